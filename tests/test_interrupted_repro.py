"""`dvc repro` SIGKILLed in the middle of a stage (the whole process group: dvc, the stage and
its dask workers): the next `dvc repro` finishes, its stores are byte-identical to an
uninterrupted run's, and no temporary folder is left behind (the killed run's
``store/.landmarks.zarr.tmp-<pid>`` is swept by the next writer of that store)."""
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from tests.helpers import copy_project, dvc

THREE_SHORT_VIDEOS = {"synthetic_speaker": {"n_videos": 3, "seconds_per_video": 4.0},   # 3 videos = 3 landmark tasks
        "cluster": {"n_workers": 1}}                                         # (cluster is no stage's dependency)


def files(store: Path) -> dict:
    return {p.relative_to(store).as_posix(): p.read_bytes() for p in sorted(store.rglob("*")) if p.is_file()}


def temporaries(proj: Path) -> list[str]:
    """Leftover ``.tmp-``/``.old-`` files or folders anywhere in the workspace (DVC's and git's own
    folders aside)."""
    found = []
    for root, dirs, names in os.walk(proj):
        dirs[:] = [d for d in dirs if d not in (".dvc", ".git")]
        found += [os.path.join(root, n) for n in dirs + names if ".tmp-" in n or ".old-" in n]
    return found


def repro_killed_in_landmarks(proj: Path) -> str:
    """Start `dvc repro landmarks` in its own process group and SIGKILL the group once the stage
    has written its first landmark shards (the stage is one task per video, so it is mid-stage);
    return the name of the temporary store it left behind."""
    env = dict(os.environ, PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"])
    log = open(proj / "killed_repro.log", "wb")
    p = subprocess.Popen([sys.executable, "-m", "dvc", "repro", "landmarks"], cwd=proj, env=env,
                         stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 900
    tmp = None
    try:
        while time.monotonic() < deadline and p.poll() is None:
            tmp = next(iter((proj / "store").glob(".landmarks.zarr.tmp-*")), None)
            if tmp is not None and (tmp / "valid" / "c").is_dir() and any((tmp / "valid" / "c").iterdir()):
                break
            time.sleep(0.01)
        assert p.poll() is None, f"dvc repro ended before it could be killed:\n{(proj / 'killed_repro.log').read_text()}"
        assert tmp is not None, "landmarks did not start writing in time"
        written = len(list((tmp / "valid" / "c").iterdir()))
        os.killpg(p.pid, signal.SIGKILL)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
        p.wait(timeout=60)
        log.close()
    for _ in range(500):                       # the stage and its dask worker processes die with the group
        try:
            os.killpg(p.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.02)
    else:
        pytest.fail("processes of the killed dvc repro survived SIGKILL of its process group")
    assert p.returncode == -signal.SIGKILL
    assert written < 3, "the kill came after the last landmark shard"
    return tmp.name


@pytest.mark.slow
def test_repro_after_a_sigkill_mid_stage_matches_an_uninterrupted_run(tmp_path):
    a = copy_project(tmp_path / "a", THREE_SHORT_VIDEOS)
    dvc(a, "repro", "ingest")                                  # synthetic speaker + ingest, shared by both runs
    b = tmp_path / "b"
    shutil.copytree(a, b, symlinks=True, ignore=lambda d, names: ["tmp"] if Path(d).name == ".dvc" else [])
    dvc(a, "repro", "landmarks")                               # the uninterrupted reference

    left = repro_killed_in_landmarks(b)
    assert (b / "store" / left).is_dir() and not (b / "store" / "landmarks.zarr").exists()
    out = dvc(b, "repro", "landmarks")                         # the next repro
    assert "Running stage 'landmarks'" in out and "Running stage 'ingest'" not in out
    assert f"{left}: left behind by process" in out, out       # swept, with one log line

    assert temporaries(b) == [], temporaries(b)
    for store in ("ingest.zarr", "landmarks.zarr"):
        fa, fb = files(a / "store" / store), files(b / "store" / store)
        assert sorted(fa) == sorted(fb), f"{store}: not the same files"
        assert [k for k in fa if fa[k] != fb[k]] == [], f"{store}: files differ from the uninterrupted run"
    lock_a = yaml.safe_load((a / "dvc.lock").read_text())["stages"]
    lock_b = yaml.safe_load((b / "dvc.lock").read_text())["stages"]
    assert lock_a["landmarks"]["outs"] == lock_b["landmarks"]["outs"]
    assert "up to date" in dvc(b, "status", "landmarks")

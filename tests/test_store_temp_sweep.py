"""A killed stage leaves ``.<out>.tmp-<pid>`` behind; the next writer of that output sweeps the
temporary folders of processes that are gone — and nothing else."""
import logging
import subprocess
import sys

from pipeline.io.store import atomic_output, pid_alive, sweep_stale_temps
from tests.conftest import ROOT


def dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    assert not pid_alive(p.pid)
    return p.pid


def test_sweep_removes_dead_writers_only(tmp_path, caplog):
    out = tmp_path / "landmarks.zarr"
    out.mkdir()
    (out / "zarr.json").write_text("{}")
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        dead = dead_pid()
        stale_tmp = tmp_path / f".landmarks.zarr.tmp-{dead}"
        stale_old = tmp_path / f".landmarks.zarr.old-{dead}"
        for d in (stale_tmp, stale_old):
            (d / "landmarks" / "c").mkdir(parents=True)
            (d / "landmarks" / "c" / "0").write_bytes(b"half a shard")
        live = tmp_path / f".landmarks.zarr.tmp-{sleeper.pid}"        # another run, writing right now
        own = tmp_path / f".landmarks.zarr.tmp-{__import__('os').getpid()}"
        keep = [live, own,
                tmp_path / f".ingest.zarr.tmp-{dead}",                # another output's leftovers: its own writer sweeps them
                tmp_path / f".landmarks.zarr.tmp-{dead}x",            # not our pattern
                tmp_path / f"landmarks.zarr.tmp-{dead}",              # no leading dot: not ours
                tmp_path / ".landmarks.zarr.tmp-abc"]
        for d in keep:
            d.mkdir()
        with caplog.at_level(logging.INFO, logger="lipsynth.store"):
            swept = sweep_stale_temps(out)
        assert sorted(swept) == sorted([stale_tmp, stale_old])
        assert not stale_tmp.exists() and not stale_old.exists()
        assert all(d.exists() for d in keep) and (out / "zarr.json").exists()
        lines = [r.getMessage() for r in caplog.records if r.name == "lipsynth.store"]
        assert len(lines) == 2 and all(str(dead) in line and "no longer running" in line for line in lines), lines
        assert sweep_stale_temps(out) == []                             # nothing left to sweep
    finally:
        sleeper.kill()
        sleeper.wait()


def test_pid_alive():
    import os
    assert pid_alive(os.getpid()) and pid_alive(1)                   # pid 1 may belong to another user: still alive
    assert not pid_alive(dead_pid()) and not pid_alive(0) and not pid_alive(-5)


KILLED_WRITER = """
import os, signal, sys
sys.path.insert(0, {root!r})
from pipeline.io.store import atomic_output
with atomic_output({out!r}) as tmp:
    tmp.mkdir()
    (tmp / "shard").write_bytes(b"x" * 1000)
    print(tmp, flush=True)
    os.kill(os.getpid(), signal.SIGKILL)
"""


def test_atomic_output_sweeps_a_sigkilled_writer_before_writing(tmp_path):
    out = tmp_path / "store" / "landmarks.zarr"
    r = subprocess.run([sys.executable, "-c", KILLED_WRITER.format(root=str(ROOT), out=str(out))],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == -9
    left = tmp_path / "store" / r.stdout.strip().rsplit("/", 1)[-1]
    assert left.name.startswith(".landmarks.zarr.tmp-") and (left / "shard").exists()   # today's leftover
    with atomic_output(out) as tmp:
        assert not left.exists()                                        # swept before this run writes
        tmp.mkdir()
        (tmp / "shard").write_bytes(b"y")
    assert sorted(p.name for p in (tmp_path / "store").iterdir()) == ["landmarks.zarr"]
    assert (out / "shard").read_bytes() == b"y"


def test_a_file_output_keeps_its_extension_and_appears_only_on_success(tmp_path):
    out = tmp_path / "result.mp4"
    out.write_bytes(b"old video")
    try:
        with atomic_output(out, suffix=".mp4") as tmp:
            assert tmp.name.endswith(".mp4") and tmp.name.startswith(".result.mp4.tmp-")
            tmp.write_bytes(b"half a video")
            raise RuntimeError("encoder failed")
    except RuntimeError:
        pass
    assert out.read_bytes() == b"old video" and sorted(p.name for p in tmp_path.iterdir()) == ["result.mp4"]
    with atomic_output(out, suffix=".mp4") as tmp:
        tmp.write_bytes(b"new video")
    assert out.read_bytes() == b"new video" and sorted(p.name for p in tmp_path.iterdir()) == ["result.mp4"]


def test_a_killed_file_writer_is_swept(tmp_path):
    out = tmp_path / "result.mp4"
    stale = tmp_path / f".result.mp4.tmp-{dead_pid()}.mp4"
    stale.write_bytes(b"half a video")
    assert sweep_stale_temps(out) == [stale] and not stale.exists()

"""Task execution without a cluster (``cluster.address: in-process``) and the shared cluster of `speak`."""
import cv2
import pytest

from pipeline.io.parallel import IN_PROCESS, SharedCluster, client_address, client_for, run_tasks
from pipeline.params import Cluster


def _square_and_pin_opencv(x):
    cv2.setNumThreads(1)                 # what a stage task does in its worker process
    return x * x


def test_in_process_runs_every_task_in_order_and_restores_opencv_threads():
    before = cv2.getNumThreads()
    cv2.setNumThreads(3)
    try:
        with client_for(Cluster(address=IN_PROCESS)) as client:
            assert client is None
            assert run_tasks(client, _square_and_pin_opencv, [3, 1, 2], "t", weights=[5, 1, 1]) == [9, 1, 4]
        assert cv2.getNumThreads() == 3
    finally:
        cv2.setNumThreads(before)


def test_in_process_task_errors_reach_the_caller():
    def fail(x):
        raise ValueError(f"bad {x}")
    with pytest.raises(ValueError, match="bad 2"):
        run_tasks(None, fail, [2, 3], "t")


def test_shared_in_process_cluster_starts_once_and_warms_nothing():
    calls = []
    with SharedCluster(Cluster(address=IN_PROCESS), warm_up=lambda: calls.append(1)) as shared:
        assert not shared.running
        with shared.client() as c:
            assert c is None and client_address(c) == IN_PROCESS
        assert shared.running
        with shared.client() as c:
            assert c is None
    assert calls == []                   # no workers to warm: the function never runs here


def _worker_malloc_trim():
    import os
    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def test_local_workers_keep_glibcs_malloc_defaults():
    """distributed's MALLOC_TRIM_THRESHOLD_ froze glibc's mmap threshold: NumPy temporaries above 128 kB were
    mapped anew each time, and a worker's gathers ran 5–6× slower than the main process's. Our LocalCluster's
    workers start without it; the main process's dask config is left as it was."""
    import dask
    import distributed  # noqa: F401  (its config keys)
    from pipeline.io.parallel import SPAWN_ENVIRON, worker_environ
    assert worker_environ({"MALLOC_TRIM_THRESHOLD_": 65536, "OMP_NUM_THREADS": 1}) == {"OMP_NUM_THREADS": 1}
    before = dict(dask.config.get(SPAWN_ENVIRON))
    with client_for(Cluster(n_workers=1)) as client:
        assert client.submit(_worker_malloc_trim, pure=False).result() is None
    assert dict(dask.config.get(SPAWN_ENVIRON)) == before


def test_a_short_target_skips_the_local_cluster_unless_workers_are_asked_for(tmp_path):
    """``lipsynth.target``: a target of at most IN_PROCESS_MAX_FRAMES frames is preprocessed in process on the
    default cluster params; a longer one, a scheduler address or an explicit worker count keep the cluster; the
    caller's params are not changed. The length comes from the file's header."""
    from lipsynth.target import IN_PROCESS_MAX_FRAMES, cluster_for_frames, target_cluster
    from tests.helpers.media import make_clip
    default = Cluster()
    assert cluster_for_frames(default, IN_PROCESS_MAX_FRAMES).address == IN_PROCESS
    assert default.address is None
    assert cluster_for_frames(default, IN_PROCESS_MAX_FRAMES + 1) is default
    assert cluster_for_frames(Cluster(n_workers=2), 10).address is None
    assert cluster_for_frames(Cluster(address="tcp://10.0.0.1:8786"), 10).address == "tcp://10.0.0.1:8786"
    clip = tmp_path / "clip.mp4"
    make_clip(clip, n_frames=30)
    assert target_cluster(default, clip).address == IN_PROCESS


def test_the_in_process_bound_is_the_one_the_bench_measured_below():
    """results/target_cluster.json (bench/target_cluster.py) was measured with today's bound, and every target
    it measured at or below the bound prepared in process no slower than on the LocalCluster, within the noise of
    a 2-core machine: 5 % of the median (measured 12-07: WDA_KatieHill_000, 200 frames, in process 20.1–21.1 s
    against 19.8–20.2 s, the runs overlapping; every other target faster in process by 1.4–2.7 s)."""
    import json
    from lipsynth.target import IN_PROCESS_MAX_FRAMES
    from tests.conftest import ROOT
    res = json.loads((ROOT / "results" / "target_cluster.json").read_text())
    assert res["in_process_max_frames"] == IN_PROCESS_MAX_FRAMES
    short = [r for r in res["targets"] if r["frames"] <= IN_PROCESS_MAX_FRAMES]
    assert len(short) >= 3
    assert all(r["in_process"]["median_s"] <= 1.05 * r["local_cluster"]["median_s"] for r in short), short

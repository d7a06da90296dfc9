"""A stage runs on a real dask scheduler with two worker processes on 127.0.0.1."""
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zarr

from tests.conftest import ROOT, shared
from tests.stage_runner import make_params, run_preprocessing


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def dask_cluster(tmp_path):
    bindir = Path(sys.executable).parent
    dask = str(bindir / "dask")
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    time.sleep(2)
    for i in range(2):
        procs.append(subprocess.Popen([dask, "worker", address, "--nthreads", "1", "--no-dashboard",
                                       "--name", f"w{i}"], cwd=tmp_path, env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    from distributed import Client
    with Client(address, timeout=30) as c:
        c.wait_for_workers(2, timeout=60)
    yield address
    for p in procs[::-1]:
        p.terminate()
    for p in procs:
        p.wait(timeout=30)


@pytest.mark.slow
def test_stages_run_on_external_scheduler(tmp_path, dask_cluster):
    from distributed import Client
    clips = sorted(shared("grid_s1", "video").glob("*.mp4"))[:4]
    local = tmp_path / "local"
    remote = tmp_path / "remote"
    local.mkdir(), remote.mkdir()
    run_preprocessing(make_params(local, [str(c) for c in clips], cluster={"n_workers": 1}), ("ingest", "landmarks"))
    params = make_params(remote, [str(c) for c in clips], cluster={"address": dask_cluster})
    run_preprocessing(params, ("ingest", "landmarks"))
    with Client(dask_cluster) as c:
        assert len(c.scheduler_info()["workers"]) == 2
        # both workers did landmark work
        done = c.run(lambda dask_worker: len(dask_worker.data) + dask_worker.state.executed_count)
        assert all(n > 0 for n in done.values()), done
    a = zarr.open_group(str(local / "landmarks.zarr"))
    b = zarr.open_group(str(remote / "landmarks.zarr"))
    np.testing.assert_array_equal(a["landmarks"][...], b["landmarks"][...])   # same result on either cluster
    np.testing.assert_array_equal(zarr.open_group(str(local / "ingest.zarr"))["mfcc"][...],
                                  zarr.open_group(str(remote / "ingest.zarr"))["mfcc"][...])

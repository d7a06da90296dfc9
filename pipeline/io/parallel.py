"""Dask execution: a LocalCluster sized to the machine, or the scheduler at ``cluster.address``.

Stages describe their work as a plain list of task arguments (shard ranges, videos) and hand
it to ``run_tasks``; nothing else in a stage knows about dask.
"""
from __future__ import annotations

import contextlib
import logging
import os

from tqdm import tqdm

log = logging.getLogger("lipsynth.parallel")


@contextlib.contextmanager
def client_for(cluster):
    """Yield a ``distributed.Client``.

    Parameters
    ----------
    cluster : pipeline.params.Cluster
        ``address`` (str or None): a running scheduler (``tcp://host:8786``); None starts a
        LocalCluster with ``n_workers`` (None → one per core) single-threaded worker processes.
    """
    from distributed import Client, LocalCluster

    for name in ("distributed", "tornado", "bokeh"):
        logging.getLogger(name).setLevel(logging.WARNING)
    address = cluster.address
    if address:
        log.info("connecting to dask scheduler %s", address)
        with Client(address, timeout=cluster.connect_timeout) as c:
            yield c
        return
    n = cluster.n_workers or os.cpu_count() or 1
    log.info("starting LocalCluster with %d worker processes", n)
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                      memory_limit=cluster.memory_limit,
                      dashboard_address=None, silence_logs=logging.WARNING) as lc, Client(lc) as c:
        yield c


def run_tasks(client, fn, items: list, desc: str, unit: str = "task", weights: list | None = None) -> list:
    """Run ``fn(item)`` for each item on the cluster; return results in item order.

    A progress bar advances by ``weights[i]`` (e.g. frames) when task i finishes. The first
    task error is re-raised in the caller (the remaining tasks are cancelled).
    """
    from distributed import as_completed

    if not items:
        return []
    futures = client.map(fn, items, pure=False)
    order = {f.key: i for i, f in enumerate(futures)}
    results = [None] * len(items)
    total = sum(weights) if weights else len(items)
    with tqdm(total=total, desc=desc, unit=unit, dynamic_ncols=True) as bar:
        try:
            for fut in as_completed(futures):
                i = order[fut.key]
                results[i] = fut.result()
                bar.update(weights[i] if weights else 1)
        except BaseException:
            client.cancel(futures)
            raise
    return results

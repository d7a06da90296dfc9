"""Dask execution: a LocalCluster sized to the machine, or the scheduler at ``cluster.address``.

Stages describe their work as a plain list of task arguments (shard ranges, videos) and hand
it to ``run_tasks``; nothing else in a stage knows about dask.

A dask scheduler runs whatever code a client sends it, so whoever can reach its port can run
code as the user who started the workers. The LocalCluster listens on 127.0.0.1 only; a real
cluster should bind to a private interface and use TLS: a ``tls://`` address connects with the
certificates of ``cluster.security`` (``distributed.security.Security``), and
``cluster.security.require_encryption`` refuses a plain ``tcp://`` address.
"""
from __future__ import annotations

import contextlib
import logging
import os
from pathlib import Path

from tqdm import tqdm

from pipeline.errors import LipsynthError

log = logging.getLogger("lipsynth.parallel")

_OWN_CLUSTERS: set[str] = set()     # addresses of the LocalClusters this process started (127.0.0.1 only)
IN_PROCESS = "in-process"           # cluster.address: no cluster, tasks run one after another in this process


def security_for(cluster):
    """The ``distributed.security.Security`` to reach ``cluster.address`` with, or None (tcp).

    ``cluster.security``'s files override dask's own configuration (``distributed.comm.tls.*``,
    read by ``Security()``); a tls:// address without a CA and a client certificate in either is
    an error, and so is a tcp:// address when ``require_encryption`` is set — except a
    LocalCluster (no address, or one this process started itself: ``lipsynth.target`` hands its
    address to the stages), which listens on the loopback interface only.
    """
    from distributed.security import Security

    sec, address = cluster.security, cluster.address or ""
    files = {k: getattr(sec, k) for k in ("tls_ca_file", "tls_client_cert", "tls_client_key")}
    for key, path in files.items():
        if path and not Path(path).is_file():
            raise LipsynthError(f"cluster.security.{key}: {path} not found")
    if address.startswith("tls://"):
        security = Security(require_encryption=sec.require_encryption or None,
                            **{k: str(Path(v).absolute()) for k, v in files.items() if v})
        if not security.tls_ca_file or not security.tls_client_cert:
            raise LipsynthError(f"cluster.address {address} is tls:// but no certificates are set: set "
                                "cluster.security.tls_ca_file and .tls_client_cert (and .tls_client_key)")
        return security
    if sec.require_encryption and address and address not in _OWN_CLUSTERS:
        raise LipsynthError(f"cluster.address {address!r} is not encrypted and cluster.security.require_encryption "
                            "is set: use a tls:// scheduler (docs/cluster.md)")
    return None


@contextlib.contextmanager
def client_for(cluster):
    """Yield a ``distributed.Client`` (None for ``in-process``: ``run_tasks`` then runs the tasks here).

    Parameters
    ----------
    cluster : pipeline.params.Cluster
        ``address`` (str or None): a running scheduler (``tcp://host:8786``, or ``tls://host:8786``
        with ``security``); None starts a LocalCluster on 127.0.0.1 with ``n_workers`` (None →
        one per core) single-threaded worker processes; ``in-process``: no cluster, the tasks run
        one after another in this process (debugging; ``lipsynth speak`` ingests its one target
        video so while its cluster's workers start).
    """
    address = cluster.address
    if address == IN_PROCESS:
        yield None
        return
    import dask
    from distributed import Client, LocalCluster

    for name in ("distributed", "tornado", "bokeh"):
        logging.getLogger(name).setLevel(logging.WARNING)
    if address:
        security = security_for(cluster)
        log.info("connecting to dask scheduler %s%s", address, " (TLS)" if security else "")
        try:
            client = Client(address, timeout=cluster.connect_timeout, security=security)
        except (OSError, TimeoutError) as exc:
            raise LipsynthError(f"cannot reach the dask scheduler at {address} within cluster.connect_timeout="
                                f"{cluster.connect_timeout:g} s ({exc})") from None
        with client as c:
            yield c
        return
    security_for(cluster)               # validates the files named in cluster.security
    n = cluster.n_workers or os.cpu_count() or 1
    log.info("starting LocalCluster with %d worker processes", n)
    # dashboard_address ":0": the scheduler's HTTP server (health routes; no dashboard without bokeh)
    # takes a free port, so two clusters at once (two test processes, two users) never fight over 8787
    with contextlib.ExitStack() as stack:
        stack.callback(_restore_levels, _distributed_levels())    # last: after the cluster has closed
        stack.enter_context(dask.config.set({SPAWN_ENVIRON: worker_environ(dask.config.get(SPAWN_ENVIRON))}))
        lc = stack.enter_context(LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                              memory_limit=cluster.memory_limit,
                                              dashboard_address=":0", silence_logs=logging.WARNING))
        c = stack.enter_context(Client(lc))
        _OWN_CLUSTERS.add(lc.scheduler_address)
        try:
            yield c
        finally:
            _OWN_CLUSTERS.discard(lc.scheduler_address)
            _quiet_shutdown(c)


SPAWN_ENVIRON = "distributed.nanny.pre-spawn-environ"


def worker_environ(environ: dict) -> dict:
    """distributed's environment for new worker processes without ``MALLOC_TRIM_THRESHOLD_``.

    distributed sets it (65536) so idle workers hand freed memory back to the OS. Setting any glibc
    malloc threshold also freezes the dynamic mmap threshold at 128 kB, so every NumPy temporary above that
    (a 176-px texture's float copy, a frame's resampling taps) is mapped and unmapped anew and page-faults
    on each use: measured, NumPy's gathers and ufuncs ran 5–6× slower in a worker than in the main process,
    and frontalize's per-shard tasks 2.7× slower (1.9 s against 0.7 s for 64 frames of 720×1280 footage).
    Our tasks are short and their memory bounded by a shard, so the workers keep glibc's defaults, as the
    main process does. The outputs are the same bytes (allocation does not change arithmetic)."""
    return {k: v for k, v in environ.items() if k != "MALLOC_TRIM_THRESHOLD_"}


def _distributed_levels() -> dict:
    """The levels of this process's ``distributed.*`` loggers, by name."""
    names = [n for n in logging.root.manager.loggerDict if n == "distributed" or n.startswith("distributed.")]
    return {n: logging.getLogger(n).level for n in names}


def _restore_levels(levels: dict) -> None:
    for name, level in levels.items():
        logging.getLogger(name).setLevel(level)


def _silence_distributed() -> None:
    """Every ``distributed.*`` logger of this process at ERROR (run on the workers before a shutdown)."""
    for name in _distributed_levels():
        logging.getLogger(name).setLevel(logging.ERROR)


def _quiet_shutdown(client) -> None:
    """Closing the LocalCluster says nothing a user can act on — a warm-up task cancelled, a busy
    worker killed after 4 s — and would print it above the error that stopped the run: the workers'
    and this process's ``distributed`` loggers go to ERROR for the shutdown."""
    try:
        client.run(_silence_distributed)
    except Exception:                   # a worker already gone: its process prints nothing more
        pass
    _silence_distributed()


def run_tasks(client, fn, items: list, desc: str, unit: str = "task", weights: list | None = None) -> list:
    """Run ``fn(item)`` for each item on the cluster; return results in item order.

    A progress bar advances by ``weights[i]`` (e.g. frames) when task i finishes. The first
    task error is re-raised in the caller (the remaining tasks are cancelled).
    """
    if not items:
        return []
    if client is None:                  # cluster.address: in-process
        return _run_here(fn, items, desc, unit, weights)
    from distributed import as_completed

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


def _run_here(fn, items: list, desc: str, unit: str, weights: list | None) -> list:
    """``run_tasks`` without a cluster: the tasks one after another in this process. Tasks set
    process-wide library state for their worker (OpenCV's thread count): restored after each."""
    from pipeline.io.threads import opencv_threads
    import cv2

    results = []
    with tqdm(total=sum(weights) if weights else len(items), desc=desc, unit=unit, dynamic_ncols=True) as bar:
        for i, item in enumerate(items):
            with opencv_threads(cv2.getNumThreads()):
                results.append(fn(item))
            bar.update(weights[i] if weights else 1)
    return results


class SharedCluster:
    """One cluster for several stage runs of an application (``lipsynth speak``'s preprocessing).

    ``client()`` gives a Client on it — the first call starts the LocalCluster (or connects to
    ``cluster.address``), later calls reuse it, so workers start and import the stages' code
    once; nothing starts when nothing needs computing. Use as a context manager: the cluster
    closes on exit.

    ``warm_up``: a function run once on every worker as soon as the cluster is up (imports,
    model loading), before any stage task — so a worker that the first stage leaves idle
    (one video is one ingest task) gets ready for the next stage meanwhile.
    """

    def __init__(self, cluster, warm_up=None):
        self.cluster = cluster
        self.warm_up = warm_up
        self._stack = contextlib.ExitStack()
        self._client = None
        self._started = False
        self._warming: list = []            # held: a released future would be forgotten by the scheduler

    def __enter__(self) -> "SharedCluster":
        return self

    def __exit__(self, *exc) -> bool:
        self._stack.close()
        return False

    @property
    def running(self) -> bool:
        """Has the cluster been started (or connected to; always false before the first ``client()``)?"""
        return self._started

    @contextlib.contextmanager
    def client(self):
        """The Client (None with ``cluster.address: in-process``: ``run_tasks`` runs tasks here)."""
        if not self._started:
            self._client = self._stack.enter_context(client_for(self.cluster))
            self._started = True
            if self.warm_up is not None and self._client is not None:
                self._warming = warm_workers(self._client, self.warm_up)
        yield self._client


def client_address(client) -> str:
    """The ``cluster.address`` that reaches ``client``'s scheduler (``in-process`` for None), for stages
    run inside another's cluster."""
    return IN_PROCESS if client is None else client.scheduler.address


def warm_workers(client, fn) -> list:
    """Submit ``fn()`` once to each worker of ``client``'s cluster (pinned to it); returns the futures."""
    workers = list(client.scheduler_info()["workers"])
    return [client.submit(fn, workers=[w], allow_other_workers=False, pure=False) for w in workers]

"""Thread settings of the libraries a frame loop calls."""
from __future__ import annotations

import contextlib


@contextlib.contextmanager
def opencv_threads(n: int):
    """Run the block with OpenCV's own thread pool at ``n`` threads (restored afterwards).

    Stages that already keep every core busy with their own frame threads set 1: OpenCV's
    parallel loops inside each call only add hand-offs and contention (composite at 720p on two
    cores: 53.9 against 63.2 s of CPU for the same frames)."""
    import cv2
    before = cv2.getNumThreads()
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        cv2.setNumThreads(before)


@contextlib.contextmanager
def library_threads(n: int):
    """Run the block with OpenCV's and the BLAS's (OpenBLAS in NumPy and SciPy) own thread pools at ``n``.

    For frame loops that keep every core busy with their own threads. Their small matrix products
    (a weighted sum of masks, a landmark fit) wake OpenBLAS's pool for each call, whose threads then
    spin-wait on the cores the frame threads need (measured: ``lipsynth speak`` at 1080p spent 6 % of its
    CPU in ``blas_thread_server``)."""
    from threadpoolctl import threadpool_limits
    with opencv_threads(n), threadpool_limits(int(n), user_api="blas"):
        yield

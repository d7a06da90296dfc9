"""The MP4 writer: what goes in comes back out (colour, size, frame count)."""
import numpy as np

from pipeline.io import media
from pipeline.io.threads import library_threads, opencv_threads


def test_written_colours_come_back(tmp_path):
    """Flat patches of saturated and grey colours survive RGB → I420 (OpenCV, BT.601 limited
    range) → x264 → decoder → RGB within a few levels: a channel swap or a full/limited-range
    mix-up would be off by tens. An odd frame size loses its last row and column."""
    colours = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255], [16, 16, 16], [128, 90, 200]],
                       np.uint8)
    frame = np.zeros((97, 6 * 32 + 1, 3), np.uint8)
    for k, c in enumerate(colours):
        frame[:, 32 * k:32 * (k + 1)] = c
    out = tmp_path / "patches.mp4"
    media.write_video(out, [frame] * 5, 25.0)
    back = [rgb for _, rgb in media.iter_frames(out)]
    assert len(back) == 5 and back[0].shape == (96, 192, 3)
    for k, c in enumerate(colours):
        patch = back[2][40:60, 32 * k + 8:32 * k + 24].reshape(-1, 3).astype(int)
        assert np.abs(np.median(patch, axis=0) - c).max() <= 6, (k, np.median(patch, axis=0), c)


def test_opencv_threads_is_restored():
    import cv2
    before = cv2.getNumThreads()
    with opencv_threads(1):
        assert cv2.getNumThreads() == 1
    assert cv2.getNumThreads() == before


def test_library_threads_holds_opencv_and_blas_and_restores_them():
    import cv2
    from threadpoolctl import threadpool_info
    blas = lambda: [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    before_cv, before_blas = cv2.getNumThreads(), blas()
    assert before_blas, "NumPy's OpenBLAS is loaded"
    with library_threads(1):
        assert cv2.getNumThreads() == 1 and set(blas()) == {1}
    assert cv2.getNumThreads() == before_cv and blas() == before_blas

"""Quality measures of a synthesized video against the original (paper 000 §4.1, "Video J" setting).

The pure measures live in ``pipeline.measures.lipsync_measures`` (the ``evaluate`` stage uses them too)
and are re-exported here; ``video_landmarks`` decodes a video and tracks its landmarks with the
pipeline's tracker (``stages.landmarks.track_video``).
"""
from __future__ import annotations

import numpy as np

from pipeline.face.dlib_face import MOUTH as LIPS, interocular  # noqa: F401  (part of this API)
from pipeline.measures.lipsync_measures import (LOWER_INNER_LIP, UPPER_INNER_LIP, best_lag, compare, flicker,  # noqa: F401
                                       inner_opening, mean_abs_difference, mouth_boxes, mouth_error, one_box,
                                       sharpness, static_mouth)
from pipeline.params import Landmarks


def video_landmarks(path, landmark_params: Landmarks) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grey frames (N, H, W) uint8, dlib landmarks (N, 68, 2) frame px and validity (N,) of a video."""
    from pipeline.io import media
    from stages.landmarks.landmarks import track_video
    grays = np.stack([np.ascontiguousarray(g) for _, g in media.iter_frames(path, "gray")])
    lms, _, valid, _ = track_video(grays, landmark_params)
    return grays, lms.astype(np.float64), valid

"""MediaPipe face landmarker lips (optional extra ``mediapipe``): the pinned model's hash check and the
mapping of the 478-point mesh to dlib's lip order 48..67, on one open-mouth frame of real footage."""
import itertools
import shutil

import numpy as np
import pytest

from tests.conftest import skip_unless_ci

try:
    import mediapipe  # noqa: F401
except ImportError:
    skip_unless_ci("mediapipe not installed: `pip install --no-deps` it as pyproject.toml's mediapipe extra says "
                   "(.ci/run does)")

from pipeline.face import dlib_face
from pipeline.face import mediapipe_lips as mpl
from pipeline.io import media
from pipeline.measures.lipsync_measures import inner_opening
from tests.conftest import shared

OPEN_FRAME = 27          # WDA_KatieHill_000.mp4: mouth wide open (dlib inner opening ≈ 26 % IOD)


def test_hash_check_rejects_missing_and_modified_file(tmp_path):
    good = mpl.check_task(mpl.task_path())
    bad = tmp_path / "face_landmarker.task"
    shutil.copyfile(good, bad)
    data = bytearray(bad.read_bytes())
    data[len(data) // 2] ^= 0xFF
    bad.write_bytes(bytes(data))
    with pytest.raises(mpl.LandmarkerModelError, match="face_landmarker.task: SHA-256"):
        mpl.check_task(bad)
    with pytest.raises(mpl.LandmarkerModelError, match="missing"):
        mpl.check_task(tmp_path / "absent.task")
    with pytest.raises(mpl.LandmarkerModelError):
        mpl.landmarker(bad)


@pytest.mark.real
def test_mapping_follows_dlib_lip_order_on_an_open_mouth():
    path = shared("hdtf", "WDA_KatieHill_000.mp4")
    _, rgb = next(itertools.islice(media.iter_frames(path, "rgb24"), OPEN_FRAME, None))
    _, gray = next(itertools.islice(media.iter_frames(path, "gray"), OPEN_FRAME, None))
    out = mpl.track(rgb[None], 25.0, video=False)
    assert out["ok"].all() and out["lips"].shape == (1, 20, 2) and out["blendshapes"].shape == (1, 52)
    assert len(out["blendshape_names"]) == 52 and out["blendshape_names"][mpl.JAW_OPEN] == "jawOpen"
    lips = out["lips"][0]                                   # index i = dlib point 48 + i
    x, y = lips[:, 0], lips[:, 1]
    assert x[0] < x[3] < x[6] and x[12] < x[14] < x[16]     # 48 left of 51 left of 54; 60 left of 62 left of 64
    assert x[11] < x[9] < x[7]                              # lower outer lip runs 59 (left) … 55 (right)
    assert np.all(y[[13, 14, 15]] < y[[19, 18, 17]])        # upper inner lip above the lower (61/67, 62/66, 63/65)
    assert y[3] < y[14] < y[18] < y[9]                      # 51 above 62 above 66 above 57

    box, _ = dlib_face.detect_face(gray)
    lm = dlib_face.predict_landmarks(gray, box)
    iod = dlib_face.interocular(lm)
    assert abs(out["iod"][0] / iod - 1) < 0.05              # mesh 33–263 ≈ dlib 36–45
    dl_open = inner_opening(lm[None])[0] / iod
    assert dl_open > 0.15                                   # the frame is an open mouth
    assert abs(out["inner_opening"][0] / iod - dl_open) < 0.04   # openings agree within 4 % IOD
    dist = np.linalg.norm(lips - lm[dlib_face.MOUTH], axis=1) / iod
    assert dist.max() < 0.08                                # each mapped point lies near its dlib point
    assert out["blendshapes"][0, mpl.JAW_OPEN] > 0.1

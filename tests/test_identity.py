"""Face identity: one person's clips are close, two people are not (real GRID footage)."""
import numpy as np

from pipeline.face import dlib_face
from pipeline.face import identity
from pipeline.io.media import FrameReader
from tests.conftest import shared


def descriptor_of(path, frames=(5, 35, 65)):
    r = FrameReader(path)
    out = []
    for k in frames:
        rgb = r.get(k)
        gray = np.ascontiguousarray(rgb.mean(2).astype(np.uint8))
        box, _ = dlib_face.detect_face(gray, 1)
        out.append(identity.face_descriptor(rgb, dlib_face.predict_landmarks(gray, box)))
    return identity.identity(np.stack(out))


def test_same_speaker_is_closer_than_another_speaker():
    s1a = descriptor_of(shared("grid_s1", "video", "bbaf2n.mp4"))
    s1b = descriptor_of(shared("grid_s1", "video", "bgan4n.mp4"))
    s4 = descriptor_of(shared("grid_s4", "prbc8s.mpg"))
    same, other = identity.distance(s1a, s1b), identity.distance(s1a, s4)
    assert same < 0.4 < other, (same, other)


def test_crop_landmarks_inverts_the_crop_transform():
    lm = np.array([[110.0, 60.0], [130.0, 90.0]])
    crop = (50.0, 20.0, 0.5)                 # frame = (x0, y0) + s · crop pixel
    q = identity.crop_landmarks(lm, crop)
    np.testing.assert_allclose(np.asarray(crop[:2]) + crop[2] * q, lm)

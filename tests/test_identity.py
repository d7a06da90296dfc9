"""Face identity: one person's clips are close, two people are not (real GRID footage)."""
import numpy as np
import pytest

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


@pytest.mark.real
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


@pytest.mark.real
def test_descriptors_read_from_a_store_equal_those_of_the_frames(tmp_path):
    """``stored_descriptors`` (the task ``speak`` runs on its workers) = ``frame_descriptors`` here."""
    import zarr
    from pipeline.io.store import rgb_to_i420
    r = FrameReader(shared("grid_s1", "video", "bbaf2n.mp4"))
    frames = [r.get(k)[:288, 36:324] for k in (5, 20, 35)]          # 288 × 288: I420 needs even sizes
    crops = zarr.open_array(tmp_path / "crops.zarr", mode="w", shape=(3, 432, 288), dtype="uint8", chunks=(1, 432, 288))
    crops[:] = [rgb_to_i420(f) for f in frames]
    lms = []
    for f in frames:
        gray = np.ascontiguousarray(f.mean(2).astype(np.uint8))
        box, _ = dlib_face.detect_face(gray, 1)
        lms.append(dlib_face.predict_landmarks(gray, box) * 2 + [10.0, 4.0])   # frame px of a crop at (10, 4), s = 2
    crop = (10.0, 4.0, 2.0)
    here = identity.frame_descriptors(crops, [0, 2], np.asarray(lms)[[0, 2]], crop)
    ingest = tmp_path / "ingest.zarr"
    zarr.open_group(ingest, mode="w").create_array("crops", data=crops[:], chunks=(1, 432, 288))
    there = identity.stored_descriptors(dict(ingest=str(ingest), frames=[0, 2], landmarks=np.asarray(lms)[[0, 2]],
                                             crop=crop))
    assert here.shape == (2, 128)
    np.testing.assert_array_equal(here, there)
    other = identity.frame_descriptors(crops, [1], np.asarray(lms)[[1]], crop)
    assert 0 < identity.distance(here[0], other[0]) < 0.4            # a real descriptor: same person, another frame

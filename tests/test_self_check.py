"""The composite's per-frame self-check: the measure, the pass rule and the cross-fade weights."""
import cv2
import numpy as np
import skimage.data

from pipeline.face import dlib_face
from stages.composite.self_check import check_frame, fallback_weights, mouth_energy, passes


def test_fallback_weights_fade_around_failed_frames():
    ok = np.ones(12, bool)
    assert np.all(fallback_weights(ok, 3) == 1)
    ok[5] = False
    w = fallback_weights(ok, 3)
    np.testing.assert_allclose(w, [1, 1, .75, .5, .25, 0, .25, .5, .75, 1, 1, 1])
    ok[0] = False                                            # a failure at the start fades out only
    assert fallback_weights(ok, 3)[0] == 0 and fallback_weights(ok, 3)[1] == 0.25
    assert np.all(fallback_weights(ok, 0)[ok] == 1)          # no fade: only the failed frames fall back


def _photo():
    rgb = skimage.data.astronaut()
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    box, _ = dlib_face.detect_faces(gray)[0]
    return rgb, dlib_face.predict_landmarks(gray, box).astype(np.float64)


def test_check_passes_a_real_face_and_catches_a_wrong_mouth():
    rgb, lm = _photo()
    good = check_frame(rgb, lm, mouth_energy(rgb, lm))
    assert good["error"] < 0.03 and abs(good["sharpness"] - 1) < 1e-6
    assert passes(good, 0.12, 4.0)
    # the synthesized mouth claimed 30 % of the inter-ocular distance lower than where it is
    moved = lm.copy()
    moved[48:68, 1] += 0.3 * dlib_face.interocular(lm)
    bad = check_frame(rgb, moved, mouth_energy(rgb, lm))
    assert bad["error"] > 0.12 and not passes(bad, 0.12, 4.0)
    # scribbles over the mouth: far sharper than the target there
    noisy = rgb.copy()
    m = lm[48:68].astype(int)
    x0, y0 = m.min(0)
    x1, y1 = m.max(0)
    noise = np.random.default_rng(0).integers(0, 255, (y1 - y0, x1 - x0, 3), dtype=np.uint8)
    noisy[y0:y1, x0:x1] = noise
    assert check_frame(noisy, lm, mouth_energy(rgb, lm))["sharpness"] > 4.0


def test_check_catches_a_lower_face_drawn_stretched_down():
    """The issue-33 failure at 4K: nose stretched down and the mouth lower — the whole lower face
    moved, so the mouth alone (its points moved with it) could pass; the nose and chin do not."""
    rgb, lm = _photo()
    good = check_frame(rgb, lm, mouth_energy(rgb, lm))
    assert good["face_error"] < 0.04 and passes(good, 0.12, 4.0, 0.1)
    iod = float(dlib_face.interocular(lm))
    top = float(lm[27:30, 1].mean())                        # below the eyes: the mouth 0.25 IOD lower
    scale = 1 + 0.25 * iod / (lm[48:68, 1].mean() - top)
    h, w = rgb.shape[:2]
    ys, xs = np.mgrid[:h, :w].astype(np.float32)
    src_y = np.where(ys > top, top + (ys - top) / scale, ys).astype(np.float32)
    stretched = cv2.remap(rgb, xs, src_y, cv2.INTER_LINEAR)
    expected = lm.copy()
    expected[48:68, 1] = top + (lm[48:68, 1] - top) * scale  # the synthesized mouth claims its new place
    bad = check_frame(stretched, expected, mouth_energy(rgb, lm))
    assert bad["error"] < 0.12                              # the mouth check alone passes it
    assert bad["face_error"] > 0.1 and not passes(bad, 0.12, 4.0, 0.1)


def _box_biased(lm):
    """Where a 3D fit may put a turned or frame-cut face's jawline and brows: the face box made from them is
    not the detector's, and dlib reads even the untouched frame far from its tracked points."""
    e = lm.copy()
    iod = float(dlib_face.interocular(lm))
    e[17:27, 1] -= iod
    e[0:17, 0] += np.sign(e[0:17, 0] - e[30, 0]) * 0.5 * iod
    return e


def test_the_differential_check_cancels_dlibs_box_bias_and_still_catches_a_wrong_mouth():
    rgb, lm = _photo()
    biased = _box_biased(lm)
    energy = mouth_energy(rgb, lm)
    absolute = check_frame(rgb, biased, energy)                  # the untouched frame, read in the biased box
    assert not passes(absolute, 0.12, 4.0, 0.1)                  # the absolute check fails it
    same = check_frame(rgb, biased, energy, rgb, biased)
    assert same["error"] < 1e-9 and same["face_error"] < 1e-9 and passes(same, 0.12, 4.0, 0.1)
    moved = biased.copy()                                        # a mouth claimed 0.3 IOD lower than it shows
    moved[48:68, 1] += 0.3 * dlib_face.interocular(lm)
    bad = check_frame(rgb, moved, energy, rgb, biased)
    assert bad["error"] > 0.25 and not passes(bad, 0.12, 4.0, 0.1)


def test_the_differential_check_catches_a_lower_face_drawn_stretched_down():
    rgb, lm = _photo()
    iod = float(dlib_face.interocular(lm))
    top = float(lm[27:30, 1].mean())
    scale = 1 + 0.25 * iod / (lm[48:68, 1].mean() - top)
    h, w = rgb.shape[:2]
    ys, xs = np.mgrid[:h, :w].astype(np.float32)
    stretched = cv2.remap(rgb, xs, np.where(ys > top, top + (ys - top) / scale, ys).astype(np.float32), cv2.INTER_LINEAR)
    target_expected = _box_biased(lm)
    expected = target_expected.copy()
    expected[48:68, 1] = top + (lm[48:68, 1] - top) * scale
    bad = check_frame(stretched, expected, mouth_energy(rgb, lm), rgb, target_expected)
    assert bad["face_error"] > 0.1 and not passes(bad, 0.12, 4.0, 0.1)

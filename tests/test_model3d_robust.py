"""The per-target 3D model of a stranger from one short, nearly rigid clip (model3d.bundle_adjust).

A 75-frame clip in which the head hardly rotates leaves depth unobservable. The free pycolmap
bundle adjustment then used to slide points metres along their rays (or return a depth-inverted
face), and every frame's PnP against the model failed. These clips are synthesised from a known
3D face whose depth differs from the anthropometric prior, with brows that move (as in speech).
"""
import numpy as np
import pytest

from pipeline.face.geometry import intrinsics, project
from pipeline.params import load_params
from stages.frontalize import model3d
from stages.frontalize.frontalize import build_model


def stranger_clip(face3d, seed, n=75, brow_mm=2.0, depth_mm=15.0, noise_px=0.5):
    """(n, 68, 2) landmarks of a 360×288 clip: head turning < 1°, brows moving, depth unlike the prior."""
    rng = np.random.default_rng(seed)
    K = intrinsics(360, 288, 1.5)
    true = face3d.copy()
    true[:, 2] += rng.normal(0, depth_mm, 68)
    angles = np.cumsum(rng.normal(0, 0.5, (n, 3)), 0) * 0.3          # a slow random walk, degrees
    obs = []
    for f in range(n):
        X = true.copy()
        X[17:27, 1] -= brow_mm * (1 + np.sin(f / 4))
        t = np.array([*rng.uniform(-5, 5, 2), 650.0])
        obs.append(project(X, np.radians(angles[f]), t, K) + rng.normal(0, noise_px, (68, 2)))
    return np.array(obs), K


@pytest.mark.parametrize("seed", [0, 1, 6])      # the old free fit: 35, 12, 11 px median on these
def test_stranger_model_reprojects(face3d, seed):
    lms, K = stranger_clip(face3d, seed)
    p = load_params("params.yaml").frontalize
    shape, report = build_model(lms, [K] * len(lms), p)
    assert report["conditioning"] < p.min_conditioning          # the degenerate case: prior start
    errs = model3d.frame_errors(shape, list(lms), [K] * len(lms))
    assert np.median(errs) < 1.5                                 # noise 0.5 px + moving brows
    assert errs.max() < 0.15 * 90 * 360 * 1.5 / 650              # every pose within frontalize's bound
    assert np.all(np.isfinite(shape)) and np.abs(shape).max() < 300
    assert shape[30, 2] < 0 < shape[[0, 16], 2].mean()          # nose in front of the eyes, jaw behind
    assert shape[8, 1] > shape[27, 1]                            # chin below the nose bridge
    assert abs(report["ba_rms_after"] - np.sqrt(np.mean(errs ** 2))) < 0.5   # the report describes it


def test_regularised_fit_keeps_unobservable_depth(face3d):
    """No head rotation at all: the 2D shape is fitted, depth stays at the start (no drift)."""
    rng = np.random.default_rng(5)
    K = intrinsics(360, 288, 1.5)
    obs = [project(face3d, np.zeros(3), np.array([*rng.uniform(-5, 5, 2), 650.0]), K) + rng.normal(0, 0.5, (68, 2))
           for _ in range(75)]
    flat = face3d.copy()
    flat[:, 1] *= 1.2                                            # wrong 2D proportions, right depth
    start = model3d._to_canonical(flat)
    refined = model3d.refine_with_prior(start, obs, [K] * 75)
    assert np.median(model3d.frame_errors(refined, obs, [K] * 75)) < 1.0
    assert np.median(model3d.frame_errors(start, obs, [K] * 75)) > 2.0
    assert np.abs(refined[model3d.RIGID, 2] - start[model3d.RIGID, 2]).mean() < 5.0
    again = model3d.refine_with_prior(start, obs, [K] * 75)
    assert refined.tobytes() == again.tobytes()                  # deterministic


def test_runaway_shapes_are_not_faces(face3d):
    runaway = face3d.copy()
    runaway[20, 2] = 2500.0                                      # one point metres along its ray
    inverted = face3d * np.array([1, 1, -1])                     # nose behind the eyes
    assert model3d._plausible(face3d)
    assert not model3d._plausible(runaway)
    assert not model3d._plausible(model3d._to_canonical(inverted, allow_reflection=False))


def test_lips_fitted_as_depth_are_not_a_face(face3d):
    """The fit of GRID s4 bwif7n: the lower lip 50 mm behind the upper (the mouth's opening taken for
    depth) — its surface folded at the mouth and rendered the lips over the mouth's interior; brwm8s:
    the lips 15 mm in front of the nose tip. Both rejected; a face with ordinary lips is kept."""
    assert model3d._plausible(face3d)
    sunk = face3d.copy()
    sunk[[56, 57, 58, 65, 66, 67], 2] += 45.0                    # lower lip pushed back
    proud = face3d.copy()
    proud[48:68, 2] = face3d[30, 2] - 10.0                        # lips ahead of the nose tip
    assert not model3d._plausible(sunk)
    assert not model3d._plausible(proud)
    opened = face3d.copy()
    opened[[56, 57, 58, 65, 66, 67], 2] += 8.0                    # a jaw opened a little: still a face
    assert model3d._plausible(opened)


def test_a_factorisation_that_is_no_face_falls_back_to_the_prior(face3d, monkeypatch, caplog):
    """latsync_demo2 (a 20-s portrait phone clip): conditioning 6.21 passed the 6.0 threshold on landmark
    noise, the factorisation put the chin 35 mm beside the nose and every candidate of the bundle
    adjustment was rejected, so the factorisation itself was kept (median PnP error 0.064 IOD; the
    composite drew a streak across the cheek). The prior start must take over."""
    lms, K = stranger_clip(face3d, seed=0)
    p = load_params("params.yaml").frontalize
    p.min_conditioning = 0.0                                     # factorisation is chosen ...
    garbage = face3d.copy()
    garbage[:, 2] *= -1                                          # ... and comes out depth-inverted and
    garbage[8] += (40.0, -120.0, 0.0)                            # with the chin above the nose: no face
    assert not model3d._plausible(model3d._to_canonical(garbage, allow_reflection=False))
    monkeypatch.setattr(model3d, "factorize", lambda _lms: model3d._to_canonical(garbage, allow_reflection=False))
    with caplog.at_level("WARNING", logger="lipsynth.frontalize"):
        shape, report = build_model(lms, [K] * len(lms), p)
    assert report["method"].startswith("prior") and "not a face" in caplog.text
    assert model3d._plausible(shape)
    errs = model3d.frame_errors(shape, list(lms), [K] * len(lms))
    assert np.median(errs) < 1.5


def test_when_no_fit_is_a_face_the_fallback_is_kept(face3d):
    """``bundle_adjust(..., fallback=)``: a start that is no face and whose refinements are none either
    gives the fallback, not the start."""
    lms, K = stranger_clip(face3d, seed=1)
    runaway = face3d.copy()
    runaway[20, 2] = 2500.0                                      # one point metres along its ray: so are its flip
    assert not model3d._plausible(runaway)                       # and the fit regularised towards it
    shape, _, after = model3d._select(runaway, runaway, 1.0, 1.0, list(lms), [K] * len(lms), fallback=face3d)
    assert np.array_equal(shape, face3d)
    assert after == pytest.approx(np.sqrt(np.mean(model3d.frame_errors(face3d, list(lms), [K] * len(lms)) ** 2)))
    shape, _, _ = model3d._select(runaway, runaway, 1.0, 1.0, list(lms), [K] * len(lms))
    assert np.array_equal(shape, runaway)                        # no fallback given: the start, as before

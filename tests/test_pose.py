"""Pose recovery and the 3D model on synthetic projections with known ground truth."""
import numpy as np
import pytest

from pipeline.face import dlib_face
from pipeline.face.geometry import intrinsics, project, rotation, rotation_angle_deg, solve_pose
from stages.frontalize import model3d


def random_poses(rng, n, max_deg):
    for _ in range(n):
        rvec = np.radians(rng.uniform(-max_deg, max_deg, 3))
        tvec = np.array([rng.uniform(-30, 30), rng.uniform(-30, 30), rng.uniform(500, 900)])
        yield rvec, tvec


def test_pose_recovery_under_one_degree(face3d):
    rng = np.random.default_rng(2)
    K = intrinsics(640, 480, 1.5)
    for rvec, tvec in random_poses(rng, 30, 25):
        obs = project(face3d, rvec, tvec, K) + rng.normal(0, 0.5, (68, 2))
        r, t, err = solve_pose(face3d[model3d.RIGID], obs[model3d.RIGID], K)
        assert rotation_angle_deg(rotation(r), rotation(rvec)) < 1.0
        assert np.linalg.norm(t - tvec) < 0.03 * tvec[2]
        assert err < 1.5


def test_canonical_frame(face3d):
    assert np.allclose(face3d[[36, 45]].mean(0), 0, atol=1e-9)
    assert dlib_face.interocular(face3d) == pytest.approx(dlib_face.IOD_MM)
    assert face3d[8, 1] > face3d[27, 1]          # chin below the nose bridge (y down)
    assert face3d[30, 2] < face3d[0, 2]          # nose tip nearer the camera than the jaw corner


def test_mirrored_shape_is_reflected_back(face3d):
    mirrored = face3d * np.array([1, 1, -1])
    np.testing.assert_allclose(model3d._to_canonical(mirrored), face3d, atol=1e-6)


def test_bundle_adjustment_and_factorization_recover_depth(face3d):
    rng = np.random.default_rng(3)
    K = intrinsics(640, 480, 1.5)
    obs = [project(face3d, r, t, K) + rng.normal(0, 0.5, (68, 2)) for r, t in random_poses(rng, 60, 15)]
    flat = face3d.copy()
    flat[:, 2] *= 0.5
    start = model3d._to_canonical(flat)
    refined, before, after = model3d.bundle_adjust(start, obs, [K] * len(obs))
    err = lambda s: np.abs(s[model3d.RIGID, 2] - face3d[model3d.RIGID, 2]).mean()
    assert after < 0.5 * before
    assert err(refined) < 0.5 * err(start)
    assert model3d.conditioning(np.array(obs)) > 6.0
    assert err(model3d.factorize(np.array(obs))) < 0.5 * err(start)


def test_conditioning_is_low_without_rotation(face3d):
    rng = np.random.default_rng(4)
    K = intrinsics(640, 480, 1.5)
    obs = [project(face3d, np.zeros(3), np.array([x, y, 700.0]), K) + rng.normal(0, 0.5, (68, 2))
           for x, y in rng.uniform(-20, 20, (60, 2))]
    assert model3d.conditioning(np.array(obs)) < 6.0

"""Starting a new person's LSTM from a base model (stages/train/fine_tune)."""
import numpy as np
import pytest

from pipeline.errors import ParameterError
from stages.train.fine_tune import rebased_readout


def orthonormal_rows(rng, k, n=36):
    q, _ = np.linalg.qr(rng.normal(size=(n, k)))
    return q.T


def test_readout_in_a_rotated_basis_gives_the_same_lip_motion_scaled():
    rng = np.random.default_rng(1)
    base = orthonormal_rows(rng, 20)
    rotation = orthonormal_rows(rng, 20, 20)
    new = rotation @ base                                      # same subspace, other axes and order
    w, b = rng.normal(size=(20, 60)), rng.normal(size=20)
    wn, bn = rebased_readout(w, b, base, new, 1.7)
    h = rng.normal(size=(60, 5))                               # five hidden states
    motion_base = base.T @ (w @ h + b[:, None])                # (36, 5) canonical px of the base store
    motion_new = new.T @ (wn @ h + bn[:, None])
    np.testing.assert_allclose(motion_new, 1.7 * motion_base, atol=1e-4)


def test_readout_in_another_subspace_is_the_projection_of_the_motion():
    rng = np.random.default_rng(2)
    base, new = orthonormal_rows(rng, 20), orthonormal_rows(rng, 8)
    w, b = rng.normal(size=(20, 60)), rng.normal(size=20)
    wn, bn = rebased_readout(w, b, base, new, 1.0)
    assert wn.shape == (8, 60) and bn.shape == (8,)
    h = rng.normal(size=60)
    motion = base.T @ (w @ h + b)
    np.testing.assert_allclose(wn @ h + bn, new @ motion, atol=1e-4)   # least-squares coordinates in the new basis


def test_bases_of_different_shape_vectors_are_refused():
    with pytest.raises(ParameterError, match="different shape vectors"):
        rebased_readout(np.zeros((20, 60)), np.zeros(20), np.zeros((20, 36)), np.zeros((20, 40)), 1.0)

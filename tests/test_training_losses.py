"""The LSTM's loss terms beside the paper's L2: motion (velocity) and inner-lip opening correlation."""
from __future__ import annotations

import dataclasses

import numpy as np
import torch

from pipeline.params import Train
from stages.train.lstm import masked_l2, opening_decorrelation, opening_direction, shape_loss, velocity_l2


def wave(b: int = 3, n: int = 50, k: int = 4, seed: int = 0) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    t = np.arange(n)[None, :, None]
    return torch.tensor(np.sin(0.3 * t + rng.uniform(0, 6, (b, 1, k))) * rng.uniform(1, 3, (b, 1, k)), dtype=torch.float32)


def test_velocity_loss_sees_motion_not_offset():
    y = wave()
    mask = torch.ones(y.shape[:2])
    assert float(velocity_l2(y + 2.0, y, mask)) < 1e-10                 # same motion, shifted shape: no motion error
    still = y.mean(1, keepdim=True).expand_as(y)
    assert float(velocity_l2(still, y, mask)) > 0.01                    # a mouth that does not move: penalised
    assert float(masked_l2(still, y, mask)) > 0


def test_velocity_loss_skips_pairs_with_an_untracked_step():
    y = wave()
    pred = y.clone()
    pred[:, 10] += 100.0                                                # a wild step where the target is untracked
    mask = torch.ones(y.shape[:2])
    mask[:, 10] = 0
    assert float(velocity_l2(pred, y, mask)) < 1e-10


def test_opening_decorrelation_is_scale_free_and_signed():
    y = wave()
    mask = torch.ones(y.shape[:2])
    direction = torch.tensor([1.0, 0.0, 0.5, 0.0])
    assert float(opening_decorrelation(0.3 * y + 1.0, y, mask, direction)) < 1e-5     # a smaller, shifted copy: corr 1
    assert abs(float(opening_decorrelation(-y, y, mask, direction)) - 2.0) < 1e-5     # opposite: corr −1
    pred = torch.zeros_like(y, requires_grad=True)
    loss = opening_decorrelation(pred + 0.01 * wave(seed=1), y, mask, direction)
    loss.backward()
    assert pred.grad is not None and float(pred.grad.abs().sum()) > 0


def test_opening_direction_reads_the_inner_lip_points():
    comps = np.zeros((2, 36))
    comps[0, 16 * 2 + 1] = 1.0                 # component 0 moves point 16 (lower inner lip) down 1 px
    comps[1, 13 * 2 + 1] = 1.0                 # component 1 moves point 13 (upper inner lip) down 1 px
    d = opening_direction({"mean": np.zeros(36), "components": comps})
    np.testing.assert_allclose(d, [1.0, -1.0])


def test_default_loss_is_the_papers_l2():
    y, pred = wave(), wave(seed=3)
    mask = torch.ones(y.shape[:2])
    direction = torch.ones(4)
    p = Train()
    assert float(shape_loss(pred, y, mask, p, direction)) == float(masked_l2(pred, y, mask))
    both = dataclasses.replace(p, velocity_weight=2.0, opening_corr_weight=3.0)
    expected = masked_l2(pred, y, mask) + 2.0 * velocity_l2(pred, y, mask) + 3.0 * opening_decorrelation(pred, y, mask, direction)
    assert abs(float(shape_loss(pred, y, mask, both, direction)) - float(expected)) < 1e-4

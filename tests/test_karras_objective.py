"""Karras et al. 2017 training objective (paper 001 §4.3–§4.5): terms, normalisation, schedule, shifts."""
import math

import numpy as np
import pytest
import torch

from stages.train_karras import objective as obj


def test_terms_follow_eqs_1_to_4():
    y = torch.tensor([[0.0, 0.0], [1.0, 1.0], [2.0, 0.0], [2.0, 0.0]])
    y_hat = torch.tensor([[0.0, 0.0], [0.0, 0.0], [2.0, 1.0], [2.0, 1.0]])
    assert torch.allclose(obj.position_term(y, y_hat), torch.tensor([0.0, 1.0, 0.5, 0.5]))
    # pair 1: true motion (1, 1), predicted (0, 0) → 2 · mean(1, 1) = 2; pair 2: no motion either way → 0
    assert torch.allclose(obj.motion_term(y, y_hat), torch.tensor([2.0, 0.0]))
    e = torch.tensor([[1.0, 1.0], [1.0, 1.0], [1.0, -1.0], [-1.0, 1.0]])
    r = obj.emotion_term(e)
    assert r[0] == 0 and r[1] == pytest.approx(2 * 4 / 1.0)
    # Eq. 4: scaling the emotion vectors does not change the regulariser
    assert torch.allclose(obj.emotion_term(0.01 * e), r)


def test_normaliser_balances_terms_of_any_magnitude():
    rng = np.random.default_rng(0)
    a, b = obj.TermNormaliser(), obj.TermNormaliser()
    for _ in range(300):
        x = torch.tensor(rng.uniform(0.5, 1.5, 50))
        la, lb = a(x), b(1e4 * x)
    assert float(la) == pytest.approx(float(lb), rel=1e-6)     # same value whatever the term's scale
    assert 0.5 < float(la) < 1.5
    # startup bias correction: the first normalised value is mean / rms of the first batch
    c = obj.TermNormaliser()
    x = torch.tensor([1.0, 3.0])
    assert float(c(x)) == pytest.approx(2.0 / math.sqrt(5.0), rel=1e-6)


def test_combined_loss_has_a_gradient_for_every_term():
    y = torch.randn(8, 5)
    w = torch.zeros(8, 5, requires_grad=True)
    e = torch.randn(8, 16, requires_grad=True)
    loss, parts = obj.KarrasLoss()(y, w, e)
    loss.backward()
    assert set(parts) == {"position", "motion", "emotion"}
    assert w.grad.abs().sum() > 0 and e.grad.abs().sum() > 0
    loss2, parts2 = obj.KarrasLoss(use_motion=False, use_emotion=False)(y, w.detach(), e.detach())
    assert set(parts2) == {"position"}


def test_schedule_ramps_up_decays_and_ramps_down_with_beta1():
    lr = lambda ep: obj.schedule(ep, 500, 1e-3)
    assert lr(0.0)[0] == pytest.approx(1e-4) and lr(1.0)[0] == pytest.approx(1e-3)
    assert lr(0.5)[0] == pytest.approx(1e-4 * 10 ** 0.5)                     # geometric
    assert lr(100.0)[0] == pytest.approx(1e-3 / 10) and lr(100.0)[1] == 0.9   # 1/√t
    assert lr(470.0) == pytest.approx((1e-3 / math.sqrt(470), 0.9))
    end = lr(499.999)
    assert end[0] < 1e-8 and end[1] == pytest.approx(0.5, abs=1e-6)
    rates = [lr(e)[0] for e in np.linspace(470, 499.99, 50)]
    assert all(b <= a for a, b in zip(rates, rates[1:]))
    # a short run keeps a third of its epochs for the ramp-down
    assert obj.schedule(6.0, 9, 1e-3)[1] == 0.9 and obj.schedule(8.9, 9, 1e-3)[1] < 0.55


def test_pair_shifts_are_shared_within_pairs_and_bounded():
    s = obj.pair_shifts(50, np.random.default_rng(1))
    assert s.shape == (100,) and (s[0::2] == s[1::2]).all()
    assert np.abs(s).max() <= 0.5 / 30 and np.std(s) > 0.005


def test_shifted_targets_interpolate_linearly():
    t = np.arange(5) / 25.0
    y = np.stack([np.arange(5.0), 10 * np.arange(5.0)], 1)
    out = obj.shifted_targets(y, t, np.array([0.02, 0.1, -1.0, 9.0]))
    assert np.allclose(out, [[0.5, 5.0], [2.5, 25.0], [0.0, 0.0], [4.0, 40.0]])


def test_targets_cover_the_lower_face_and_pairs_need_two_valid_frames():
    from pipeline.face.dlib_face import LIP_POINTS
    from stages.train_karras.targets import FACE_POINTS, LIP_INDEX, training_pairs
    assert len(FACE_POINTS) == 42 and [FACE_POINTS[i] for i in LIP_INDEX] == LIP_POINTS
    assert 8 in FACE_POINTS and 30 in FACE_POINTS          # chin and nose tip move with the face
    videos = [dict(ok=np.array([True, True, False, True, True, True])), dict(ok=np.array([True, False]))]
    assert training_pairs(videos).tolist() == [[0, 0], [0, 3], [0, 4]]


@pytest.mark.slow
def test_fit_learns_a_mapping_from_audio_to_targets():
    """The whole §4 loop (features, pairs, shifts, noise, normalised loss, schedule) learns to tell a
    tone from the noise floor well enough to predict it on a fresh clip (~1 min on 2 cores).
    Four clips (316 pairs, 15 steps of 10 pairs per epoch) for 300 steps = 20 epochs at lr 3e-3. (At the
    paper's 1e-3 this short budget is a lottery: the fresh clip's correlation ranged 0.12–0.95 over seeds and
    CPUs — the network often still predicts the mean at step 300; at 3e-3 it was 0.93–0.98 over five seeds and
    both SIMD levels. Bound 0.8.)"""
    from stages.train_karras.fit import FitConfig, batch_inputs, fit
    fps, sr = 25.0, 16000

    def clip(seed, split):
        r = np.random.default_rng(seed)
        on = np.repeat(np.resize(r.permutation([0, 1]), 4), int(0.8 * sr))   # 3.2 s: alternating 0.8 s of tone / noise floor
        t = np.arange(len(on)) / sr
        audio = on * np.sin(2 * np.pi * 220 * t) + 0.01 * r.standard_normal(len(on))
        ft = np.arange(int(len(on) / sr * fps)) / fps
        level = np.interp(ft, t, on.astype(float))
        return dict(name=f"c{seed}", split=split, samples=audio, frame_time=ft, ok=np.ones(len(ft), bool),
                    targets=np.stack([level, 1 - level, 0.5 * level], 1).astype(np.float32))

    videos = [clip(s, "train") for s in range(4)]
    net, emo, hist = fit(videos, FitConfig(steps=300, val_every=15, batch=20, lr=3e-3, seed=0, emotions=False), progress=False)
    assert emo.shape == (sum(len(v["targets"]) for v in videos), 16)
    assert hist[-1]["position"] < 0.01 * hist[0]["position"], hist
    # the trained network tells tone from noise on a fresh clip
    test = clip(9, "val")
    rows = np.column_stack([np.zeros(len(test["targets"]), int), np.arange(len(test["targets"]))])
    x, y = batch_inputs([test], rows, np.zeros(len(rows)))
    with torch.no_grad():
        out = net(torch.as_tensor(x), torch.zeros(len(rows), 16)).numpy()
    assert np.corrcoef(out[:, 0], y[:, 0])[0, 1] > 0.8

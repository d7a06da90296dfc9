"""Training budgets (pipeline/models/training_budget.py): steps, validation points, early stopping, the plan."""
import logging

import numpy as np
import pytest

from pipeline.errors import ParameterError
from pipeline.models.training_budget import Budget, EarlyStopping, StepPlan, format_duration, plan_text, seeded_subset
from pipeline.params import Train


def test_validation_points_fall_every_val_every_steps_and_on_the_last():
    b = Budget(steps=25, val_every=10)
    assert [s for s in range(1, 26) if b.is_validation_step(s)] == [10, 20, 25]


@pytest.mark.parametrize("kwargs, message", [(dict(steps=0, val_every=1), "steps=0"),
                                             (dict(steps=10, val_every=0), "val_every=0"),
                                             (dict(steps=10, val_every=2, patience=0), "patience=0")])
def test_a_bad_budget_names_the_key(kwargs, message):
    with pytest.raises(ParameterError, match=message):
        Budget(**kwargs).check("train")


def test_early_stopping_waits_patience_flat_points_and_keeps_the_best_state():
    stop = EarlyStopping(Budget(steps=100, val_every=10, patience=2, min_delta=0.01))
    state = {"w": np.zeros(2)}
    curve = [5.0, 4.0, 3.0, 2.999, 3.5]                # 2.999 is not a 1 % gain: flat
    said = []
    for k, v in enumerate(curve):
        state["w"][:] = k
        said.append(stop.update(10 * (k + 1), v, state))
    assert said == [False, False, False, False, True]
    assert stop.best_step == 30 and stop.best_value == 3.0
    assert stop.best_state["w"].tolist() == [2, 2]     # a copy, not the live object
    never = EarlyStopping(Budget(steps=100, val_every=10))
    assert not any(never.update(10 * k, 1.0, None) for k in range(1, 10))


def test_the_plan_names_steps_epochs_and_the_measured_time(caplog):
    b = Budget(steps=3000, val_every=100, patience=5)
    text = plan_text("Karras", b, steps_per_epoch=24, epoch_unit="1,200 frames", seconds_per_step=0.22)
    assert text.startswith("Karras: 3,000 steps (≈ 125.0 epochs of 1,200 frames)") and "early stop after 5" in text
    assert "≈ 11.0 min on this machine" in text
    assert format_duration(42) == "42 s" and format_duration(3 * 3600) == "3.0 h"
    plan = StepPlan("LSTM", Budget(steps=10, val_every=5), 2, "10 s of audio", logging.getLogger("t"), calibrate=3)
    with caplog.at_level(logging.INFO, logger="t"):
        for _ in range(10):
            plan.step_done()
    assert len([r for r in caplog.records if "plan — LSTM: 10 steps" in r.getMessage()]) == 1


def test_lstm_runs_its_step_budget_and_early_stopping_keeps_the_best_weights():
    from stages.train import lstm
    rng = np.random.default_rng(0)
    train = [(rng.normal(size=(200, 3)).astype(np.float32), rng.normal(size=(200, 2)).astype(np.float32),
              np.ones(200, bool)) for _ in range(4)]                          # noise: validation cannot improve for long
    val = [(rng.normal(size=(200, 3)).astype(np.float32), rng.normal(size=(200, 2)).astype(np.float32),
            np.ones(200, bool))]
    p = Train(hidden=8, batch_size=4, bptt=50, lr=0.05, steps=37, val_every=4)
    model, hist, kept = lstm.train(train, val, p, 0, "cpu")
    assert [h["step"] for h in hist] == [4, 8, 12, 16, 20, 24, 28, 32, 36, 37] and kept == 37
    assert hist[0]["epoch"] == pytest.approx(1.0)                             # 800 frames / (4 streams × 50) = 4 steps
    p = Train(hidden=8, batch_size=4, bptt=50, lr=0.05, steps=400, val_every=4, patience=3)
    model, hist, kept = lstm.train(train, val, p, 0, "cpu")
    best = min(hist, key=lambda h: h["val_loss"])
    assert hist[-1]["step"] < 400 and kept == best["step"] and hist[-1]["step"] == kept + 3 * 4
    assert lstm.evaluate_loss(model, val, 0, "cpu") == pytest.approx(best["val_loss"], rel=1e-5)


def test_seeded_subset_first_reaches_the_seconds_and_is_reproducible():
    durations = [3.0] * 28
    assert seeded_subset(durations, None, 0) == list(range(28))
    a = seeded_subset(durations, 20.0, 0)
    assert len(a) == 7 and len(set(a)) == 7                       # 18 s < 20 s ≤ 21 s
    assert a == seeded_subset(durations, 20.0, 0) != seeded_subset(durations, 20.0, 1)
    assert seeded_subset(durations, 40.0, 0)[:7] == a             # a longer budget extends the shorter one
    assert sorted(seeded_subset(durations, 1e9, 0)) == list(range(28))

"""Training budgets: how long a training stage runs, and when it stops early.

Every gradient-trained family (the LSTM, its delay sweep, Karras et al.) runs for a budget of
**optimizer steps**, not epochs and not wall-clock time:

- a step costs one minibatch, whose size is fixed by the params (LSTM: ≤ ``batch_size`` streams ×
  ``bptt`` steps; Karras: ``batch`` samples), so N steps take about the same time on 45 s and on
  17 h of footage — an epoch grows with the corpus (one LSTM step per epoch on the synthetic
  speaker, 21 on GRID s1's 45 min, ~600 on 17 h);
- a wall-clock cap would make the weights depend on the machine's speed and load, and DVC could
  no longer trust its cache (the same inputs must give the same outputs).

On top of the budget, **early stopping** reads the validation curve every ``val_every`` steps (at
fixed steps, so it is deterministic): after ``patience`` validations without an improvement of at
least ``min_delta`` (relative) the run stops, and the weights of the best validation point are
the result. ``patience: null`` runs the whole budget (the papers' fixed schedules).

Before the long part starts, ``StepPlan`` logs the plan with a time estimate measured on this
machine over the first steps, e.g. ``Karras: 3,000 steps (≈ 125 epochs of 1,200 frames),
validation every 100 steps, early stop after 5 flat ≈ 11.0 min on this machine``.
"""
from __future__ import annotations

import copy
import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from pipeline.errors import ParameterError


@dataclass(frozen=True)
class Budget:
    """steps: optimizer steps at most; val_every: steps between validation points; patience:
    validation points without improvement before stopping (None: never); min_delta: relative
    improvement that counts."""
    steps: int
    val_every: int
    patience: int | None = None
    min_delta: float = 0.0

    def check(self, section: str) -> "Budget":
        if not isinstance(self.steps, int) or self.steps < 1:
            raise ParameterError(f"{section}.steps={self.steps!r}: expected a positive number of optimizer steps")
        if not isinstance(self.val_every, int) or self.val_every < 1:
            raise ParameterError(f"{section}.val_every={self.val_every!r}: expected a positive number of steps")
        if self.patience is not None and (not isinstance(self.patience, int) or self.patience < 1):
            raise ParameterError(f"{section}.patience={self.patience!r}: expected a positive count or null")
        return self

    def is_validation_step(self, step: int) -> bool:
        """Validate after ``step`` (1-based) steps: every ``val_every`` and at the last step."""
        return step % self.val_every == 0 or step == self.steps


def format_duration(seconds: float) -> str:
    """'42 s', '3.5 min', '2.4 h'."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def plan_text(name: str, budget: Budget, steps_per_epoch: float, epoch_unit: str,
              seconds_per_step: float | None = None) -> str:
    """One line: the budget, what it is in epochs of this corpus, and (when measured) its time."""
    stop = f", early stop after {budget.patience} flat validations" if budget.patience else ""
    text = (f"{name}: {budget.steps:,} steps (≈ {budget.steps / max(steps_per_epoch, 1e-9):,.1f} epochs of "
            f"{epoch_unit}), validation every {budget.val_every} steps{stop}")
    if seconds_per_step is not None:
        text += (f" ≈ {format_duration(budget.steps * seconds_per_step)} on this machine "
                 f"({seconds_per_step:.3f} s/step measured)")
    return text


class StepPlan:
    """Times the first ``calibrate`` steps, then logs the plan with its time estimate once."""

    def __init__(self, name: str, budget: Budget, steps_per_epoch: float, epoch_unit: str,
                 log: logging.Logger, calibrate: int = 3):
        self.name, self.budget, self.steps_per_epoch, self.epoch_unit = name, budget, steps_per_epoch, epoch_unit
        self.log, self.calibrate = log, max(1, min(calibrate, budget.steps))
        self.t0, self.done, self.seconds_per_step = time.perf_counter(), 0, None

    def step_done(self) -> None:
        """Count one optimizer step; after ``calibrate`` of them, log the plan with their mean time."""
        self.done += 1
        if self.seconds_per_step is None and self.done == self.calibrate:
            self.seconds_per_step = (time.perf_counter() - self.t0) / self.calibrate
            self.log.info("plan — %s", plan_text(self.name, self.budget, self.steps_per_epoch, self.epoch_unit,
                                                 self.seconds_per_step))


class EarlyStopping:
    """Tracks the validation curve; keeps a copy of the best state; says when to stop. (With
    ``patience`` None it never stops, and the caller keeps the last weights: a fixed schedule.)"""

    def __init__(self, budget: Budget):
        self.budget = budget
        self.best_value, self.best_step, self.best_state, self.flat = math.inf, 0, None, 0

    def update(self, step: int, value: float, state) -> bool:
        """Record the validation ``value`` after ``step``; ``state`` (any object: state dicts,
        tensors) is deep-copied when it is the best so far and ``patience`` is set (the caller then
        restores it). True when the run should stop."""
        if not math.isfinite(value):
            return False
        if value < self.best_value * (1 - self.budget.min_delta) or self.best_step == 0:
            # the copy is only needed when the run may stop early and go back to it
            kept = copy.deepcopy(state) if self.budget.patience is not None else None
            self.best_value, self.best_step, self.best_state, self.flat = value, step, kept, 0
            return False
        self.flat += 1
        return self.budget.patience is not None and self.flat >= self.budget.patience


def seeded_subset(durations: list[float], seconds: float | None, seed: int) -> list[int]:
    """Indices of a seeded random subset of videos whose durations (s) first reach ``seconds``
    (all indices, in order, when ``seconds`` is None or 0): the short-footage regimes of papers
    001 (3–5 min) and 002 (about 60 s), and learning curves."""
    if not seconds:
        return list(range(len(durations)))
    out, total = [], 0.0
    for i in np.random.default_rng(seed).permutation(len(durations)):
        if total >= seconds:
            break
        out.append(int(i))
        total += durations[i]
    return out

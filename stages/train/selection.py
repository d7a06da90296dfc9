"""Which personalization candidate to keep: k-fold figures over the person's segments, a score that
follows the lips, and a change from the base only when it is more than noise (issue 47).

Pure functions (no I/O, no models): ``adapt`` fits and scores the candidates fold by fold and hands
the figures here.

* ``fold_plan`` — the person's segments (time order) in ``k`` contiguous blocks; each block is held out
  once while the candidates are fitted on the rest.
* ``utility`` — one number per fold and candidate: opening correlation at lag 0 plus the share of the
  mean shape's mouth error removed, ``corr + (1 − ratio)``. The error alone kept a read-out whose
  opening barely followed the speech (corr 0.39 against 0.65) because its mean error was 3 % lower.
* ``beats`` — a candidate replaces the base only if its per-fold gain over the base has a positive
  mean more than ``z`` standard errors above 0 (paired over the same folds).
"""
from __future__ import annotations

import numpy as np

Z_NOISE = 1.0            # standard errors the mean per-fold gain must clear
FOLDS = 5                # blocks of segments (fewer when the footage has fewer segments)


def fold_plan(n_segments: int, k: int) -> list[np.ndarray]:
    """Indices (into the time-ordered segments) held out by each of ``min(k, n_segments)`` folds:
    contiguous blocks of near-equal size covering every segment once."""
    if n_segments < 2:
        raise ValueError(f"{n_segments} segment(s): k-fold selection needs at least 2")
    k = max(2, min(int(k), n_segments))
    return [np.asarray(b, int) for b in np.array_split(np.arange(n_segments), k)]


def utility(corr: float, ratio: float) -> float:
    """Opening correlation at lag 0 plus the share of the mean shape's error removed (``1 − ratio``);
    a fold without a correlation (a mouth that never moved) counts as 0 correlation."""
    corr = 0.0 if corr is None or not np.isfinite(corr) else float(corr)
    return corr + (1.0 - float(ratio))


def beats(gains, z: float = Z_NOISE) -> bool:
    """Is the mean of per-fold ``gains`` (candidate − base) above 0 by more than ``z`` standard errors?"""
    g = np.asarray(gains, np.float64)
    g = g[np.isfinite(g)]
    if len(g) < 2:
        return False
    se = g.std(ddof=1) / np.sqrt(len(g))
    return bool(g.mean() > 0 and g.mean() - z * se > 0)


def choose(per_fold: dict[str, list[float]], base: str = "base", z: float = Z_NOISE) -> tuple[str, dict]:
    """The kept candidate from per-fold utilities ``{name: [u_1 … u_k]}`` (same folds for all).

    Among the candidates that beat ``base`` beyond noise (``beats``), the one with the highest mean
    utility; none: ``base``. Returns (name, {name: dict(mean, gain, gain_se, beats_base)})."""
    ref = np.asarray(per_fold[base], np.float64)
    table = {}
    for name, us in per_fold.items():
        u = np.asarray(us, np.float64)
        gain = u - ref
        se = float(gain.std(ddof=1) / np.sqrt(len(gain))) if len(gain) > 1 else float("nan")
        table[name] = dict(mean=float(u.mean()), gain=float(gain.mean()), gain_se=se,
                           beats_base=name != base and beats(gain, z))
    winners = [n for n, t in table.items() if t["beats_base"]]
    return (max(winners, key=lambda n: table[n]["mean"]) if winners else base), table

"""Speech flags A(i) for re-timing (paper 000 §3.3): which output frames carry speech.

A frame is speech when its audio level (RMS in the frame's window, dB relative to the clip's loudest 10 ms) is above
a threshold that adapts to the clip's noise floor; the raw flags are cleaned (short gaps joined, short blips dropped,
speech dilated a little) so the re-timing's onsets are the utterances' starts. Used by ``stages.synthesize.retime``.
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.errors import ParameterError


REFERENCE_WINDOW_S = 0.010      # speech level is relative to the clip's loudest 10 ms window
SILENT_PEAK_DBFS = -80.0        # a clip whose loudest 10 ms window is below this is all silence
NOISE_FLOOR_PERCENTILE = 10     # the noise floor is this percentile of the frame levels
MAX_ADAPTIVE_DB = -15.0         # the noise-floor rule never raises the threshold above this


# ---------------------------------------------------------------- A(i): speech flags

def speech_flags(samples: np.ndarray, sample_rate: float, fps: float, n_frames: int,
                 threshold_db: float = -35.0, join_gap_s: float = 0.5, dilate_s: float = 0.1,
                 min_run_s: float = 0.1, noise_margin_db: float | None = 12.0) -> np.ndarray:
    """A(i): is output frame i (time i / fps) inside speech?

    A frame is speech when the RMS level of the audio in its period [(i − ½)/fps, (i + ½)/fps)
    is above a threshold relative to the clip's loudest 10 ms window (so the result does not
    depend on recording gain; a clip whose loudest window is below −80 dBFS is all silence).
    The threshold is ``threshold_db``, raised to ``noise_margin_db`` above the clip's noise floor
    (10th percentile of the frame levels) when that is higher, but by this rule never above
    −15 dB (see ``speech_threshold_db``): recordings whose pauses hold room noise at −27…−38 dB
    (GRID, HDTF) would otherwise be all speech at −35 dB.
    The raw flags are then cleaned as in the paper, in this order:

    1. closing: silent gaps between speech shorter than ``join_gap_s`` become speech
       (leading and trailing silence are not gaps and stay);
    2. speech runs shorter than ``min_run_s`` (clicks, breaths) become silence;
    3. dilation: every speech run grows by ``dilate_s`` on both sides;
    4. silent gaps shorter than ``min_run_s`` left by the dilation become speech.

    The second threshold is applied to speech runs before the dilation — after it every run is at
    least 2·dilate_s long and the threshold would do nothing.

    Parameters
    ----------
    samples : (S,) or (S, C) float, full scale ±1 (channels are averaged).
    sample_rate : Hz.
    fps : output video frame rate (frames/s).
    n_frames : N, number of output frames; frames past the end of the audio are silent.
    threshold_db : dB relative to the loudest 10 ms window; the lowest threshold used.
    join_gap_s, dilate_s, min_run_s : seconds.
    noise_margin_db : dB above the noise floor; None uses ``threshold_db`` alone.

    Returns
    -------
    (N,) bool.
    """
    _require_positive(sample_rate=sample_rate, fps=fps)
    _require_non_negative(n_frames=n_frames, join_gap_s=join_gap_s, dilate_s=dilate_s,
                          min_run_s=min_run_s)
    x = np.asarray(samples, np.float64)
    if x.ndim == 2:
        x = x.mean(axis=1)
    if x.ndim != 1:
        raise ParameterError(f"samples: expected shape (S,) or (S, C), got {x.shape}")
    level = frame_level_db(x, sample_rate, fps, int(n_frames))
    raw = level > speech_threshold_db(level, threshold_db, noise_margin_db)
    return clean_flags(raw, fps, join_gap_s, dilate_s, min_run_s)


def speech_threshold_db(level: np.ndarray, threshold_db: float = -35.0,
                        noise_margin_db: float | None = 12.0) -> float:
    """The speech threshold for a clip: max(threshold_db, min(floor + noise_margin_db, −15)).

    Parameters
    ----------
    level : (N,) frame levels, dB relative to the loudest 10 ms window (``frame_level_db``).
    threshold_db : dB, the lowest threshold.
    noise_margin_db : dB above the noise floor (the 10th percentile of ``level``; −inf when
        that many frames are digital silence); None disables the rule.

    Returns
    -------
    float dB.
    """
    if noise_margin_db is None or level.size == 0:
        return float(threshold_db)
    floor = np.percentile(level, NOISE_FLOOR_PERCENTILE, method="lower")
    return float(max(threshold_db, min(floor + noise_margin_db, MAX_ADAPTIVE_DB)))


def frame_level_db(samples: np.ndarray, sample_rate: float, fps: float, n_frames: int) -> np.ndarray:
    """RMS level of each video frame's audio period, dB relative to the loudest 10 ms window.

    Parameters
    ----------
    samples : (S,) float mono, full scale ±1.
    sample_rate, fps : Hz, frames/s.
    n_frames : N.

    Returns
    -------
    (N,) float dB (≤ ~0); −inf for digital silence, frames past the audio, or a silent clip.
    """
    x = np.asarray(samples, np.float64)
    level = np.full(n_frames, -np.inf)
    if x.size == 0 or n_frames == 0:
        return level
    energy = np.concatenate([[0.0], np.cumsum(x * x)])
    w = min(x.size, max(1, int(round(REFERENCE_WINDOW_S * sample_rate))))
    peak = np.max(energy[w:] - energy[:-w]) / w
    if peak <= 10.0 ** (SILENT_PEAK_DBFS / 10.0):
        return level
    centre = np.arange(n_frames) / fps
    lo = np.clip(np.round((centre - 0.5 / fps) * sample_rate).astype(np.int64), 0, x.size)
    hi = np.clip(np.round((centre + 0.5 / fps) * sample_rate).astype(np.int64), 0, x.size)
    count = hi - lo
    power = np.maximum(energy[hi] - energy[lo], 0.0) / np.maximum(count, 1)
    with np.errstate(divide="ignore"):
        return np.where(count > 0, 10.0 * np.log10(power / peak), -np.inf)


def clean_flags(raw: np.ndarray, fps: float, join_gap_s: float = 0.5, dilate_s: float = 0.1,
                min_run_s: float = 0.1) -> np.ndarray:
    """The paper's salt-and-pepper cleanup of per-frame speech flags (see ``speech_flags``).

    Parameters
    ----------
    raw : (N,) bool.
    fps : frames/s; the durations below are converted with it.
    join_gap_s, dilate_s, min_run_s : seconds.

    Returns
    -------
    (N,) bool.
    """
    gap_max = _frames_shorter_than(join_gap_s, fps)
    run_max = _frames_shorter_than(min_run_s, fps)
    flags = _flip_short_runs(np.asarray(raw, bool), False, gap_max, interior_only=True)
    flags = _flip_short_runs(flags, True, run_max, interior_only=False)
    flags = _dilate(flags, int(round(dilate_s * fps)))
    return _flip_short_runs(flags, False, run_max, interior_only=True)


def _require_positive(**values: float) -> None:
    for name, value in values.items():
        if not (np.isfinite(value) and value > 0):
            raise ParameterError(f"{name}={value}: must be a positive number")


def _require_non_negative(**values: float) -> None:
    for name, value in values.items():
        if not (np.isfinite(value) and value >= 0):
            raise ParameterError(f"{name}={value}: must be a non-negative number")


def _frames_shorter_than(seconds: float, fps: float) -> int:
    """Largest run length (frames) that lasts strictly less than ``seconds``."""
    return max(0, math.ceil(seconds * fps - 1e-9) - 1)


def _runs(flags: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run-length encoding of a 1-D bool array: (starts, lengths, values)."""
    if flags.size == 0:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0, bool)
    starts = np.concatenate([[0], np.flatnonzero(flags[1:] != flags[:-1]) + 1])
    lengths = np.diff(np.concatenate([starts, [flags.size]]))
    return starts, lengths, flags[starts]


def _flip_short_runs(flags: np.ndarray, value: bool, max_len: int, interior_only: bool) -> np.ndarray:
    """Invert runs of ``value`` at most ``max_len`` long (only runs with neighbours on both
    sides if ``interior_only``)."""
    out = flags.copy()
    starts, lengths, values = _runs(flags)
    for k in np.flatnonzero((values == value) & (lengths <= max_len)):
        if interior_only and (k == 0 or k == len(starts) - 1):
            continue
        out[starts[k]:starts[k] + lengths[k]] = not value
    return out


def _dilate(flags: np.ndarray, radius: int) -> np.ndarray:
    """Grow every True run by ``radius`` frames on both sides."""
    if radius <= 0 or flags.size == 0:
        return flags.copy()
    return np.convolve(flags.astype(np.int32), np.ones(2 * radius + 1, np.int32), mode="same") > 0

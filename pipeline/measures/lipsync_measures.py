"""Lip-sync quality measures of a synthesized video against the original (paper 000 §4.1, "Video J").

A clip used as its own target with its own audio and no re-timing has a ground truth: the
original frames. Given landmarks (N, 68, 2) and grey frames (N, H, W) of both videos, these pure
functions compare them: mouth landmark error next to a static mouth, inner-lip opening and its
correlation and best lag, mouth-region mean absolute difference, sharpness and flicker. The pixel
measures use the mouth region, a box around the original's lip landmarks.

Two measures look at the fine detail only, the band a weighted median loses: ``detail_energy``
(mean power of the high-pass band, wavelengths below ≈ IOD/8) and ``detail_flicker`` (that band's
change between consecutive frames after motion compensation by DIS optical flow, so that a mouth
that moves is not counted as flicker). The band scales with the face (σ = IOD/50), so the same
measure applies at 256² and at 4K.

Used by the ``evaluate`` stage and by ``lipsynth.lipsync_quality`` (benchmarks).
"""
from __future__ import annotations

import numpy as np

from pipeline.face.dlib_face import MOUTH as LIPS, interocular

UPPER_INNER_LIP, LOWER_INNER_LIP = [61, 62, 63], [67, 66, 65]      # facing pairs of the inner lip


def mouth_error(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N,) mean distance over the 20 lip landmarks, px."""
    return np.linalg.norm(pred[:, LIPS] - truth[:, LIPS], axis=-1).mean(-1)


def static_mouth(truth: np.ndarray) -> np.ndarray:
    """The baseline: every frame's lips replaced by the clip's median lip shape relative to the nose
    bridge (landmark 27), i.e. a mouth that does not move. (N, 68, 2)."""
    rel = truth[:, LIPS] - truth[:, 27:28]
    out = truth.copy()
    out[:, LIPS] = np.median(rel, axis=0) + truth[:, 27:28]
    return out


def inner_opening(lms: np.ndarray) -> np.ndarray:
    """(N,) inner-lip opening: mean vertical gap between the inner upper and lower lip, px."""
    return (lms[:, LOWER_INNER_LIP, 1] - lms[:, UPPER_INNER_LIP, 1]).mean(-1)


def mouth_boxes(truth: np.ndarray, shape: tuple, margin: float = 0.35) -> np.ndarray:
    """(N, 4) int boxes x0, y0, x1, y1 around the lips, grown by ``margin`` × the mouth width."""
    lo, hi = truth[:, LIPS].min(1), truth[:, LIPS].max(1)
    pad = margin * (hi[:, 0] - lo[:, 0])[:, None]
    h, w = shape[:2]
    b = np.hstack([np.floor(lo - pad), np.ceil(hi + pad)]).astype(int)
    return np.clip(b, 0, [w, h, w, h])


def one_box(boxes: np.ndarray) -> tuple[int, int, int, int]:
    """The union of per-frame boxes: one fixed region for temporal measures."""
    return int(boxes[:, 0].min()), int(boxes[:, 1].min()), int(boxes[:, 2].max()), int(boxes[:, 3].max())


def mean_abs_difference(a: np.ndarray, b: np.ndarray, box) -> float:
    """Mean |a − b| over frames (N, H, W) in the box, grey levels."""
    x0, y0, x1, y1 = box
    return float(np.abs(a[:, y0:y1, x0:x1].astype(np.float64) - b[:, y0:y1, x0:x1]).mean())


def sharpness(frames: np.ndarray, box) -> float:
    """Median over frames of the variance of the Laplacian in the box (grey levels²)."""
    import cv2
    x0, y0, x1, y1 = box
    return float(np.median([cv2.Laplacian(f[y0:y1, x0:x1].astype(np.float64), cv2.CV_64F).var() for f in frames]))


def flicker(frames: np.ndarray, box) -> float:
    """Mean absolute temporal difference of consecutive frames in the box, grey levels."""
    x0, y0, x1, y1 = box
    crop = frames[:, y0:y1, x0:x1].astype(np.float64)
    return float(np.abs(np.diff(crop, axis=0)).mean())


def detail_band(frame: np.ndarray, sigma: float) -> np.ndarray:
    """High-pass band (float32, grey levels) of a grey image: the image minus its Gaussian blur (σ px)."""
    import cv2
    x = frame.astype(np.float32)
    return x - cv2.GaussianBlur(x, (0, 0), sigma)


def detail_energy(frames: np.ndarray, box, sigma: float) -> float:
    """Median over frames of the mean squared ``detail_band`` in the box (grey levels²).

    The band is taken on the whole frame, then cropped (no edge effects at the box)."""
    x0, y0, x1, y1 = box
    return float(np.median([np.mean(detail_band(f, sigma)[y0:y1, x0:x1] ** 2) for f in frames]))


def detail_flicker(frames: np.ndarray, box, sigma: float) -> float:
    """Mean over consecutive frames of mean |band(t+1) − band(t) moved by the flow t → t+1| in the box.

    The flow (DIS, on the box's grey crop grown by a margin, smoothed by σ) follows the mouth's
    motion, so what remains is detail that appears, vanishes or jitters: temporal noise."""
    import cv2
    x0, y0, x1, y1 = box
    m = int(np.ceil(4 * sigma)) + 4
    h, w = frames.shape[1:3]
    a0, b0, a1, b1 = max(x0 - m, 0), max(y0 - m, 0), min(x1 + m, w), min(y1 + m, h)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    gy, gx = np.mgrid[b0:b1, a0:a1].astype(np.float32)
    gx -= a0
    gy -= b0
    out = []
    prev = None
    for f in frames:
        crop = f[b0:b1, a0:a1]
        band = detail_band(crop, sigma)
        smooth = cv2.GaussianBlur(crop, (0, 0), max(sigma, 0.5))
        if prev is not None:
            flow = dis.calc(smooth, prev[1], None)        # smooth(p) ≈ prev(p + flow(p))
            moved = cv2.remap(prev[0], gx + flow[..., 0], gy + flow[..., 1], cv2.INTER_CUBIC,
                              borderMode=cv2.BORDER_REPLICATE)
            inner = (slice(y0 - b0, y1 - b0), slice(x0 - a0, x1 - a0))
            out.append(float(np.abs(band[inner] - moved[inner]).mean()))
        prev = (band, smooth)
    return float(np.mean(out)) if out else float("nan")


def best_lag(a: np.ndarray, b: np.ndarray, max_lag: int = 5) -> int:
    """Lag (frames) in ±``max_lag`` maximising the correlation of a[t + lag] with b[t] (NaN = missing)."""
    best, score = 0, -np.inf
    for lag in range(-max_lag, max_lag + 1):
        x = a[max(lag, 0):len(a) + min(lag, 0)]
        y = b[max(-lag, 0):len(b) + min(-lag, 0)]
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.sum() > 5 and x[ok].std() > 0 and y[ok].std() > 0:
            c = np.corrcoef(x[ok], y[ok])[0, 1]
            if c > score:
                best, score = lag, c
    return best


def audio_envelope(samples: np.ndarray, fps: float, n_frames: int, sample_rate: int = 16000) -> np.ndarray:
    """(n_frames,) log RMS (dB) of the 300 Hz–3 kHz speech band over each video frame's period.

    Frame k covers [k, k + 1) / fps seconds; a frame past the audio's end is NaN."""
    from scipy.signal import butter, sosfiltfilt
    x = np.asarray(samples, np.float64)
    if len(x) > 30:
        x = sosfiltfilt(butter(4, [300, 3000], btype="band", fs=sample_rate, output="sos"), x)
    out = np.full(n_frames, np.nan)
    for k in range(n_frames):
        a, b = int(k * sample_rate / fps), int((k + 1) * sample_rate / fps)
        if b <= len(x):
            out[k] = 10 * np.log10(np.mean(x[a:b] ** 2) + 1e-10)
    return out


def source_offset(samples: np.ndarray, opening: np.ndarray, ok: np.ndarray, fps: float, max_lag: int = 5) -> dict:
    """Audio–video offset of a source clip itself, no model: the lag (frames, + = the mouth opens
    after the sound) in ±``max_lag`` at which the speech-band envelope best correlates with the tracked
    inner-lip opening, and that correlation. A clip whose own offset is far from 0 is out of sync at
    the source, so a model's lag on it is not the model's error."""
    env = audio_envelope(samples, fps, len(opening))
    op = np.where(ok, opening, np.nan)
    lag = best_lag(op, env, max_lag)
    x, y = op[max(lag, 0):len(op) + min(lag, 0)], env[max(-lag, 0):len(env) + min(-lag, 0)]
    both = np.isfinite(x) & np.isfinite(y)
    corr = float(np.corrcoef(x[both], y[both])[0, 1]) if both.sum() > 5 else float("nan")
    return dict(offset_frames=int(lag), envelope_corr=corr)


def compare(out_gray: np.ndarray, out_lm: np.ndarray, out_ok: np.ndarray,
            ref_gray: np.ndarray, ref_lm: np.ndarray, ref_ok: np.ndarray) -> dict:
    """All measures of an output video against its original (same length, same timing)."""
    n = min(len(out_gray), len(ref_gray))
    ok = out_ok[:n] & ref_ok[:n]
    if ok.sum() < 10:
        raise ValueError(f"landmarks found on both videos in only {int(ok.sum())} frames")
    o, r = out_lm[:n][ok], ref_lm[:n][ok]
    iod = np.median(interocular(r))
    err, static = mouth_error(o, r), mouth_error(static_mouth(r), r)
    box = one_box(mouth_boxes(ref_lm[:n][ref_ok[:n]], ref_gray.shape[1:]))
    op_o, op_r = inner_opening(o), inner_opening(r)
    seq_o, seq_r = np.full(n, np.nan), np.full(n, np.nan)
    seq_o[ok], seq_r[ok] = op_o, op_r
    sharp_o, sharp_r = sharpness(out_gray[:n], box), sharpness(ref_gray[:n], box)
    flick_o, flick_r = flicker(out_gray[:n], box), flicker(ref_gray[:n], box)
    band = iod / 50                                        # px: the detail band scales with the face
    energy_o, energy_r = detail_energy(out_gray[:n], box, band), detail_energy(ref_gray[:n], box, band)
    dflick_o, dflick_r = detail_flicker(out_gray[:n], box, band), detail_flicker(ref_gray[:n], box, band)
    return {
        "frames": int(n), "frames_with_landmarks": int(ok.sum()), "interocular_px": float(iod),
        "mouth_error_px": float(err.mean()), "mouth_error_iod_pct": float(100 * err.mean() / iod),
        "static_mouth_error_px": float(static.mean()), "static_mouth_error_iod_pct": float(100 * static.mean() / iod),
        "opening_corr": float(np.corrcoef(op_o, op_r)[0, 1]) if op_r.std() > 0 and op_o.std() > 0 else float("nan"),
        "opening_best_lag": best_lag(seq_o, seq_r),
        "mouth_mad": mean_abs_difference(out_gray[:n], ref_gray[:n], box),
        "sharpness_ratio": sharp_o / sharp_r, "flicker_ratio": flick_o / flick_r, "mouth_box": list(box),
        "detail_energy_ratio": energy_o / energy_r, "detail_flicker_ratio": dflick_o / dflick_r,
    }

"""Do the synthesized teeth look like the speaker's real teeth? (paper 000 §3.2.2, issue 9 item 5)

For an output video and its target video, dlib finds the inner lip (60–67) in every frame; inside
it, teeth pixels are the bright, unsaturated ones (HSV S ≤ 0.45, V ≥ 0.45, as in the teeth proxy).
Frames where teeth cover ≥ 15 % of an open mouth are "teeth frames"; over them, per video:

    brightness   median V of the teeth pixels (0–255)
    contrast     median standard deviation of the grey level inside the inner lip
    detail       median Laplacian energy (mean squared Laplacian of grey) inside the inner lip

and each is printed as output / target (goal: within ±20 %, i.e. 0.8–1.2).

    python bench/teeth.py OUTPUT.mp4 TARGET.mp4 [OUTPUT2.mp4 TARGET2.mp4 ...] [--png strip.png]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import cv2
import numpy as np


from pipeline.io import media
from pipeline.face import dlib_face


def teeth_measures(path) -> dict:
    """Per-video medians over teeth frames (see module doc) and the teeth frames' indices."""
    rows, idx = [], []
    box = None
    for k, (_, rgb) in enumerate(media.iter_frames(path)):
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        if box is None or k % 10 == 0:
            found = dlib_face.detect_face(gray, 1)
            box = None if found is None else found[0]
        if box is None:
            continue
        lm = dlib_face.predict_landmarks(gray, box)
        inner = np.round(lm[60:68]).astype(np.int32)
        mask = np.zeros(gray.shape, np.uint8)
        cv2.fillPoly(mask, [inner], 1)
        inside = mask.astype(bool)
        if inside.sum() < 30:
            continue
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        teeth = inside & (hsv[..., 1] <= 0.45 * 255) & (hsv[..., 2] >= 0.45 * 255)
        if teeth.sum() < 0.15 * inside.sum():
            continue
        lap = cv2.Laplacian(gray.astype(np.float32), cv2.CV_32F)
        rows.append((np.median(hsv[..., 2][teeth]), gray[inside].std(), np.mean(lap[inside] ** 2)))
        idx.append(k)
    if not rows:
        return dict(teeth_frames=0)
    r = np.asarray(rows)
    return dict(teeth_frames=len(rows), brightness=float(np.median(r[:, 0])), contrast=float(np.median(r[:, 1])),
                detail=float(np.median(r[:, 2])), frames=idx)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pairs", nargs="+", help="OUTPUT TARGET pairs")
    a = ap.parse_args()
    if len(a.pairs) % 2:
        ap.error("give OUTPUT TARGET pairs")
    ratios = []
    for out, tgt in zip(a.pairs[::2], a.pairs[1::2]):
        o, t = teeth_measures(out), teeth_measures(tgt)
        if not o["teeth_frames"] or not t["teeth_frames"]:
            print(f"{Path(out).name}: teeth frames output {o['teeth_frames']}, target {t['teeth_frames']} — skipped")
            continue
        r = {k: o[k] / t[k] for k in ("brightness", "contrast", "detail")}
        ratios.append(r)
        print(f"{Path(out).name} vs {Path(tgt).name}: teeth frames {o['teeth_frames']} / {t['teeth_frames']}; "
              + ", ".join(f"{k} {o[k]:.1f} / {t[k]:.1f} = {r[k]:.2f}" for k in r))
    if ratios:
        print("median ratio (output / target):",
              ", ".join(f"{k} {np.median([r[k] for r in ratios]):.2f}" for k in ratios[0]))


if __name__ == "__main__":
    main()

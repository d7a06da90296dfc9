"""Lip sync of a model on speakers it was not trained on: real clips with their own audio.

For every clip, the model's predicted inner-lip opening (from the clip's audio) is correlated
with the opening tracked on the clip's own video (the pipeline's landmark tracker). A model
that learned its speaker's acoustics rather than speech shows a low correlation here.

    python bench/cross_speaker.py --model runs/grid_s1/models/lstm

Clips: ../shared/data/obama/obama_0*.mp4 (720p, 29.97 fps) and the two HDTF clips (512², 25 fps).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lipsynth import lipsync_quality as quality  # noqa: E402
from pipeline import media  # noqa: E402
from pipeline.face import LIP_POINTS  # noqa: E402
from pipeline.mouth_prediction import load_audio, predict_mouth  # noqa: E402
from pipeline.params import load_params  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"
TOP, BOTTOM = [LIP_POINTS.index(k) for k in (61, 62, 63)], [LIP_POINTS.index(k) for k in (67, 66, 65)]


def best_lag(a: np.ndarray, b: np.ndarray, max_lag: int = 5) -> tuple[int, float]:
    """Lag (frames, + = prediction late) maximising the correlation, and that correlation."""
    best = (0, -1.0)
    for lag in range(-max_lag, max_lag + 1):
        x, y = a[max(lag, 0):len(a) + min(lag, 0)], b[max(-lag, 0):len(b) + min(-lag, 0)]
        c = float(np.corrcoef(x, y)[0, 1])
        best = max(best, (lag, c), key=lambda t: t[1])
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", action="append", required=True, help="model folder (repeatable)")
    a = ap.parse_args()
    lp = load_params(ROOT / "params.yaml").landmarks
    clips = sorted((SHARED / "obama").glob("obama_0*.mp4")) + sorted((SHARED / "hdtf").glob("WDA_*.mp4"))
    tracked = {}
    for clip in clips:
        _, lms, ok = quality.video_landmarks(clip, lp)
        iod = np.median(quality.interocular(lms[ok])) if ok.any() else 1.0
        tracked[clip] = (quality.inner_opening(lms) / iod, ok, media.probe(clip).fps)
    for model in a.model:
        corr0, corrs = [], []
        print(f"\n{model}")
        for clip in clips:
            truth, ok, fps = tracked[clip]
            if ok.mean() < 0.5:
                print(f"  {clip.name:<34} face tracked in only {ok.mean():.0%} of the frames: skipped")
                continue
            m = predict_mouth(load_audio(clip), model, fps)
            pred = (m["lip_points"][:, BOTTOM, 1] - m["lip_points"][:, TOP, 1]).mean(1)
            n = min(len(pred), len(truth))
            keep = ok[:n]
            c0 = float(np.corrcoef(pred[:n][keep], truth[:n][keep])[0, 1])
            lag, c = best_lag(pred[:n], truth[:n])
            corr0.append(c0); corrs.append(c)
            print(f"  {clip.name:<34} opening corr at lag 0: {c0:+.3f}   best {c:+.3f} at {lag:+d} frames")
        print(f"  median corr at lag 0: {np.median(corr0):+.3f}   median best: {np.median(corrs):+.3f}")


if __name__ == "__main__":
    main()

"""Where does `lipsynth speak` lose what the model knows? The inner-lip opening followed stage by stage.

    python bench/speak_stages.py --model runs/diagnosis/lieu/model --audio HELD_OUT.mp4 --target HELD_OUT.mp4 \
        [--reference WORDS.mp4] [--set synthesize.detail=aligned ...] [--json out.json]

Runs the path `lipsynth speak --no-retime` runs (``lipsynth.speak.prepare``, ``synthesize.run``,
``composite.run``) but keeps the synthesis store, and compares four openings with the reference's
(dlib on the footage that said the words: ``--reference``, by default the audio file, which must then
be a video):

1. ``model`` — the predicted lip points (what the model knows; ``lipsynth predict-mouth``);
2. ``wanted`` — the lip points the texture was asked for (after any re-targeting onto the target's mouth);
3. ``candidates`` — the weight-averaged lip points of the chosen candidates (§3.2.3): what the weighted
   median shows, before the detail and the composite;
4. ``output`` — dlib re-tracking the written MP4 (what a user gets).

Per stage: the opening correlation with the reference at lag 0 and the best lag within ±5 frames, the
correlation with the model's own prediction, and the opening's spread (std) in inter-ocular units over
the reference's. The stage where the correlation drops is the one that loses it. Beside them, how the output's
mouth looks against the target's own (``lipsynth.lipsync_quality.compare``: sharpness, flicker, detail energy
and detail flicker ratios; 1 = as the real mouth).
"""
from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np
import yaml

from lipsynth import lipsync_quality as quality
from lipsynth import speak as speak_app
from pipeline.face.dlib_face import IOD_MM, LIP_POINTS
from pipeline.io.store import open_group
from pipeline.params import load_params, parse
from stages.composite import composite
from stages.synthesize import synthesize
from stages.synthesize.texture_pool import read_pool

ROOT = Path(__file__).resolve().parents[1]
#: rows of the 18 ``LIP_POINTS`` (48–59, 61–63, 65–67) that are the dlib inner lips 61–63 and 65–67
UPPER18, LOWER18 = [12, 13, 14], [17, 16, 15]


def opening18(pts: np.ndarray) -> np.ndarray:
    """(N, 18, 2) lip points → (N,) inner-lip opening, the mean vertical gap of 61–63 / 67–65 (as dlib's
    ``inner_opening``), in the points' units."""
    return (pts[:, LOWER18, 1] - pts[:, UPPER18, 1]).mean(-1)


def corr(a: np.ndarray, b: np.ndarray, lag: int = 0) -> float:
    """Pearson correlation of a[t + lag] with b[t] over the frames where both are finite."""
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    if lag > 0:
        a, b = a[lag:], b[:n - lag]
    elif lag < 0:
        a, b = a[:lag], b[-lag:]
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 10 or a[ok].std() == 0 or b[ok].std() == 0:
        return float("nan")
    return float(np.corrcoef(a[ok], b[ok])[0, 1])


def stage_row(x: np.ndarray, ref: np.ndarray, model: np.ndarray, x_iod: float, ref_iod: float) -> dict:
    lags = {lag: corr(x, ref, lag) for lag in range(-5, 6)}
    best = max(lags, key=lambda k: -np.inf if np.isnan(lags[k]) else lags[k])
    return dict(corr=lags[0], corr_best=lags[best], best_lag=best, corr_model=corr(x, model),
                spread=float(np.nanstd(x) / x_iod / (np.nanstd(ref) / ref_iod)))


def run(model: str, audio: str, target: str, reference: str, params_path: str, sets: list[str], cache: Path | None,
        keep: Path | None = None) -> dict:
    raw = yaml.safe_load(Path(params_path).read_text())
    for item in sets:
        key, _, value = item.partition("=")
        section, _, name = key.partition(".")
        raw[section] = dict(raw[section], **{name: yaml.safe_load(value)})
    params = parse(raw) if sets else load_params(params_path)
    prep = speak_app.prepare(audio, target, params, model, retime=False, cache=cache)
    work = Path(tempfile.mkdtemp(prefix="speak_stages-"))
    try:
        store = str(work / "synthesize.zarr")
        synthesize.run(prep.params, store, prep.stores, prep.entry, mouth=prep.mouth)
        out = str((keep or work) / "out.mp4") if keep else str(work / "out.mp4")
        composite.run(prep.params, store, out, prep.params.frontalize.out, target, audio)
        g = open_group(store)
        wanted = np.asarray(g["lip_points"][...], np.float64)
        pool_shapes = read_pool(prep.stores, prep.entry, prep.params.synthesize)[3][:, LIP_POINTS]
        cand = np.asarray(g["candidate_landmarks"][...], np.float64)[:, LIP_POINTS]
        tex_iod = IOD_MM / prep.stores["frontalize"].attrs["texture_window"]["mm_per_px"]
        mouth = prep.mouth or synthesize.predicted_lips(np.zeros(1), prep.stores, prep.entry, prep.params.synthesize, None)[1]
        predicted = mouth["lip_points"].astype(np.float64)
        lm_params = prep.params.landmarks
        _, ref_lm, ref_ok = quality.video_landmarks(reference, lm_params)
        out_gray, out_lm, out_ok = quality.video_landmarks(out, lm_params)
        look = quality.compare(out_gray, out_lm, out_ok, *quality.video_landmarks(target, lm_params))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    ref = np.where(ref_ok, quality.inner_opening(ref_lm), np.nan)
    ref_iod = float(np.median(quality.interocular(ref_lm[ref_ok])))
    output = np.where(out_ok, quality.inner_opening(out_lm), np.nan)
    out_iod = float(np.median(quality.interocular(out_lm[out_ok])))
    model_open = opening18(predicted)
    iod_model = float(mouth.get("iod_px") or tex_iod)
    d2 = ((wanted[:, None] - pool_shapes[None]) ** 2).sum(-1).mean(-1)          # (N, P) mean squared point distance
    nearest = np.sqrt(d2.min(1)) / tex_iod
    rows = dict(model=stage_row(model_open, ref, model_open, iod_model, ref_iod),
                wanted=stage_row(opening18(wanted), ref, model_open, tex_iod, ref_iod),
                candidates=stage_row(opening18(cand), ref, model_open, tex_iod, ref_iod),
                output=stage_row(output, ref, model_open, out_iod, ref_iod))
    return dict(model=model, audio=audio, target=target, reference=reference, sets=sets, path=prep.report["path"],
                frames=int(len(wanted)), stages=rows, pool=int(len(pool_shapes)),
                nearest_iod=dict(median=float(np.median(nearest)), p90=float(np.quantile(nearest, 0.9))),
                look={k: look[k] for k in ("sharpness_ratio", "flicker_ratio", "detail_energy_ratio", "detail_flicker_ratio")})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", required=True)
    ap.add_argument("--audio", required=True, help="the words (a video: it is also the reference by default)")
    ap.add_argument("--target", required=True, help="the face")
    ap.add_argument("--reference", help="footage of the words being said (default: --audio)")
    ap.add_argument("--params", default=str(ROOT / "params.yaml"))
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--keep", type=Path, default=None, help="folder to keep the output MP4 in (out.mp4)")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    from pipeline.io.runner import setup_logging
    setup_logging(False)
    res = run(a.model, a.audio, a.target, a.reference or a.audio, a.params, a.set, a.cache, a.keep)
    for k, r in res["stages"].items():
        print(f"{k:>10}: corr {r['corr']:.2f} best {r['corr_best']:.2f} (lag {r['best_lag']:+d})  vs model "
              f"{r['corr_model']:.2f}  spread {r['spread']:.2f}")
    print(f"  nearest candidate (RMS point distance / IOD): median {res['nearest_iod']['median']:.3f}, "
          f"p90 {res['nearest_iod']['p90']:.3f} over a pool of {res['pool']}")
    print("  look (output ÷ target's own mouth): " + ", ".join(f"{k} {v:.2f}" for k, v in res["look"].items()))
    if a.json:
        a.json.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()

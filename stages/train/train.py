"""train — audio → mouth shape models (paper 000 §3.1.1, §4.2), selected by ``train.model``.

Model families live beside each other in this folder; ``lstm`` (the paper's time-delayed LSTM)
is the default. Whatever the family, the stage writes one self-contained model folder
(``models/<model>/``: weights, input normalisation, PCA basis, params, and its speaker — identity,
3D face model, candidate bank — for ``lipsynth speak``), DVC metrics
(``metrics/train.json``: losses, validation mouth error of the model and of the baselines —
the mean mouth shape and the same LSTM without delay) and the loss curves (``plots/``).

Run: ``python -m stages.train.train``.
"""
from __future__ import annotations

import csv
import json
import logging
import time

import numpy as np

from pipeline.audio import front_ends
from pipeline.errors import LipsynthError, ParameterError
from pipeline.params import FEATURE_STORE_OF, Params, Train, as_dict, front_end_store
from pipeline.io.runner import stage_main, write_timing
from pipeline.io.store import atomic_output, open_group
from pipeline.measures import mouth_metrics
from pipeline.models.speaker_bank import export_speaker
from pipeline.models.training_budget import seeded_subset
from pipeline.models.model_folder import save_model
from pipeline.models.mouth_prediction import to_frames
from stages.train import extra_corpora, fine_tune

log = logging.getLogger("lipsynth.train")


def load_sequences(ingest_path: str, pca_path: str, features: str = "mfcc", phonetic_path: str | None = None,
                   whisper_path: str | None = None):
    """Per-video (x (m, D), y (m, 20), ok (m,)) at 100 Hz, plus frame-rate truth for evaluation.

    x holds the ``features`` front end (``pipeline.audio.front_ends``): ingest's MFCC, the
    ``phonetic`` stage's phone indicators and/or the ``whisper`` stage's encoder states (same time axis)."""
    src, pca = open_group(ingest_path), open_group(pca_path)
    mfcc = np.asarray(src["mfcc"][...], np.float32) if front_ends.uses_mfcc(features) else None
    phones = None
    if front_ends.uses_phones(features):
        if phonetic_path is None:
            raise ParameterError(f"train.features={features!r} needs the phonetic store (run the phonetic stage)")
        phones = np.asarray(open_group(phonetic_path)["phones"][...], np.float32)
    states = None
    if front_ends.uses_whisper(features):
        if whisper_path is None:
            raise ParameterError(f"train.features={features!r} needs the whisper store (run the whisper stage)")
        states = open_group(whisper_path)["states"]
    c100 = np.asarray(pca["coeffs_100hz"][...], np.float32)
    v100 = np.asarray(pca["valid_100hz"][...])
    coeffs = np.asarray(pca["coeffs"][...], np.float32)
    valid = np.asarray(pca["valid"][...])
    ftime = np.asarray(src["frame_time"][...])
    out = {"train": [], "val": []}
    for v in pca.attrs["videos"]:
        if v.get("excluded"):
            continue
        m0, m, f0, n = v["first_mfcc"], v["n_mfcc"], v["first_frame"], v["n_frames"]
        x = front_ends.combine(features, None if mfcc is None else mfcc[m0:m0 + m],
                               None if phones is None else phones[m0:m0 + m],
                               None if states is None else np.asarray(states[m0:m0 + m], np.float32))
        out[v["split"]].append(dict(name=v["name"], fps=v["fps"], x=x, y=c100[m0:m0 + m], audio=(v["first_sample"], v["n_samples"]),
                                    ok=v100[m0:m0 + m], frame_y=coeffs[f0:f0 + n], frame_ok=valid[f0:f0 + n],
                                    frame_time=ftime[f0:f0 + n]))
    if not out["train"]:
        raise LipsynthError(f"{pca_path}: no training videos")
    if not out["val"]:
        raise LipsynthError(f"{pca_path}: no validation videos (raise data.val_fraction or add videos)")
    basis = {k: np.asarray(pca[k][...], np.float64) for k in ("mean", "components")}
    return out, basis, dict(pca.attrs)


def normalisation(train: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    x = np.concatenate([s["x"] for s in train])
    return x.mean(0).astype(np.float32), np.maximum(x.std(0), 1e-6).astype(np.float32)


def feature_normalisation(data: dict, how: str, features: str = "mfcc") -> tuple[np.ndarray, np.ndarray]:
    """The (mean, std) the model's inputs are normalised with (saved in the model folder).

    ``corpus`` (the paper): each MFCC dimension by its mean and variance over the training set.
    ``utterance``: every video's MFCC are first normalised over the video itself (CMVN, in
    place in ``data``; prediction does the same over the new audio), then the corpus
    normalisation as above (a no-op on CMVN'd columns; it centres and scales phone indicators).
    """
    if how not in ("corpus", "utterance"):
        raise ParameterError(f"train.feature_norm={how!r}: choose corpus or utterance")
    if how == "utterance":
        for s in data["train"] + data["val"]:
            s["x"] = front_ends.utterance_norm(s["x"], features)
    return normalisation(data["train"])


def augmented_copies(data: dict, ingest_path: str, warps: list, shifts: list, features: str,
                     feature_norm: str) -> float:
    """Add ``s["x_aug"]`` (K, m, D) to every training video: its frames with the MFCC recomputed from
    the stored audio at each VTLP factor (``audio_features.vtlp_warp``) and each pitch shift in
    semitones (``audio_features.pitch_shifted_mfcc``: formants and timing kept); phone columns
    unchanged. Returns the seconds spent."""
    import time
    from pipeline.audio.audio_features import FEATURE_DIM, mfcc_features, pitch_shifted_mfcc
    t0 = time.perf_counter()
    audio = open_group(ingest_path)["audio"]
    makers = [lambda x, a=a: mfcc_features(x, warp=float(a)) for a in warps] + \
             [lambda x, st=st: pitch_shifted_mfcc(x, float(st)) for st in shifts]
    for s in data["train"]:
        s0, n = s["audio"]
        samples = np.asarray(audio[s0:s0 + n], np.float32) / 32767.0
        copies = []
        for make in makers:
            x = np.array(s["x"], np.float32)
            x[:, :FEATURE_DIM] = make(samples)[:len(x)]
            copies.append(front_ends.utterance_norm(x, features) if feature_norm == "utterance" else x)
        s["x_aug"] = np.stack(copies)
    return time.perf_counter() - t0


def fit_lstm(data: dict, p: Train, delay: int, device, mean, std, desc="lstm", init: dict | None = None,
             opening: np.ndarray | None = None):
    from stages.train import lstm
    norm = lambda s: ((s["x"] - mean) / std, s["y"], s["ok"])

    def norm_train(s):
        if "x_aug" not in s:
            return norm(s)
        return (np.concatenate([s["x"][None], s["x_aug"]]) - mean) / std, s["y"], s["ok"]
    model, history, kept = lstm.train([norm_train(s) for s in data["train"]], [norm(s) for s in data["val"]], p, delay,
                                      device, seed=p.seed, desc=desc, init=init, opening=opening)
    preds = [lstm.predict_sequence(model, norm(s)[0], delay, device) for s in data["val"]]
    return model, history, preds, kept


def kept_point(history: list[dict], kept: int) -> dict:
    """The validation point of the step whose weights were kept."""
    return next(h for h in history if h["step"] == kept)


def score(preds100: list, data: dict, basis: dict, iod_px: float) -> dict:
    frames = [to_frames(c, s["frame_time"]) for c, s in zip(preds100, data["val"])]
    return mouth_metrics.evaluate_videos(frames, [s["frame_y"] for s in data["val"]], [s["frame_ok"] for s in data["val"]],
                                    [s["fps"] for s in data["val"]], basis, iod_px)


def run(params: Params, ingest_path: str, pca_path: str, landmarks_path: str | None = None,
        frontalize_path: str | None = None, phonetic_path: str | None = None, whisper_path: str | None = None) -> dict:
    """Train ``train.model``; the model folder also gets the speaker (identity, 3D model, candidate
    bank, ``pipeline/models/speaker_bank``) when the landmarks and frontalize stores are given."""
    from pipeline.models.delayed_lstm import pick_device
    clock_start = time.perf_counter()
    p = params.train
    data, basis, pattrs = load_sequences(ingest_path, pca_path, p.features, phonetic_path, whisper_path)
    if p.train_seconds:
        keep = seeded_subset([len(s["x"]) / 100 for s in data["train"]], p.train_seconds, p.seed)
        data["train"] = [data["train"][i] for i in keep]
        log.info("train.train_seconds=%g: %d of the training videos (%.1f s), seeded", p.train_seconds, len(keep),
                 sum(len(s["x"]) for s in data["train"]) / 100)
    own_train = list(data["train"])
    data["train"] += extra_corpora.load(p.extra_corpora, p.features, basis, pattrs["iod_px"], p.extra_repeat)
    device = pick_device(p.device)
    mean, std = feature_normalisation(data, p.feature_norm, p.features)
    init = None
    if p.init_from:
        init = fine_tune.initial_state(p.init_from, p.features, encoder_settings(p.features, whisper_path), basis,
                                       pattrs["iod_px"], device)
        base = init["base_config"]
        if (base.get("feature_norm", "corpus"), int(base["delay"])) != (p.feature_norm, p.delay):
            raise ParameterError(f"train.init_from={p.init_from}: the base model has feature_norm "
                                 f"{base.get('feature_norm', 'corpus')!r} and delay {base['delay']}, this run "
                                 f"{p.feature_norm!r} and {p.delay}")
        mean, std = init["feature_mean"], init["feature_std"]          # the base's weights expect its normalisation
        log.info("fine-tuning from %s (%s weights trained; its read-out re-expressed in this store's PCA basis)",
                 p.init_from, p.fine_tune)
    if p.vtlp_warps or p.pitch_shifts:                  # values checked when params are loaded (Train.validate)
        secs = augmented_copies(data, ingest_path, p.vtlp_warps, p.pitch_shifts, p.features, p.feature_norm)
        log.info("augmentation: %d VTLP copies (α = %s) and %d pitch-shifted copies (%s semitones) of every training "
                 "video in %.1f s", len(p.vtlp_warps), ", ".join(f"{a:g}" for a in p.vtlp_warps) or "-",
                 len(p.pitch_shifts), ", ".join(f"{a:+g}" for a in p.pitch_shifts) or "-", secs)
    log.info("training %s (%s features, %d-D) on %d videos (%d steps), validating on %d videos, device %s", p.model,
             p.features, mean.shape[0], len(data["train"]), sum(len(s["x"]) for s in data["train"]), len(data["val"]),
             device)
    t0 = time.perf_counter()
    from stages.train.lstm import opening_direction
    model, history, preds, kept = fit_lstm(data, p, p.delay, device, mean, std, init=init,
                                           opening=opening_direction(basis))
    clock = {"fit_s": time.perf_counter() - t0, "steps": history[-1]["step"]}
    clock["seconds_per_step"] = clock["fit_s"] / max(clock["steps"], 1)
    best = kept_point(history, kept)
    metrics = {"model": p.model, "features": p.features, "delay_steps": p.delay, "steps_run": history[-1]["step"],
               "step_kept": kept, "train_loss": best["train_loss"], "val_loss": best["val_loss"],
               "val": score(preds, data, basis, pattrs["iod_px"])}
    k = basis["components"].shape[0]
    rest = rest_shape(own_train, ingest_path)
    mean_shape = np.concatenate([s["y"][s["ok"]] for s in own_train]).mean(0)
    metrics["baseline_mean_shape"] = score([np.tile(mean_shape, (len(s["x"]), 1)) for s in data["val"]],
                                           data, basis, pattrs["iod_px"])
    curves = {f"{p.model}": history}
    if p.baselines and p.delay != 0:
        _, h0, preds0, kept0 = fit_lstm(data, p, 0, device, mean, std, desc="baseline")
        best0 = kept_point(h0, kept0)
        metrics["baseline_lstm_delay0"] = dict(score(preds0, data, basis, pattrs["iod_px"]),
                                               val_loss=best0["val_loss"], train_loss=best0["train_loss"])
        curves[f"{p.model}_delay0"] = h0
    metrics["ratio_to_mean_shape"] = metrics["val"]["mouth_error_px"] / metrics["baseline_mean_shape"]["mouth_error_px"]
    log.info("validation mouth error: %s %.3f px (%.2f%% IOD); mean shape %.3f px; ratio %.2f",
             p.model, metrics["val"]["mouth_error_px"], metrics["val"]["mouth_error_iod_pct"],
             metrics["baseline_mean_shape"]["mouth_error_px"], metrics["ratio_to_mean_shape"])
    with atomic_output(p.out) as tmp:
        save_model(tmp, model, dict(model=p.model, delay=p.delay, hidden=model.lstm.hidden_size, layers=model.lstm.num_layers,
                                    n_features=int(mean.shape[0]), n_components=k, feature_rate=100.0,
                                    feature_norm=p.feature_norm, features=p.features, params=as_dict(p),
                                    encoder=encoder_settings(p.features, whisper_path)),
                   mean, std, basis, pattrs, rest)
        if landmarks_path and frontalize_path:
            metrics["speaker"] = export_speaker(tmp, ingest_path, landmarks_path, frontalize_path,
                                                p.bank_frames, p.identity_frames)
    write_outputs(metrics, curves, p)
    write_timing("train", dict(clock, total_s=time.perf_counter() - clock_start))     # untracked: outputs stay deterministic
    return metrics


def rest_shape(train: list[dict], ingest_path: str) -> np.ndarray | None:
    """(k,) median PCA coefficients of the training frames in silent stretches of their audio
    (``audio_features.silent_frames``): the mouth a speaker holds when not speaking, or None."""
    from pipeline.audio.audio_features import silent_frames
    audio = open_group(ingest_path)["audio"]
    rows = []
    for s in train:
        s0, n = s["audio"]
        quiet = silent_frames(np.asarray(audio[s0:s0 + n], np.float32) / 32767.0, len(s["y"])) & s["ok"]
        rows.append(s["y"][quiet])
    rows = np.concatenate(rows)
    if len(rows) < 25:
        return None
    log.info("rest mouth: median of %d training frames in silent stretches (%.1f%% of the frames)", len(rows),
             100 * len(rows) / sum(len(s["y"]) for s in train))
    return np.median(rows, axis=0)


def encoder_settings(features: str, whisper_path: str | None) -> dict | None:
    """The whisper windowing the training features were made with (prediction repeats it)."""
    if not front_ends.uses_whisper(features):
        return None
    a = open_group(whisper_path).attrs
    out = dict(window_s=float(a["window_s"]), overlap_s=float(a["overlap_s"]))
    if list(a.get("layers", [5])) != [5]:                  # the final layer alone stays unrecorded, as before
        out["layers"] = [int(k) for k in a["layers"]]
    return out


def write_outputs(metrics: dict, curves: dict, p: Train) -> None:
    """The metrics json and the loss-curve csv, each replaced whole (``atomic_output``)."""
    with atomic_output(p.metrics, suffix=".json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=2))
    with atomic_output(p.plots, suffix=".csv") as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["model", "step", "epoch", "train_loss", "val_loss"])
        for name, hist in curves.items():
            for h in hist:
                w.writerow([name, h["step"], f"{h['epoch']:.3f}", f"{h['train_loss']:.5f}", f"{h['val_loss']:.5f}"])


def feature_store(params: Params) -> dict[str, str | None]:
    """The front end's store, as the DVC stage declares it (``train.feature_store``), as ``run``'s
    ``phonetic_path``/``whisper_path``; the stage reads no other front end's store, so ``dvc repro train``
    runs only the front end it uses. A ``feature_store`` that is not the one ``features`` reads stops
    with one line naming the key to set."""
    t = params.train
    section, expected = FEATURE_STORE_OF[t.features], front_end_store(params)
    if t.feature_store != expected:
        raise ParameterError(f"train.feature_store={t.feature_store!r}: train.features {t.features!r} reads "
                             f"{section}.out ({expected!r}); set train.feature_store: {expected}")
    return dict(phonetic_path=expected if section == "phonetic" else None,
                whisper_path=expected if section == "whisper" else None)


def main(argv=None) -> int:
    return stage_main("lipsynth train", __doc__, lambda p: run(p, p.ingest.out, p.pca.out, p.landmarks.out, p.frontalize.out,
                                                             **feature_store(p)),
                      argv)


if __name__ == "__main__":
    raise SystemExit(main())

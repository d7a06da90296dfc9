"""Mining the emotion database for robust emotion vectors (paper 001 §5.1), automated.

The paper culls by hand in three steps; here each step is a measured rule:

1. **Response to articulation.** Probe windows from the validation videos: ``probes`` frames where
   the tracked mouth is most closed and ``probes`` where it is most open, among frames whose
   520 ms window is loud (speech, not silence), at most one of each per clip. A database vector
   passes when, used as the constant emotion, the predicted inner-lip opening is below the
   midpoint of the true closed/open openings at *every* closed probe and above it at *every*
   open probe. Its *response* is mean(open) − mean(closed), relative to the true difference.
2. **Playback.** The strongest-responding survivors (``playback`` of them) are played over the
   validation clips: vectors whose opening varies less than half as much as the tracked one
   (subdued) or whose frame-to-frame jitter (mean |second difference|) is over twice the tracked
   one (spurious) are dropped.
3. **Another speaker** (the paper's third step) needs audio of another person, which the corpus
   does not have; it is left out and said so in the log.

The survivors are clustered (k-means, ``clusters``); each cluster's representative is its
member with the lowest validation mouth error. Candidates are ordered by that error, so
candidate 0 — the default — is the most accurate robust vector ("neutral" in the paper's terms).
"""
from __future__ import annotations

import logging

import numpy as np
import torch

from pipeline.audio.speech_autocorrelation import windows

log = logging.getLogger("lipsynth.train_karras")


def opening(points: np.ndarray, upper: int, lower: int) -> np.ndarray:
    """Inner-lip opening (px): vertical distance of two face points; points (T, P, 2) → (T,)."""
    return points[:, lower, 1] - points[:, upper, 1]


def loudness(padded: np.ndarray, times: np.ndarray) -> np.ndarray:
    """RMS of each time's 520 ms analysis window (the autocorrelation at lag 0, summed)."""
    return windows(padded, times)[:, :, 0].sum(1)


def probe_frames(videos: list[dict], upper: int, lower: int, k: int) -> tuple[list, list, float, float]:
    """(closed, open) probe lists of (video, frame) and the mean true opening of each set."""
    rows = []
    for vi, v in enumerate(videos):
        ok = np.flatnonzero(v["ok"])
        if len(ok) < 3:
            continue
        pts = v["targets"].reshape(len(v["targets"]), -1, 2)
        op = opening(pts[ok], upper, lower)
        loud = loudness(v["padded"], v["frame_time"][ok])
        keep = loud >= np.median(loud)
        if keep.sum() < 2:
            continue
        rows.append((vi, ok[keep][np.argmin(op[keep])], op[keep].min(), ok[keep][np.argmax(op[keep])], op[keep].max()))
    by_closed = sorted(rows, key=lambda r: r[2])[:k]
    by_open = sorted(rows, key=lambda r: -r[4])[:k]
    closed = [(r[0], r[1]) for r in by_closed]
    opened = [(r[0], r[3]) for r in by_open]
    return closed, opened, float(np.mean([r[2] for r in by_closed])), float(np.mean([r[4] for r in by_open]))


def outputs_for(net, feats: torch.Tensor, vectors: np.ndarray, batch: int = 4096) -> np.ndarray:
    """Network outputs for every (vector, window) pair: (V, W, D), formant features computed once."""
    n_v, n_w = len(vectors), feats.shape[0]
    out = []
    with torch.no_grad():
        ev = torch.as_tensor(vectors, dtype=torch.float32)
        per = max(1, batch // n_w)
        for i in range(0, n_v, per):
            e = ev[i:i + per]
            f = feats.repeat(len(e), 1, 1, 1)
            out.append(net.articulate(f, e.repeat_interleave(n_w, 0)).reshape(len(e), n_w, -1).numpy())
    return np.concatenate(out)


def window_features(net, videos: list[dict], rows: list) -> torch.Tensor:
    x = np.concatenate([windows(videos[vi]["padded"], videos[vi]["frame_time"][[fi]]) for vi, fi in rows])
    with torch.no_grad():
        return net.formant_features(torch.as_tensor(x[:, None]))


def mine(net, database: np.ndarray, sources: list[tuple[str, int]], val: list[dict], upper: int, lower: int,
         max_candidates: int = 2000, probes: int = 8, playback: int = 64, playback_clips: int = 8,
         clusters: int = 8, seed: int = 0) -> dict:
    """Robust emotion candidates from ``database`` (N, E) (one learned vector per training frame,
    ``sources`` its (video name, frame)). Returns dict(candidates (K, E), info (per candidate),
    counts per step)."""
    from sklearn.cluster import KMeans
    net.eval()
    rng = np.random.default_rng(seed)
    pick = np.sort(rng.choice(len(database), min(max_candidates, len(database)), replace=False))
    vecs = database[pick]
    closed, opened, true_closed, true_open = probe_frames(val, upper, lower, probes)
    thr = 0.5 * (true_closed + true_open)
    y = outputs_for(net, window_features(net, val, closed + opened), vecs)
    op = opening(y.reshape(-1, y.shape[2] // 2, 2), upper, lower).reshape(len(vecs), -1)
    pc, po = op[:, :len(closed)], op[:, len(closed):]
    response = (po.mean(1) - pc.mean(1)) / max(true_open - true_closed, 1e-6)
    passed = np.flatnonzero((pc < thr).all(1) & (po > thr).all(1))
    log.info("emotion mining step 1: %d of %d database vectors close the mouth at all %d closed probes and open "
             "it at all %d open probes (threshold %.2f px)", len(passed), len(vecs), len(closed), len(opened), thr)
    step1 = len(passed)
    if len(passed) < clusters:
        passed = np.argsort(-response)[:max(clusters, len(passed))]
        log.warning("emotion mining: too few vectors pass step 1 — keeping the %d strongest responders", len(passed))
    top = passed[np.argsort(-response[passed])][:playback]
    # step 2: playback over validation clips
    order = np.argsort([-v["ok"].sum() for v in val])[:playback_clips]
    clip_rows = [(vi, fi) for vi in order for fi in range(len(val[vi]["targets"]))]
    yv = outputs_for(net, window_features(net, val, clip_rows), vecs[top])             # (V, W, D)
    truth = np.concatenate([val[vi]["targets"] for vi in order])
    ok = np.concatenate([val[vi]["ok"] for vi in order])
    bounds = np.cumsum([0] + [len(val[vi]["targets"]) for vi in order])
    pts = yv.reshape(len(top), len(clip_rows), -1, 2)
    tpts = truth.reshape(len(truth), -1, 2)
    err = np.linalg.norm(pts - tpts[None], axis=-1).mean(-1)[:, ok].mean(1)
    std_ratio, jitter_ratio = np.zeros(len(top)), np.zeros(len(top))
    t_op = opening(tpts, upper, lower)
    for j in range(len(top)):
        p_op = opening(pts[j], upper, lower)
        s, jt = [], []
        for a, b in zip(bounds[:-1], bounds[1:]):
            m = ok[a:b]
            if m.sum() < 5:
                continue
            s.append(p_op[a:b][m].std() / max(t_op[a:b][m].std(), 1e-6))
            jt.append(np.abs(np.diff(p_op[a:b], 2)).mean() / max(np.abs(np.diff(t_op[a:b], 2)).mean(), 1e-6))
        std_ratio[j], jitter_ratio[j] = np.median(s), np.median(jt)
    good = np.flatnonzero((std_ratio >= 0.5) & (jitter_ratio <= 2.0))
    log.info("emotion mining step 2: %d of %d candidates move the mouth at least half as much as the tracked one "
             "without over twice its jitter on %d validation clips; step 3 (another speaker's audio) skipped: "
             "the corpus has one speaker", len(good), len(top), len(order))
    step2 = len(good)
    if len(good) == 0:
        good = np.arange(len(top))
        log.warning("emotion mining: no candidate passes step 2 — clustering the step-1 survivors")
    k = min(clusters, len(good))
    km = KMeans(k, n_init=10, random_state=seed).fit(vecs[top[good]])
    reps = []
    for c in range(k):
        members = good[km.labels_ == c]
        best = members[np.argmin(err[members])]
        src = [sources[pick[top[m]]] for m in members]
        names, counts = np.unique([s[0] for s in src], return_counts=True)
        reps.append(dict(database_row=int(pick[top[best]]), video=sources[pick[top[best]]][0],
                         frame=int(sources[pick[top[best]]][1]), cluster_size=int(len(members)),
                         videos={str(n): int(c_) for n, c_ in sorted(zip(names, counts), key=lambda t: -t[1])[:5]},
                         response=float(response[top[best]]), opening_std_ratio=float(std_ratio[best]),
                         jitter_ratio=float(jitter_ratio[best]), val_error_px=float(err[best])))
    reps.sort(key=lambda r: r["val_error_px"])
    for i, r in enumerate(reps):
        r["index"] = i
    cands = np.stack([database[r["database_row"]] for r in reps]).astype(np.float32)
    return dict(candidates=cands, info=reps, steps=dict(database=int(len(database)), scanned=int(len(vecs)),
                                                       step1=int(step1), step2=int(step2), clusters=int(k),
                                                       probes_closed=len(closed), probes_open=len(opened)))

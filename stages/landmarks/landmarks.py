"""landmarks — dlib 68-point landmarks for every frame, detect rarely, track in between.

The HOG detector (~25 ms) runs on the first frame of each video, every ``detect_every`` frames,
and whenever tracking is lost; in between, the face box for frame t+1 is derived from frame t's
landmarks (using the box/landmark relation measured at the last detection) and only the shape
predictor (~2 ms) runs.

Confidence: the predictor is run again from a box shifted diagonally by ``jitter`` × box size.
On a face the predicted landmarks stay put; on clutter they follow the box. confidence = 1 − (mean
landmark displacement / box displacement), in [0, 1]. A frame is valid when its confidence is
at least ``min_confidence`` and the landmarks lie inside the crop.

Store ``store/landmarks.zarr`` (same global frame axis as ingest):
    landmarks   (N, 68, 2) float32  pixel coordinates in the source video frame
    confidence  (N,) float32        see above; 0 where no face was found
    valid       (N,) bool
    detected    (N,) bool           the detector ran on this frame
    attrs["videos"]: ingest's index plus ``valid_fraction`` per video

Run: ``python -m stages.landmarks.landmarks``.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from pipeline.face import dlib_face
from pipeline.errors import LipsynthError
from pipeline.io.parallel import client_for, run_tasks
from pipeline.params import Landmarks, Params
from pipeline.io.runner import stage_main
from pipeline.io.store import (atomic_output, create_group, create_timed, occupied_shards, open_group,
                            video_of_frames, videos_in)

log = logging.getLogger("lipsynth.landmarks")


def box_relation(box: np.ndarray, lm: np.ndarray) -> np.ndarray:
    """Express a detector box relative to the landmarks' bounding box: (4,) offsets in lm-box sizes."""
    lo, hi = lm.min(0), lm.max(0)
    size = hi - lo
    return np.array([(box[0] - lo[0]) / size[0], (box[1] - lo[1]) / size[1],
                     (box[2] - hi[0]) / size[0], (box[3] - hi[1]) / size[1]])


def box_from_landmarks(lm: np.ndarray, relation: np.ndarray) -> np.ndarray:
    """Inverse of ``box_relation``: the detector-style box for landmarks ``lm`` (68, 2)."""
    lo, hi = lm.min(0), lm.max(0)
    size = hi - lo
    return np.array([lo[0] + relation[0] * size[0], lo[1] + relation[1] * size[1],
                     hi[0] + relation[2] * size[0], hi[1] + relation[3] * size[1]])


def landmark_confidence(gray: np.ndarray, box: np.ndarray, lm: np.ndarray, jitter: float) -> float:
    """1 − (landmark displacement / box displacement) under a diagonal box shift, in [0, 1]."""
    d = jitter * (box[2] - box[0])
    lm2 = dlib_face.predict_landmarks(gray, box + np.array([d, d, d, d]))
    shift = np.mean(np.linalg.norm(lm2 - lm, axis=1)) / np.hypot(d, d)
    return float(np.clip(1.0 - shift, 0.0, 1.0))


def track_video(grays, p: Landmarks):
    """Landmarks for consecutive frames of one video.

    Parameters
    ----------
    grays : iterable of (S, S) uint8
    p : pipeline.params.Landmarks
        landmarks params: detect_every, detect_upsample, jitter, min_confidence, margin.

    Returns
    -------
    lms (T, 68, 2) float32, conf (T,) float32, valid (T,) bool, detected (T,) bool — crop pixels.
    """
    lms, conf, valid, detected = [], [], [], []
    box, relation, since = None, None, 0
    for gray in grays:
        s = gray.shape[0]
        det = box is None or since >= p.detect_every
        if det:
            found = dlib_face.detect_face(gray, p.detect_upsample)
            if found is not None:
                box, since = found[0], 0
                relation = None
        detected.append(det)
        if box is None:
            lms.append(np.zeros((68, 2), np.float32))
            conf.append(0.0)
            valid.append(False)
            continue
        lm = dlib_face.predict_landmarks(gray, box)
        c = landmark_confidence(gray, box, lm, p.jitter)
        inside = bool(np.all(lm > -p.margin * s) and np.all(lm < (1 + p.margin) * s))
        ok = c >= p.min_confidence and inside
        lms.append(lm)
        conf.append(c)
        valid.append(ok)
        if ok:
            if relation is None:
                relation = box_relation(box, lm)
            box = box_from_landmarks(lm, relation)
            since += 1
        else:
            box = None  # lost: detect again on the next frame
    return (np.array(lms, np.float32).reshape(-1, 68, 2), np.array(conf, np.float32),
            np.array(valid, bool), np.array(detected, bool))


def landmark_block(job: dict) -> dict:
    """Track frames ``[start, stop)`` (one shard) and write them; return per-video valid counts."""
    import cv2
    import zarr
    cv2.setNumThreads(1)
    src = zarr.open_group(job["ingest"], mode="r")
    dst = zarr.open_group(job["out"], mode="r+")
    start, stop, S = job["start"], job["stop"], job["crop_size"]
    crops = src["crops"][start:stop]
    out_lm = np.zeros((stop - start, 68, 2), np.float32)
    out_c = np.zeros(stop - start, np.float32)
    out_v = np.zeros(stop - start, bool)
    out_d = np.zeros(stop - start, bool)
    counts = {}
    for v, lo, hi in video_of_frames(job["videos"], start, stop):
        grays = (crops[i - start, :S] for i in range(lo, hi))   # Y plane of I420 = grayscale
        lm, c, ok, det = track_video(grays, job["params"])
        x0, y0, s = v["crop"]
        out_lm[lo - start:hi - start] = lm * s + np.array([x0, y0], np.float32)
        out_c[lo - start:hi - start], out_v[lo - start:hi - start], out_d[lo - start:hi - start] = c, ok, det
        counts[v["name"]] = int(ok.sum())
    dst["landmarks"][start:stop] = out_lm
    dst["confidence"][start:stop] = out_c
    dst["valid"][start:stop] = out_v
    dst["detected"][start:stop] = out_d
    return counts


def run(params: Params, ingest_path: str, out: str) -> list[dict]:
    p, data = params.landmarks, params.data
    src = open_group(ingest_path)
    videos = [dict(v) for v in src.attrs["videos"]]
    n, shard = src["crops"].shape[0], src["crops"].shards[0]
    with atomic_output(out) as tmp, client_for(params.cluster) as client:
        g = create_group(tmp)
        create_timed(g, "landmarks", n, (68, 2), "float32", shard, shard)
        create_timed(g, "confidence", n, (), "float32", shard, shard)
        create_timed(g, "valid", n, (), "bool", shard, shard, fill_value=False)
        create_timed(g, "detected", n, (), "bool", shard, shard, fill_value=False)
        ranges = occupied_shards(videos, n, shard)
        jobs = [dict(ingest=str(Path(ingest_path).absolute()), out=str(tmp), start=a, stop=b, params=p,
                     crop_size=src.attrs["crop_size"], videos=list(videos_in(videos, a, b))) for a, b in ranges]
        frames = [sum(hi - lo for _, lo, hi in video_of_frames(videos, a, b)) for a, b in ranges]
        results = run_tasks(client, landmark_block, jobs, "landmarks", "frame", frames)
        counts: dict[str, int] = {}
        for r in results:
            for k, c in r.items():
                counts[k] = counts.get(k, 0) + c
        for v in videos:
            v["valid_fraction"] = counts.get(v["name"], 0) / max(v["n_frames"], 1)
            v["excluded"] = v["valid_fraction"] < p.min_valid_fraction
            if v["excluded"]:
                msg = (f"{v['path']}: face tracked in only {100 * v['valid_fraction']:.1f}% of frames "
                       f"(landmarks.min_valid_fraction={p.min_valid_fraction})")
                if data.on_bad_input != "skip":
                    raise LipsynthError(msg + " — set data.on_bad_input: skip to leave it out")
                log.warning("excluding %s", msg)
        g.attrs.update({"videos": videos, "coordinates": "source frame pixels"})
        total = sum(counts.values())
        real = sum(v["n_frames"] for v in videos)
        log.info("valid landmarks on %d of %d frames (%.2f%%)", total, real, 100 * total / max(real, 1))
    return videos


def main(argv=None) -> int:
    return stage_main("lipsynth landmarks", __doc__, lambda p: run(p, p.ingest.out, p.landmarks.out), argv)


if __name__ == "__main__":
    raise SystemExit(main())

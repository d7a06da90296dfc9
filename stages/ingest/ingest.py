"""ingest — decode the corpus into the zarr store (paper 000 §3.1, "Audio Features").

For every training video: probe it, decode its audio (mono, 16 kHz, aligned to the first video
frame by stream timestamps, RMS-normalised), compute the 28-D MFCC features at 100 Hz, find the
face on a few key frames to fix a per-video face-region crop (``crop.py``), and store every frame's crop.

Why crops and why YUV 4:2:0: later stages only look at the head, neck and shoulders, which a
square crop of ``crop_scale`` × the detected face width holds. A crop of ``crop_size``² pixels in
I420 costs 1.5 B/pixel (the source video is 4:2:0 already, so nothing is lost that the codec
kept), e.g. 192² → 55 KB raw per frame before compression versus 311 KB for a whole 360×288 RGB
frame and 2.7 MB at 720p. Full frames stay available from the source file (the index keeps the
path and timestamps) for compositing.

Store ``store/ingest.zarr``:
    crops       (N, 3S/2, S) uint8   I420 face-region crop of every frame (S = crop_size)
    frame_time  (N,) float64         presentation time (s) of each frame from its video's start
    video_id    (N,) int32           index into attrs["videos"] (−1 in the gaps between videos)
    audio       (A,) int16           16 kHz mono RMS-normalised PCM
    mfcc        (M, 28) float32      100 Hz features (13 MFCC, log energy, deltas)
    attrs["videos"]: per-video index (name, path relative to the project root, split, first_frame, n_frames, first_sample,
    n_samples, first_mfcc, n_mfcc, fps, crop, ...)

Every video starts on a shard boundary of each axis, so the one task that decodes a video
writes its own shards directly (no scratch copies, no two workers on one file); the gaps after
each video hold no chunks on disk.

Run: ``python -m stages.ingest.ingest`` (reads ``data``, ``ingest`` and ``cluster`` params).
"""
from __future__ import annotations

import dataclasses
import glob
import hashlib
import logging
import os
from pathlib import Path

import cv2
import numpy as np

from pipeline.audio import audio_features
from pipeline.io import media
from pipeline.errors import BadInputError, LipsynthError, ParameterError
from pipeline.io.parallel import client_for, run_tasks
from pipeline.io.segments import time_split
from pipeline.params import Ingest, Params
from stages.ingest.crop import auto_crop_size, crop_box, cut_crop, find_face_boxes, sampled_face_widths
from pipeline.io.runner import stage_main
from pipeline.io.store import atomic_output, create_group, create_timed, project_path

log = logging.getLogger("lipsynth.ingest")
VIDEO_EXTS = {".mp4", ".mov", ".mkv", ".avi", ".webm", ".mpg", ".mpeg", ".m4v"}


# ---------------------------------------------------------------- plan (pure functions)
def list_videos(spec) -> list[str]:
    """Expand ``data.videos`` (a file, a folder, a glob, or a list of them) to sorted paths."""
    specs = spec if isinstance(spec, (list, tuple)) else [spec]
    paths: list[str] = []
    for s in specs:
        s = str(s)
        if os.path.isdir(s):
            found = sorted(str(p) for p in Path(s).iterdir() if p.suffix.lower() in VIDEO_EXTS)
            if not found:
                raise BadInputError(s, "folder holds no video files (" + ", ".join(sorted(VIDEO_EXTS)) + ")")
            paths += found
        elif any(ch in s for ch in "*?["):
            found = sorted(p for p in glob.glob(s, recursive=True) if Path(p).suffix.lower() in VIDEO_EXTS)
            if not found:
                raise BadInputError(s, "glob matches no video files")
            paths += found
        elif os.path.exists(s):
            paths.append(s)
        else:
            raise BadInputError(s, "file not found")
    names = [video_name(p) for p in paths]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ParameterError(f"data.videos: several videos share the name(s) {sorted(dup)[:3]}; names must be unique")
    return paths


def video_name(path: str) -> str:
    return Path(path).stem


def split_videos(names: list[str], val_fraction: float, seed: int) -> dict[str, str]:
    """Deterministic train/validation split by video.

    Videos are ranked by a hash of ``(seed, name)``; the first ``round(val_fraction * n)``
    (at least one when there are two or more videos and val_fraction > 0) are validation.
    Adding a video never moves another video to the other split unless the count changes.
    """
    if not 0 <= val_fraction < 1:
        raise ParameterError(f"data.val_fraction={val_fraction}: must be in [0, 1)")
    ranked = sorted(names, key=lambda n: hashlib.sha1(f"{seed}:{n}".encode()).hexdigest())
    n_val = int(round(val_fraction * len(names)))
    if val_fraction > 0 and len(names) >= 2:
        n_val = max(1, n_val)
    val = set(ranked[:n_val])
    return {n: ("val" if n in val else "train") for n in names}


def probe_video(path: str, p: Ingest, require_audio: bool = True) -> dict:
    """Header-only checks and size estimates of one video (on the client, before any writing)."""
    info = media.probe(path)
    if not (p.min_fps <= info.fps <= p.max_fps):
        raise BadInputError(path, f"frame rate {info.fps:.3f} fps outside the supported {p.min_fps}–{p.max_fps} fps")
    if require_audio and not info.has_audio:
        raise BadInputError(path, "no audio track (training videos need the speaker's audio)")
    if info.duration and info.duration < p.min_seconds:
        raise BadInputError(path, f"too short: {info.duration:.2f} s < ingest.min_seconds={p.min_seconds}")
    if info.n_frames and info.n_frames / info.fps < p.min_seconds:     # the container may be longer (audio)
        raise BadInputError(path, f"too short: {info.n_frames / info.fps:.2f} s of video "
                                  f"< ingest.min_seconds={p.min_seconds}")
    est = max(info.n_frames, int(np.ceil(info.duration * info.fps)))   # a variable rate may repeat frames
    return dict(name=video_name(path), path=project_path(path), fps=info.fps, width=info.width,
                height=info.height, est_frames=est, source_audio_rate=info.audio_rate,
                source_audio_channels=info.audio_channels)


def decode_video(path: str, p: Ingest, require_audio: bool = True) -> dict:
    """Everything ingest stores for one video, as arrays (pure of the store).

    Returns
    -------
    dict with crops (T, 3S/2, S) uint8, frame_time (T,) s, audio (A,) float32 16 kHz,
    mfcc (1 + A // 160, 28), crop [x0, y0, s], audio_offset (s), fps.
    """
    info = media.probe(path)
    boxes = find_face_boxes(path, p.detect_samples, p.min_face_px, p.detect_upsample)
    box = crop_box(boxes, p.crop_scale, p.crop_shift_down)
    size = auto_crop_size(boxes[:, 2] - boxes[:, 0], p.crop_scale, p.max_crop_size) if p.crop_size == "auto" \
        else p.crop_size                # run() resolves auto once for the whole store; alone, a video sizes itself
    times, crops = [], []
    for t, yuv in media.iter_frames(path, fmt="yuv"):
        times.append(t)
        crops.append(cut_crop(yuv, box, size))
    n = len(times)
    if n == 0:
        raise BadInputError(path, "no decodable video frames")
    if n / info.fps < p.min_seconds:
        raise BadInputError(path, f"too short: {n / info.fps:.2f} s < ingest.min_seconds={p.min_seconds}")
    if require_audio or info.has_audio:
        samples, audio_start = media.read_audio(path, audio_features.SAMPLE_RATE)
    else:                   # a target for new speech needs no audio of its own: silence
        samples, audio_start = np.zeros(0, np.float32), times[0]
    audio = media.align_audio(samples, audio_start, times[0], n / info.fps, audio_features.SAMPLE_RATE)
    audio = audio_features.rms_normalize(audio, p.rms_target_dbfs)
    return dict(crops=np.stack(crops), frame_time=np.asarray(times) - times[0], audio=audio,
                mfcc=audio_features.mfcc_features(audio), crop=[box[0], box[1], box[2] / size],
                audio_offset=audio_start - times[0], fps=info.fps)


def ingest_video(job: dict) -> dict:
    """Decode one video and write it into its own shard-aligned regions of the store.

    Returns its measured sizes, or ``{"error": msg}`` for a bad video (nothing is written).
    """
    import zarr
    cv2.setNumThreads(1)
    e = job["entry"]
    try:
        d = decode_video(job["source"], job["params"], job["require_audio"])
    except BadInputError as exc:                       # named as the user gave it
        return {"error": str(BadInputError(job["given"], exc.problem)), "path": e["path"]}
    g = zarr.open_group(job["out"], mode="r+")
    n, a, m = (min(len(d[k]), e[c]) for k, c in (("crops", "cap_frames"), ("audio", "cap_samples"),
                                                   ("mfcc", "cap_mfcc")))
    f0, s0, m0 = e["first_frame"], e["first_sample"], e["first_mfcc"]
    g["crops"][f0:f0 + n] = d["crops"][:n]
    g["frame_time"][f0:f0 + n] = d["frame_time"][:n]
    g["video_id"][f0:f0 + n] = np.full(n, e["id"], np.int32)
    g["audio"][s0:s0 + a] = np.round(d["audio"][:a] * 32767).astype(np.int16)
    g["mfcc"][m0:m0 + m] = d["mfcc"][:m]
    return dict(n_frames=n, n_samples=a, n_mfcc=m, crop=d["crop"], audio_offset=d["audio_offset"],
                truncated=len(d["crops"]) > n)


# ---------------------------------------------------------------- stage
def round_up(x: int, multiple: int) -> int:
    return -(-x // multiple) * multiple


def layout(entries: list[dict], shard_frames: int, shard_samples: int, shard_mfcc: int,
           slack: float = 0.02) -> tuple[int, int, int]:
    """Give each video its own shard-aligned region on the frame, sample and MFCC axes.

    Every video starts on a shard boundary, so the task that decodes it writes only shards of
    its own (no two workers touch a file) and nothing has to be copied afterwards. Capacity is
    the header's estimate plus ``slack``; gaps between videos hold no chunks on disk.
    Returns the three axis lengths.
    """
    f = s = m = 0
    for e in entries:
        frames = int(e["est_frames"] * (1 + slack)) + 8
        seconds = frames / e["fps"]
        e["cap_frames"], e["cap_samples"] = frames, int(np.ceil(seconds * audio_features.SAMPLE_RATE))
        e["cap_mfcc"] = 1 + e["cap_samples"] // audio_features.HOP
        e["first_frame"], e["first_sample"], e["first_mfcc"] = f, s, m
        f += round_up(e["cap_frames"], shard_frames)
        s += round_up(e["cap_samples"], shard_samples)
        m += round_up(e["cap_mfcc"], shard_mfcc)
    return f, s, m


def run(params: Params, out: str, require_audio: bool = True) -> list[dict]:
    """Ingest ``data.videos`` into ``out``. Training videos need their audio (``require_audio``);
    a target video that only receives new speech (``lipsynth speak``) does not."""
    data, p = params.data, params.ingest
    paths = list_videos(data.videos)
    names = [video_name(q) for q in paths]
    splits = (time_split(names, data.val_fraction) if data.split == "time"
              else split_videos(names, data.val_fraction, data.split_seed))
    log.info("ingesting %d videos from %s", len(paths), data.videos)
    entries = []
    for q in paths:
        try:
            entries.append(probe_video(q, p, require_audio))
        except BadInputError as exc:
            if data.on_bad_input != "skip":
                raise LipsynthError(f"{exc} (set data.on_bad_input: skip to leave such videos out)") from None
            log.warning("skipping %s", exc)
    if not entries:
        raise LipsynthError(f"{data.videos}: no usable videos")
    if p.crop_size == "auto":
        widths = sampled_face_widths([e["path"] for e in entries], p)
        p = dataclasses.replace(p, crop_size=auto_crop_size(widths, p.crop_scale, p.max_crop_size))
        log.info("crop size %d px (ingest.crop_size: auto — %.2f × the median face width %.0f px of %d detections, "
                 "at most ingest.max_crop_size=%d)", p.crop_size, p.crop_scale, float(np.median(widths)) if widths else
                 float("nan"), len(widths), p.max_crop_size)
    S, sh = p.crop_size, p.shard_frames
    sh_audio, sh_mfcc = 16000 * p.shard_seconds, 100 * p.shard_seconds
    n_frames, n_samples, n_mfcc = layout(entries, sh, sh_audio, sh_mfcc)
    for i, e in enumerate(entries):
        e["id"], e["split"] = i, splits[e["name"]]
    with atomic_output(out) as tmp, client_for(params.cluster) as client:
        g = create_group(tmp)
        create_timed(g, "crops", n_frames, (S * 3 // 2, S), "uint8", sh, p.chunk_frames)
        create_timed(g, "frame_time", n_frames, (), "float64", sh, sh, fill_value=float("nan"))
        create_timed(g, "video_id", n_frames, (), "int32", sh, sh, fill_value=-1)
        create_timed(g, "audio", n_samples, (), "int16", sh_audio, sh_audio // 10)
        create_timed(g, "mfcc", n_mfcc, (28,), "float32", sh_mfcc, sh_mfcc // 10)
        # workers may run in another directory: they get absolute paths, the store records relative ones
        given = {video_name(q): q for q in paths}
        jobs = [dict(entry=e, source=str(Path(e["path"]).absolute()), given=given[e["name"]], params=p,
                     require_audio=require_audio, out=str(tmp))
                for e in entries]
        results = run_tasks(client, ingest_video, jobs, "ingest", "frame", [e["cap_frames"] for e in entries])
        for e, r in zip(entries, results):
            if "error" in r:
                if data.on_bad_input != "skip":
                    raise LipsynthError(r["error"] + " (set data.on_bad_input: skip to leave such videos out)")
                log.warning("skipping %s", r["error"])
                e.update(n_frames=0, n_samples=0, n_mfcc=0, crop=[0.0, 0.0, 1.0], audio_offset=0.0, excluded=True)
                continue
            if r.pop("truncated"):
                log.warning("%s: more frames than its header announced; kept the first %d", e["path"], r["n_frames"])
            e.update(r)
        g.attrs.update({"videos": entries, "sample_rate": audio_features.SAMPLE_RATE, "mfcc_rate": 100,
                        "crop_size": S, "crop_format": "I420"})
    kept = [e for e in entries if not e.get("excluded")]
    if not kept:
        raise LipsynthError(f"{data.videos}: no usable videos")
    log.info("stored %d frames of %d videos (%d train, %d val) in %s", sum(e["n_frames"] for e in kept), len(kept),
             sum(e["split"] == "train" for e in kept), sum(e["split"] == "val" for e in kept), out)
    return entries


def main(argv=None) -> int:
    return stage_main("lipsynth ingest", __doc__, lambda p: run(p, p.ingest.out), argv)


if __name__ == "__main__":
    raise SystemExit(main())

"""What a model folder carries about its speaker, so ``lipsynth speak`` needs no corpus store.

    models/<model>/speaker.npz   shape3d (68, 3) mm — the corpus 3D face model (frontalize),
                                 surface_depth (H, W) mm, surface_grid [x0, y0, step] mm — its extended
                                 surface f*, texture_window [x0, y0, mm_per_px, size] (the mesh render),
                                 identity (128,) — median dlib face descriptor of training frames,
                                 head_texture (H, W, 3) uint8, head_window [x0, y0, mm_per_px, W, H],
                                 head_landmarks (68, 2) mm — the whole face, mouth shut, for the 3D head
                                 identity_spread (F,) — each sampled frame's distance to it
    models/<model>/audio_domain.json  the training audio's MFCC mean/std and the shifts of the held-out
                                 (validation) clips from it (``pipeline.audio.audio_domain``): speak warns about far audio
    models/<model>/bank.zarr     the candidate bank: ``train.bank_frames`` training frames spread
                                 evenly over the training videos (valid pose and landmarks):
        texture (P, 3T/2, T) uint8 I420 frontal texture, clothing_mask (P, T, T) bool,
        frontal_landmarks (P, 68, 2) float32 texture px, pose (P, 6) float32, frame (P,) int64
        (global frame index in the corpus stores); attrs: texture_window, grid, focal_factor.

A same-speaker target is frontalized with ``shape3d`` (so its textures live in the bank's
canonical frame and the model's PCA basis) and draws mouths from the bank as the in-store
synthesize draws from the corpus.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from pipeline.audio import audio_domain
from pipeline.face import head_texture as head
from pipeline.face import identity as ident
from pipeline.face.canonical import Surface
from pipeline.face.geometry import intrinsics
from pipeline.io.store import create_group, open_group, take

log = logging.getLogger("lipsynth.speaker_bank")


def training_frames(fr, lmg) -> tuple[np.ndarray, list[dict]]:
    """Global indices of the training videos' frames with a valid pose and landmarks, and those videos."""
    videos = [v for v in fr.attrs["videos"] if v["split"] == "train" and v["n_frames"] and not v.get("excluded")]
    ok = np.asarray(fr["pose_valid"][...]) & np.asarray(lmg["valid"][...])
    idx = np.concatenate([np.arange(v["first_frame"], v["first_frame"] + v["n_frames"]) for v in videos])
    return idx[ok[idx]], videos


def video_index(idx: np.ndarray, videos: list[dict]) -> np.ndarray:
    """(max(idx) + 1,) the position in ``videos`` of the video each global frame index belongs to."""
    by_frame = np.zeros(int(idx.max()) + 1, np.int64)
    for k, v in enumerate(videos):
        by_frame[v["first_frame"]:v["first_frame"] + v["n_frames"]] = k
    return by_frame


def spread_evenly(idx: np.ndarray, n: int) -> np.ndarray:
    """At most ``n`` entries of ``idx`` at even spacing (all of them when there are fewer)."""
    return idx[np.unique(np.linspace(0, len(idx) - 1, min(n, len(idx))).round().astype(int))]


def export_speaker(folder, ingest_path: str, landmarks_path: str, frontalize_path: str,
                   bank_frames: int, identity_frames: int) -> dict:
    """Write speaker.npz and bank.zarr into the model folder ``folder``; returns their summary."""
    src, lmg, fr = open_group(ingest_path), open_group(landmarks_path), open_group(frontalize_path)
    idx, videos = training_frames(fr, lmg)
    if not len(idx):
        raise ValueError(f"{frontalize_path}: no training frame with a valid pose")
    # identity: descriptors of frames spread over the training videos
    by_frame = video_index(idx, videos)
    pick = spread_evenly(idx, identity_frames)
    lms = np.asarray(lmg["landmarks"].get_orthogonal_selection((pick,)), np.float64)
    descs = np.stack([ident.face_descriptor(_rgb(src["crops"][int(i)]), ident.crop_landmarks(lm, videos[by_frame[i]]["crop"]))
                      for i, lm in zip(pick, lms)])
    who = ident.identity(descs)
    spread = np.linalg.norm(descs - who, axis=1)
    tw, grid = fr.attrs["texture_window"], fr.attrs["grid"]
    np.savez(Path(folder) / "speaker.npz", shape3d=np.asarray(fr["model/shape3d"][...], np.float32),
             surface_depth=np.asarray(fr["model/depth"][...], np.float32),
             surface_grid=np.array([grid["x0"], grid["y0"], grid["step"]], np.float64),
             texture_window=np.array([tw["x0"], tw["y0"], tw["mm_per_px"], tw["size"]], np.float64),
             identity=who, identity_spread=spread.astype(np.float32), **head_of(src, fr, idx, videos, by_frame))
    # the candidate bank
    bank = spread_evenly(idx, bank_frames)
    g = create_group(Path(folder) / "bank.zarr", dict(texture_window=fr.attrs["texture_window"],
                                                      grid=fr.attrs["grid"], focal_factor=fr.attrs["focal_factor"],
                                                      n_training_frames=int(len(idx))))
    P = len(bank)
    c = min(64, P)
    for name in ("texture", "clothing_mask", "frontal_landmarks", "pose"):
        data = take(fr[name], bank)
        g.create_array(name, data=data, chunks=(c, *data.shape[1:]), shards=(-(-P // c) * c, *data.shape[1:]))
    g.create_array("frame", data=bank.astype(np.int64))
    size = sum(f.stat().st_size for f in (Path(folder) / "bank.zarr").rglob("*") if f.is_file())
    log.info("speaker: identity from %d frames (spread median %.3f, max %.3f); candidate bank %d of %d training "
             "frames, %.1f MB", len(pick), float(np.median(spread)), float(spread.max()), P, len(idx), size / 1e6)
    domain = audio_domain.export(folder, ingest_path)        # how far new audio may be from the training audio
    log.info("speaker: audio domain from the training MFCC; held-out clips shift %.3f (median) … %.3f (max)",
             domain["held_out_median"], domain["held_out_max"])
    return dict(identity_frames=int(len(pick)), identity_spread_max=float(spread.max()), bank_frames=int(P),
                bank_mb=round(size / 1e6, 2), audio_held_out_shift_max=domain["held_out_max"])


def add_head(folder, ingest_path: str, landmarks_path: str, frontalize_path: str) -> None:
    """Add the dense head's texture to a model folder written before it (same stores as its training)."""
    src, lmg, fr = open_group(ingest_path), open_group(landmarks_path), open_group(frontalize_path)
    idx, videos = training_frames(fr, lmg)
    by_frame = video_index(idx, videos)
    path = Path(folder) / "speaker.npz"
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    data.update(head_of(src, fr, idx, videos, by_frame))
    tmp = path.with_name("speaker.tmp.npz")
    np.savez(tmp, **data)
    os.replace(tmp, path)


def head_of(src, fr, idx: np.ndarray, videos: list[dict], by_frame: np.ndarray, n_frames: int = 41) -> dict:
    """The whole-face texture of the dense 3D head (``pipeline.face.head_texture``) from training frames
    ``idx`` facing the camera with the mouth shut: head_texture (H, W, 3) uint8, head_window (5,),
    head_landmarks (68, 2) mm — the median frontal landmarks of those frames, where the texture's features are."""
    tw = fr.attrs["texture_window"]
    grid = fr.attrs["grid"]
    surface = Surface(np.asarray(fr["model/depth"][...], np.float64), grid["x0"], grid["y0"], grid["step"])
    poses = take(fr["pose"], idx).astype(np.float64)
    lms = take(fr["frontal_landmarks"], idx).astype(np.float64) * tw["mm_per_px"] + [tw["x0"], tw["y0"]]
    pick = head.pick_still_frames(poses[:, :3], lms, n_frames)
    window = head.HeadWindow.covering(tw["mm_per_px"])
    vids = [videos[by_frame[i]] for i in idx[pick]]
    images = [_rgb(src["crops"][int(i)]) for i in idx[pick]]
    Ks = [intrinsics(v["width"], v["height"], fr.attrs["focal_factor"]) for v in vids]
    tex = head.head_texture(images, poses[pick], Ks, [v["crop"] for v in vids], surface, window)
    log.info("speaker: head texture %d × %d px (%.2f mm/px) from %d frontal closed-mouth frames",
             window.width, window.height, window.mm_per_px, len(pick))
    return dict(head_texture=tex, head_window=window.as_array(),
                head_landmarks=np.median(lms[pick], axis=0).astype(np.float32))


def _rgb(i420) -> np.ndarray:
    from pipeline.io.store import i420_to_rgb
    return i420_to_rgb(np.asarray(i420))

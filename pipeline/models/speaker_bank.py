"""What a model folder carries about its speaker, so ``lipsynth speak`` needs no corpus store.

    models/<model>/speaker.npz   shape3d (68, 3) mm — the corpus 3D face model (frontalize),
                                 surface_depth (H, W) mm, surface_grid [x0, y0, step] mm — its extended
                                 surface f*, texture_window [x0, y0, mm_per_px, size] (the mesh render),
                                 identity (128,) — median dlib face descriptor of training frames,
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
from pathlib import Path

import numpy as np

from pipeline.audio import audio_domain
from pipeline.face import identity as ident
from pipeline.io.store import create_group, open_group, take

log = logging.getLogger("lipsynth.speaker_bank")


def training_frames(fr, lmg) -> tuple[np.ndarray, list[dict]]:
    """Global indices of the training videos' frames with a valid pose and landmarks, and those videos."""
    videos = [v for v in fr.attrs["videos"] if v["split"] == "train" and v["n_frames"] and not v.get("excluded")]
    ok = np.asarray(fr["pose_valid"][...]) & np.asarray(lmg["valid"][...])
    idx = np.concatenate([np.arange(v["first_frame"], v["first_frame"] + v["n_frames"]) for v in videos])
    return idx[ok[idx]], videos


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
    by_frame = np.zeros(int(idx.max()) + 1, np.int64)
    for k, v in enumerate(videos):
        by_frame[v["first_frame"]:v["first_frame"] + v["n_frames"]] = k
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
             identity=who, identity_spread=spread.astype(np.float32))
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


def _rgb(i420) -> np.ndarray:
    from pipeline.io.store import i420_to_rgb
    return i420_to_rgb(np.asarray(i420))

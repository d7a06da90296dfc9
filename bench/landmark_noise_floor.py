"""Landmark noise floor: how far do the tracked lip points move when a clip is merely re-encoded?

For each validation video of a preprocessed corpus: re-encode it with H.264 at --crf (default
28), cut the same face crop, track landmarks again and frontalize them with the corpus' own 3D
model and surface, then compare the 18 frontal lip points of the two trackings. Prints the mean
error (canonical texture pixels and % inter-ocular distance) next to the model's and the
baselines' validation errors from the train metrics, if given.

    python bench/landmark_noise_floor.py --params /path/to/params.yaml [--crf 28] [--max-videos 60]

Run it from the corpus's project root: the params' store paths and the video paths the stores
record are relative to it.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import av
import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from pipeline.io import media  # noqa: E402
from pipeline.face.canonical import Surface, TextureWindow, frontal_landmarks  # noqa: E402
from pipeline.face.dlib_face import IOD_MM, LIP_POINTS  # noqa: E402
from pipeline.face.geometry import intrinsics, solve_pose  # noqa: E402
from pipeline.params import load_params  # noqa: E402
from pipeline.io.store import open_group  # noqa: E402
from stages.frontalize import model3d  # noqa: E402
from stages.ingest.crop import cut_crop  # noqa: E402
from stages.landmarks.landmarks import track_video  # noqa: E402


def reencode(src: str, dst: str, crf: int) -> None:
    """Re-encode the video stream with libx264 at ``crf`` (audio is not needed here)."""
    with av.open(src) as ic, av.open(dst, "w") as oc:
        iv = ic.streams.video[0]
        ov = oc.add_stream("libx264", rate=iv.average_rate, options={"crf": str(crf), "preset": "medium"})
        ov.width, ov.height, ov.pix_fmt = iv.codec_context.width, iv.codec_context.height, "yuv420p"
        for frame in ic.decode(iv):
            frame.pts = None
            for p in ov.encode(frame):
                oc.mux(p)
        for p in ov.encode():
            oc.mux(p)


def frontal_lips(lms, valid, shape, surface, win, K):
    out = np.full((len(lms), len(LIP_POINTS), 2), np.nan)
    for i, (lm, ok) in enumerate(zip(lms, valid)):
        if not ok:
            continue
        rvec, tvec, _ = solve_pose(shape[model3d.RIGID], lm[model3d.RIGID], K)
        xy = frontal_landmarks(lm.astype(np.float64), shape[:, :2], surface, rvec, tvec, K)
        out[i] = win.to_pixels(xy)[LIP_POINTS]
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", required=True)
    ap.add_argument("--crf", type=int, default=28)
    ap.add_argument("--max-videos", type=int, default=60)
    a = ap.parse_args()
    params = load_params(a.params)
    src = open_group(params.ingest.out)
    lmg = open_group(params.landmarks.out)
    fr = open_group(params.frontalize.out)
    shape = np.asarray(fr["model/shape3d"][...], np.float64)
    g = fr.attrs["grid"]
    surface = Surface(np.asarray(fr["model/depth"][...], np.float64), g["x0"], g["y0"], g["step"])
    win = TextureWindow(**fr.attrs["texture_window"])
    iod = IOD_MM / win.mm_per_px
    S = src.attrs["crop_size"]
    errs, static = [], []
    videos = [v for v in fr.attrs["videos"] if v["split"] == "val" and not v.get("excluded")][:a.max_videos]
    with tempfile.TemporaryDirectory() as tmp:
        for v in videos:
            sl = slice(v["first_frame"], v["first_frame"] + v["n_frames"])
            K = intrinsics(v["width"], v["height"], params.frontalize.focal_factor)
            x0, y0, s = v["crop"]
            orig = np.asarray(lmg["landmarks"][sl], np.float64)
            ok0 = np.asarray(lmg["valid"][sl])
            dst = str(Path(tmp) / "re.mp4")
            reencode(v["path"], dst, a.crf)
            crops = [cut_crop(yuv, (x0, y0, s * S), S)[:S] for _, yuv in media.iter_frames(dst, fmt="yuv")]
            lm1, _, ok1, _ = track_video(crops, params.landmarks)
            lm1 = lm1 * s + np.array([x0, y0])
            n = min(len(lm1), len(orig))
            ok = ok0[:n] & ok1[:n]
            a0 = frontal_lips(orig[:n], ok, shape, surface, win, K)
            a1 = frontal_lips(lm1[:n], ok, shape, surface, win, K)
            e = np.linalg.norm(a0 - a1, axis=-1).mean(-1)
            errs.append(e[ok])
            static.append(np.linalg.norm(a0[ok] - np.nanmean(a0[ok], axis=0), axis=-1).mean(-1))
    e, st = np.concatenate(errs), np.concatenate(static)
    print(f"{len(videos)} validation videos, {len(e)} frames, re-encoded with H.264 CRF {a.crf}")
    print(f"noise floor (tracking vs tracking after re-encode): {e.mean():.3f} px = {100 * e.mean() / iod:.2f}% IOD "
          f"(median {np.median(e):.3f} px)")
    print(f"each clip's own static mean mouth vs its tracking:   {st.mean():.3f} px = {100 * st.mean() / iod:.2f}% IOD")
    mpath = Path(params.train.metrics)
    if mpath.exists():
        m = json.loads(mpath.read_text())
        for name, d in (("LSTM (d=%d)" % m["delay_steps"], m["val"]), ("LSTM (d=0)", m.get("baseline_lstm_delay0")),
                        ("mean shape", m["baseline_mean_shape"])):
            if d:
                print(f"{name:<12} validation mouth error {d['mouth_error_px']:.3f} px = {d['mouth_error_iod_pct']:.2f}% IOD "
                      f"({d['mouth_error_px'] / e.mean():.2f}× the noise floor)")


if __name__ == "__main__":
    main()

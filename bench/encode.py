"""H.264 encoding cost per x264 setting: the last phase of every ``lipsynth speak`` frame.

    python bench/encode.py            # results/encode.json, docs/encode.md

Encodes the first ``--frames`` frames of obama_08 (720p) and of the same clip upscaled to 1080p (bench/synthesize.py
writes it) with ``pipeline.io.video_writer.VideoWriter`` (OpenCV's I420 conversion, then x264 on one thread, CRF 18,
as compositing does), for each setting of ``SETTINGS``. Per setting: ms/frame (median of ``--repeats`` runs of
thread time), the file's bitrate, and PSNR of the decoded luma against the frames that went in (quality at equal
CRF). The default (``composite.preset`` + ``composite.x264_options``) is what ``speak`` runs.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

from pipeline.io import media                           # noqa: E402  (caps the SIMD level before NumPy loads)
from bench.bench_results import publish, stamp          # noqa: E402
import numpy as np                                      # noqa: E402

SETTINGS = [("veryfast", ""), ("veryfast", "me=dia"), ("veryfast", "me=dia:subme=1"), ("superfast", ""),
            ("superfast", "mbtree=1:rc-lookahead=10")]
CLIPS = {"720p": ROOT.parent / "shared" / "data" / "obama" / "obama_08.mp4",
         "1080p": ROOT / "bench" / "results" / "synthesize" / "obama_08_1080p.mp4"}


def frames_of(video: Path, n: int) -> list[np.ndarray]:
    """The first ``n`` RGB frames (H, W, 3) uint8 of ``video``."""
    out = []
    for _, rgb in media.iter_frames(video):
        out.append(rgb)
        if len(out) == n:
            break
    return out


def psnr_luma(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) between the BT.601 luma of two (H, W, 3) uint8 RGB frames."""
    w = np.array([0.299, 0.587, 0.114], np.float32)
    d = a.astype(np.float32) @ w - b.astype(np.float32) @ w
    return float(10 * np.log10(255.0 ** 2 / max(float(np.mean(d * d)), 1e-12)))


def encode(frames: list[np.ndarray], fps: float, preset: str, options: str, out: Path) -> float:
    """Thread time (s) of writing ``frames`` with one setting."""
    t0 = time.thread_time()
    with media.VideoWriter(out, fps, 18, preset, x264_options=options) as w:
        for f in frames:
            w.write(f)
    return time.thread_time() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    rows = []
    for name, clip in CLIPS.items():
        if not clip.is_file():
            sys.exit(f"bench/encode.py: {clip} is missing (bench/synthesize.py --only 1080p writes the 1080p clip)")
        frames = frames_of(clip, a.frames)
        fps = media.probe(clip).fps
        for preset, options in SETTINGS:
            with tempfile.TemporaryDirectory() as d:
                out = Path(d) / "x.mp4"
                secs = [encode(frames, fps, preset, options, out) for _ in range(a.repeats)]
                kbit = out.stat().st_size * 8 / 1000 / (len(frames) / fps)
                decoded = frames_of(out, len(frames))
            psnr = float(np.mean([psnr_luma(x, y) for x, y in zip(frames, decoded)]))
            rows.append(dict(clip=name, preset=preset, options=options, ms_per_frame=round(1000 * float(np.median(secs)) / len(frames), 2),
                             kbit_per_s=round(kbit), psnr_luma=round(psnr, 2)))
            print(f"{name:6} {preset:10} {options or '-':28} {rows[-1]['ms_per_frame']:6.1f} ms/frame "
                  f"{rows[-1]['kbit_per_s']:6d} kbit/s  PSNR {psnr:.2f} dB")
    s = stamp()
    lines = ["<!-- written by bench/encode.py from results/encode.json; do not edit -->", "# Encoding cost", "",
             f"`python bench/encode.py`: the first {a.frames} frames of obama_08 (720p) and of the same clip upscaled to "
             "1080p through lipsynth's video writer (OpenCV's I420 conversion, x264 on one thread, CRF 18); ms/frame is "
             f"thread time, median of {a.repeats} runs; PSNR of the decoded luma against the frames written. "
             f"Measured at {s['commit']} on {s['date']} ({s['machine']}). `composite.preset` and `composite.x264_options` "
             "choose the setting.", "",
             "| clip | preset | x264 options | ms/frame | kbit/s | PSNR luma (dB) |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['clip']} | {r['preset']} | {r['options'] or '—'} | {r['ms_per_frame']:.1f} | {r['kbit_per_s']} | "
              f"{r['psnr_luma']:.2f} |" for r in rows]
    publish("encode", dict(stamp=s, frames=a.frames, repeats=a.repeats, rows=rows), "\n".join(lines))


if __name__ == "__main__":
    main()

"""``lipsynth cut`` — one video as consecutive segment files, for a corpus split in time.

    lipsynth cut VIDEO --out data/NAME [--seconds 10]

Writes ``data/NAME/<stem>_s000.mp4``, ``_s001``, … (H.264 + AAC, each segment in sync from its
first frame). With ``data.videos: data/NAME`` and ``data.split: time`` in params.yaml, ``dvc repro``
trains on the start of the footage and validates on its last ``data.val_fraction``.
"""
from __future__ import annotations

import argparse

from pipeline.io.runner import run_main, setup_logging
from pipeline.io.segments import cut_video


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth cut", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("video")
    ap.add_argument("--out", required=True, help="folder for the segments (created)")
    ap.add_argument("--seconds", type=float, default=10.0, help="segment length (default 10 s)")
    a = ap.parse_args(argv)
    setup_logging(False)
    return run_main(lambda: print("\n".join(str(p) for p in cut_video(a.video, a.seconds, a.out))))


if __name__ == "__main__":
    raise SystemExit(main())

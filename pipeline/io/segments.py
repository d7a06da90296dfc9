"""One long video as consecutive segment files, so a corpus of one video can be split in time.

The store splits training from validation by whole video (``stages/ingest.split_videos``). A user
with one minute of one person has one video; cut into segments named ``<stem>_s000``,
``<stem>_s001``, … in time order, ``data.split: time`` holds out the last ``data.val_fraction``
of each video's segments — the end of the footage — and no training sequence ever reaches into the
held-out time (each segment is its own sequence). The index records the segment files; evaluation
and ``speak`` read them like any clip.

Segments are re-encoded (H.264 CRF ``crf``, AAC 48 kHz mono) from the decoded frames and the audio
aligned to the first frame, so every segment starts on its own first frame and its audio is in sync.
"""
from __future__ import annotations

import logging
import re
import shutil
from pathlib import Path

from pipeline.errors import BadInputError, ParameterError
from pipeline.io import media

log = logging.getLogger("lipsynth.segments")
SEGMENT = re.compile(r"^(?P<stem>.+)_s(?P<index>\d{3})$")
AUDIO_RATE = 48000


def segment_bounds(duration: float, seconds: float) -> list[tuple[float, float]]:
    """Consecutive [start, end) intervals (s) of about ``seconds`` covering ``duration``; a last piece
    shorter than half a segment joins the one before.

    >>> segment_bounds(24.0, 10.0)
    [(0.0, 10.0), (10.0, 24.0)]
    """
    if seconds <= 0:
        raise ParameterError(f"segment length {seconds} s: must be positive")
    n = max(1, int(duration // seconds))
    if duration - n * seconds >= seconds / 2:
        n += 1
    edges = [min(i * seconds, duration) for i in range(n)] + [duration]
    return [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:])]


def segment_group(name: str) -> tuple[str, int] | None:
    """(source stem, index) of a segment's name, or None for a whole video."""
    m = SEGMENT.match(name)
    return (m["stem"], int(m["index"])) if m else None


def video_seconds(info: media.VideoInfo) -> float:
    """The duration of a probed video's frames (s): frame count / rate, else the container's."""
    return info.n_frames / info.fps if info.n_frames else info.duration


def cut_video(path, seconds: float, out_dir, crf: int = 18, stem: str | None = None, first_index: int = 0,
              min_segments: int = 2) -> list[Path]:
    """Write ``path`` as segment files ``out_dir/<stem>_sNNN.mp4`` (created atomically: all or none).

    ``stem`` (default: the file's) and ``first_index`` number the segments, so several short clips
    can be cut into one group (``data.split: time`` then holds out the group's last segments: the
    last clips). Raises BadInputError for a file without audio or with fewer than ``min_segments``
    segments' worth of footage.
    """
    path, out_dir = Path(path), Path(out_dir)
    info = media.probe(path)
    if not info.has_audio:
        raise BadInputError(path, "no audio track (a person's footage must have their speech)")
    samples, a_start = media.read_audio(path, AUDIO_RATE)
    frames = media.iter_frames(path)
    first = next(frames, None)
    if first is None:
        raise BadInputError(path, "no decodable video frames")
    v_start = first[0]
    duration = video_seconds(info)                                  # the video's, not the audio's
    bounds = segment_bounds(duration, seconds)
    if len(bounds) < min_segments:
        raise BadInputError(path, f"{duration:.1f} s of footage: too short to split into training and held-out "
                                  f"parts of {seconds:g} s (needs at least {1.5 * seconds:g} s)")
    audio = media.align_audio(samples, a_start, v_start, duration + 1.0, AUDIO_RATE)
    tmp = out_dir.parent / f".{out_dir.name}.tmp-segments"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    written = []
    try:
        pending = first
        for k, (t0, t1) in enumerate(bounds):
            a0, a1 = int(round(t0 * AUDIO_RATE)), int(round(t1 * AUDIO_RATE))
            target = tmp / f"{stem or path.stem}_s{first_index + k:03d}.mp4"
            with media.VideoWriter(target, info.fps, crf, audio=audio[a0:a1], sample_rate=AUDIO_RATE) as w:
                last = k == len(bounds) - 1
                while pending is not None and (last or pending[0] - v_start < t1 - 0.5 / info.fps):
                    w.write(pending[1])
                    pending = next(frames, None)
            written.append(target.name)
        out_dir.mkdir(parents=True, exist_ok=True)
        for name in written:
            (tmp / name).replace(out_dir / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    log.info("%s: %.1f s cut into %d segments of ~%g s in %s", path, duration, len(written), seconds, out_dir)
    return [out_dir / n for n in written]


def time_split(names: list[str], val_fraction: float) -> dict[str, str]:
    """``data.split: time``: in each group of segments of one source (``<stem>_sNNN``), the last
    ``round(val_fraction · n)`` (at least one when n ≥ 2) are validation; a whole video is training.
    """
    if not 0 <= val_fraction < 1:
        raise ParameterError(f"data.val_fraction={val_fraction}: must be in [0, 1)")
    groups: dict[str, list[tuple[int, str]]] = {}
    out = {}
    for n in names:
        g = segment_group(n)
        if g is None:
            out[n] = "train"
        else:
            groups.setdefault(g[0], []).append((g[1], n))
    for members in groups.values():
        members.sort()
        n_val = int(round(val_fraction * len(members)))
        if val_fraction > 0 and len(members) >= 2:
            n_val = max(1, n_val)
        for i, (_, name) in enumerate(members):
            out[name] = "val" if i >= len(members) - n_val else "train"
    return out

"""Media I/O with PyAV (bundled FFmpeg): probe, decode frames with timestamps, decode audio.

All times are in seconds on the container's clock; audio is returned aligned to the first
video frame so that sample 0 is heard when frame 0 is shown.

Frames come out as players show them: a display rotation (a phone's portrait video: the
display matrix, 90/180/270°) is applied, and non-square pixels (a sample aspect ratio other
than 1, as DV and broadcast sources store them) are resampled to square ones along the width.
``probe`` reports that displayed size. Writing (H.264 + AAC) lives in ``video_writer``; its
``VideoWriter`` and ``write_video`` are importable from here too.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Iterator

import av
import cv2
import numpy as np

from pipeline.errors import BadInputError
from pipeline.io.video_writer import VideoWriter, write_video  # noqa: F401  (media I/O in one place for callers)

log = logging.getLogger("lipsynth.media")


@dataclass
class VideoInfo:
    """What a container holds. ``fps`` is the video stream's average rate (frames/s)."""

    path: str
    width: int
    height: int
    fps: float
    duration: float          # seconds, from the container (may be approximate)
    n_frames: int            # frame count from the header (0 if the container does not say)
    has_audio: bool
    audio_rate: int | None   # Hz of the first audio stream
    audio_channels: int | None


@dataclass(frozen=True)
class Display:
    """How a stream's decoded frames become what players show: ``turns`` clockwise quarter turns,
    then the width scaled by ``sar`` (sample aspect ratio) to square pixels."""
    turns: int = 0
    sar: Fraction = Fraction(1)

    @property
    def identity(self) -> bool:
        return self.turns == 0 and self.sar == 1

    def size(self, width: int, height: int) -> tuple[int, int]:
        """(width, height) shown for a coded (width, height)."""
        w = square_width(width, self.sar)
        return (height, w) if self.turns % 2 else (w, height)


MAX_SIDE = 4320                  #: frames whose displayed long side exceeds this (8K) are refused


def square_width(width: int, sar: Fraction) -> int:
    """The width (px, even) of a row of ``width`` samples of aspect ``sar`` in square pixels."""
    return width if sar == 1 else max(2, int(round(width * sar / 2)) * 2)


def display_of(frame: av.VideoFrame, stream, path) -> Display:
    """The display transform of a decoded frame of ``stream`` (the frame's DISPLAYMATRIX side data,
    the stream's sample aspect ratio). Raises BadInputError for a rotation that is not a multiple of 90°."""
    angle = -float(frame.rotation or 0)                    # FFmpeg: counter-clockwise; players turn it back
    if abs(angle / 90 - round(angle / 90)) > 1e-3:
        raise BadInputError(path, f"display rotation of {angle:g}° (only multiples of 90° are supported)")
    sar = stream.codec_context.sample_aspect_ratio or stream.sample_aspect_ratio
    sar = Fraction(sar) if sar and sar > 0 else Fraction(1)
    return Display(int(round(angle / 90)) % 4, sar)


def _shown(img: np.ndarray, d: Display, interpolation=cv2.INTER_AREA) -> np.ndarray:
    """One image (H, W[, C]) or plane as shown: resampled to square pixels, then turned."""
    if d.sar != 1:
        w = square_width(img.shape[1], d.sar)
        img = cv2.resize(img, (w, img.shape[0]), interpolation=cv2.INTER_LINEAR if w > img.shape[1] else interpolation)
    if d.turns:
        img = np.ascontiguousarray(np.rot90(img, -d.turns))
    return img


def _open(path) -> av.container.InputContainer:
    path = Path(path)
    if not path.exists():
        raise BadInputError(path, "file not found")
    if path.stat().st_size == 0:
        raise BadInputError(path, "file is empty (0 bytes)")
    try:
        return av.open(str(path))
    except (av.error.FFmpegError, UnicodeDecodeError) as exc:  # corrupt or not media
        raise BadInputError(path, f"cannot be opened as media ({exc.__class__.__name__}): corrupt or not a video file") from None


def probe(path) -> VideoInfo:
    """Read stream metadata without decoding. Raises BadInputError if there is no video stream."""
    with _open(path) as c:
        if not c.streams.video:
            raise BadInputError(path, "no video stream")
        v = c.streams.video[0]
        rate = _stream_rate(v, path)
        a = c.streams.audio[0] if c.streams.audio else None
        dur = float(c.duration / av.time_base) if c.duration else (
            float(v.duration * v.time_base) if v.duration else 0.0)
        width, height = v.codec_context.width, v.codec_context.height
        try:
            first = next(c.decode(v), None)
        except av.error.FFmpegError:
            first = None
        if first is not None:
            width, height = display_of(first, v, path).size(first.width, first.height)
        if max(width, height) > MAX_SIDE:
            raise BadInputError(path, f"{width}×{height} frames: larger than the {MAX_SIDE}-px long side lipsynth "
                                      f"processes (8K and above; scale the video down first)")
        return VideoInfo(str(path), width, height, float(rate), dur,
                         int(v.frames or 0), a is not None, a.codec_context.sample_rate if a else None,
                         a.codec_context.channels if a else None)


def yuv_planes(frame: av.VideoFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Y (H, W), U and V (⌈H/2⌉, ⌈W/2⌉) uint8 planes of a frame, converted to 4:2:0 if needed."""
    if frame.format.name != "yuv420p":
        frame = frame.reformat(format="yuv420p")
    out = []
    for plane in frame.planes:
        buf = np.frombuffer(plane, np.uint8).reshape(-1, plane.line_size)
        out.append(np.ascontiguousarray(buf[:plane.height, :plane.width]))   # drop row padding (dlib ignores strides)
    return out[0], out[1], out[2]


def constant_rate(timed: Iterator[tuple[float, object]], fps: float) -> Iterator[tuple[float, object]]:
    """Frames of any timing → frames on the grid ``t0 + k / fps`` (what players show).

    Slot k shows the latest frame whose time is at most half a period after the slot, so a
    constant-rate stream passes unchanged (timestamp jitter below half a frame is ignored), a
    variable-rate one (phones, screen recorders) has frames repeated over its gaps and dropped
    where they crowd. The last frame lasts one period. Times that go backwards are clamped.

    Parameters
    ----------
    timed : iterator of tuple
        (t, image) in presentation order, t in s.
    fps : float
        Output rate, frames/s (the stream's average rate keeps the frame count).

    Yields
    ------
    tuple
        (s_k, image) with s_k = t0 + k / fps exactly (s).
    """
    period, half = 1.0 / fps, 0.5 / fps
    t0, k, prev, last_t = None, 0, None, None
    for t, img in timed:
        if t0 is None:
            t0, prev, last_t = t, img, t
            continue
        t = max(t, last_t)
        while t0 + k * period + half < t:         # slot k ends before this frame starts: it shows prev
            yield t0 + k * period, prev
            k += 1
        prev, last_t = img, t
    if t0 is None:
        return
    while t0 + k * period < last_t + half:         # the last frame's own period
        yield t0 + k * period, prev
        k += 1


def iter_frames(path, fmt: str = "rgb24", keyframes_only: bool = False) -> Iterator[tuple[float, object]]:
    """Yield ``(t, image)`` for each frame as a player shows it, on the stream's average rate.

    Frames are turned by the display rotation, resampled to square pixels, and put on the
    constant-rate grid of ``constant_rate`` (variable frame rate → repeated or dropped frames);
    ``keyframes_only`` yields the key frames at their own times.

    Parameters
    ----------
    path : str or Path
        The video file.
    fmt : str
        ``rgb24`` gives (H, W, 3) uint8; ``yuv`` gives the (Y, U, V) planes of ``yuv_planes``
        (no colour conversion: cheapest); ``gray`` gives the Y plane (H, W).
    keyframes_only : bool
        Decode only key frames (fast sparse sampling of a long video).

    Yields
    ------
    t : float
        Presentation time in seconds (stream clock).
    image : ndarray or tuple of ndarray
        The frame in ``fmt``.
    """
    if keyframes_only:
        yield from _decoded(path, fmt, True)
        return
    yield from constant_rate(_decoded(path, fmt, False), probe_rate(path))


def probe_rate(path) -> float:
    """The video stream's average frame rate (frames/s), as ``probe`` reports it."""
    with _open(path) as c:
        if not c.streams.video:
            raise BadInputError(path, "no video stream")
        return _stream_rate(c.streams.video[0], path)


def _stream_rate(v, path) -> float:
    rate = v.average_rate or v.guessed_rate or v.base_rate
    if not rate or float(rate) <= 0:
        raise BadInputError(path, "video stream has no usable frame rate")
    return float(rate)


DECODE_THREADS = 2     #: FFmpeg threads per decoder (frame and slice threading): a 720p H.264 clip decodes in ≈ 0.6×
                       #: the time of one thread. FFmpeg's decoders give the same pixels with any threading. Two, not
                       #: all cores: preprocessing runs a decoder in each dask worker.


def _decoded(path, fmt: str, keyframes_only: bool) -> Iterator[tuple[float, object]]:
    """Every decoded frame at its own presentation time, upright and with square pixels."""
    with _open(path) as c:
        if not c.streams.video:
            raise BadInputError(path, "no video stream")
        v = c.streams.video[0]
        if keyframes_only:
            v.codec_context.skip_frame = "NONKEY"
        else:
            v.thread_type, v.codec_context.thread_count = "AUTO", DECODE_THREADS
        display = None
        try:
            for frame in c.decode(v):
                t = float(frame.pts * v.time_base) if frame.pts is not None else float(frame.time or 0.0)
                display = display or display_of(frame, v, path)
                if display.identity:
                    if fmt == "yuv":
                        yield t, yuv_planes(frame)
                    elif fmt == "gray":
                        yield t, yuv_planes(frame)[0]
                    else:
                        yield t, np.ascontiguousarray(frame.to_ndarray(format=fmt))
                elif fmt == "yuv":
                    y, u, w = yuv_planes(frame)
                    y = _shown(y, display)
                    h2, w2 = (y.shape[0] + 1) // 2, (y.shape[1] + 1) // 2
                    yield t, (y, *(cv2.resize(_shown(q, display), (w2, h2), interpolation=cv2.INTER_AREA) for q in (u, w)))
                elif fmt == "gray":
                    yield t, _shown(yuv_planes(frame)[0], display)
                else:
                    yield t, _shown(np.ascontiguousarray(frame.to_ndarray(format=fmt)), display)
        except av.error.FFmpegError as exc:
            raise BadInputError(path, f"video stream is corrupt ({exc})") from None


MAX_DAMAGED_AUDIO = 0.5       # share of undecodable audio packets above which a track is refused ("mostly")


def read_audio(path, sample_rate: int = 16000) -> tuple[np.ndarray, float]:
    """Decode the first audio stream, down-mixed to mono and resampled.

    An isolated damaged packet (a real-world kind of damage: one bad MP2 frame among hundreds)
    is concealed as FFmpeg's command line does — replaced by silence of the packet's duration,
    so later samples keep their time — with a warning that counts them. A track with more than
    ``MAX_DAMAGED_AUDIO`` of its packets undecodable is refused.

    Returns
    -------
    samples : ndarray
        (S,) float32 in [-1, 1], at ``sample_rate`` Hz.
    start : float
        Time (s, stream clock) of the first sample.
    """
    with _open(path) as c:
        if not c.streams.audio:
            raise BadInputError(path, "no audio track")
        a = c.streams.audio[0]
        res = av.AudioResampler(format="flt", layout="mono", rate=sample_rate)
        chunks, start, packets, damaged = [], None, 0, 0
        try:
            for packet in c.demux(a):
                packets += packet.size > 0                 # (the last, empty packet flushes the decoder)
                try:
                    frames = packet.decode()
                except av.error.InvalidDataError:
                    damaged += 1
                    seconds = float(packet.duration * packet.time_base) if packet.duration else 0.0
                    chunks.append(np.zeros(int(round(seconds * sample_rate)), np.float32))
                    continue
                for frame in frames:
                    if start is None and frame.pts is not None:
                        start = float(frame.pts * a.time_base)
                    for out in res.resample(frame):
                        chunks.append(out.to_ndarray().reshape(-1))
            for out in res.resample(None):
                chunks.append(out.to_ndarray().reshape(-1))
        except av.error.FFmpegError as exc:
            raise BadInputError(path, f"audio stream is corrupt ({exc})") from None
        declared = float(a.duration * a.time_base) if a.duration else None
    if packets and damaged > MAX_DAMAGED_AUDIO * packets:
        raise BadInputError(path, f"audio stream is mostly undecodable ({damaged} of {packets} packets damaged)")
    if damaged:
        log.warning("%s: concealed %d damaged audio packet(s) of %d with silence", path, damaged, packets)
    if not chunks or not any(len(ch) for ch in chunks):
        raise BadInputError(path, "audio track holds no samples")
    samples = np.concatenate(chunks).astype(np.float32)
    bad = int((~np.isfinite(samples)).sum())
    if bad:
        raise BadInputError(path, f"audio holds {bad} NaN or infinite samples (of {len(samples)}): not a valid recording")
    if declared:  # AAC decoders emit the encoder's padding past the stream's declared end: drop it
        samples = samples[:int(round(declared * sample_rate))]
    return samples, float(start or 0.0)


def align_audio(samples: np.ndarray, audio_start: float, video_start: float, duration: float,
                sample_rate: int) -> np.ndarray:
    """Cut/pad ``samples`` so sample 0 plays at ``video_start`` and the length is ``duration``.

    Audio that starts after the video is preceded by silence; audio that starts before
    is trimmed; a short tail is padded with zeros. Returns float32 of
    ``round(duration * sample_rate)`` samples.
    """
    n = int(round(duration * sample_rate))
    offset = int(round((audio_start - video_start) * sample_rate))  # >0: audio starts late
    out = np.zeros(n, np.float32)
    src0 = max(0, -offset)
    dst0 = max(0, offset)
    m = min(n - dst0, len(samples) - src0)
    if m > 0:
        out[dst0:dst0 + m] = samples[src0:src0 + m]
    return out


class FrameReader:
    """Random access to the frames of a video, cheap when indices mostly increase.

    ``get(j)`` decodes forward from the current position; every decoded frame is kept in an
    LRU cache of ``cache_bytes`` (so ping-pong playback and re-timing's small backward steps
    cost nothing); a backward jump past the cache reopens the file. Frames are (H, W, 3) uint8
    RGB and must not be modified by the caller.
    """

    def __init__(self, path, cache_bytes: int = 1 << 30):
        from collections import OrderedDict
        self.path = str(path)
        self._it, self._pos = None, -1
        self._cache: OrderedDict = OrderedDict()
        self._budget, self._bytes = cache_bytes, 0

    def _restart(self):
        self._it = (img for _, img in iter_frames(self.path))
        self._pos = -1

    def _keep(self, j: int, img: np.ndarray) -> None:
        self._cache[j] = img
        self._bytes += img.nbytes
        while self._bytes > self._budget and len(self._cache) > 1:
            _, old = self._cache.popitem(last=False)
            self._bytes -= old.nbytes

    def get(self, j: int) -> np.ndarray:
        if j in self._cache:
            self._cache.move_to_end(j)
            return self._cache[j]
        if self._it is None or j < self._pos:
            self._restart()
        while self._pos < j:
            try:
                img = next(self._it)
            except StopIteration:
                raise BadInputError(self.path, f"has no frame {j} (only {self._pos + 1})") from None
            self._pos += 1
            self._keep(self._pos, img)
        return self._cache[j]

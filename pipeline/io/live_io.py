"""Live audio in, live video out (``lipsynth live``).

In: 16 kHz mono signed 16-bit little-endian PCM from a byte stream (stdin, a named pipe), raw or with a
WAV header (checked: a header of another rate, channel count or sample format is refused with one
line), read in blocks as it arrives; or any audio file PyAV reads, replayed at its real pace
(``paced_file``). Each block comes with the monotonic time it arrived.

Out: H.264 video with the audio muxed in as AAC, interleaved frame by frame, into MPEG-TS (a byte stream:
stdout for ``ffplay -``, or a file) or an HLS folder (``index.m3u8`` and 1-s segments, for a browser).
"""
from __future__ import annotations

import struct
import time
from fractions import Fraction
from pathlib import Path
from typing import BinaryIO, Iterator

import av
import cv2
import numpy as np

from pipeline.errors import BadInputError
from pipeline.io.video_writer import _rate

SAMPLE_RATE = 16000
BLOCK = 320                        #: samples per block read (20 ms)


def _read_exact(stream: BinaryIO, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = stream.read(n - len(data))
        if not chunk:
            break
        data += chunk
    return data


def skip_wav_header(stream: BinaryIO, name: str) -> bytes:
    """Consume a WAV header at the start of ``stream`` (refusing any format but 16 kHz mono s16le); returns
    the bytes read that are already audio (raw PCM: its first bytes)."""
    head = _read_exact(stream, 12)
    if head[:4] != b"RIFF" or head[8:12] != b"WAVE":
        return head
    while True:
        chunk = _read_exact(stream, 8)
        if len(chunk) < 8:
            raise BadInputError(name, "WAV header without a data chunk")
        tag, size = chunk[:4], struct.unpack("<I", chunk[4:])[0]
        if tag == b"data":
            return b""
        body = _read_exact(stream, size + (size & 1))
        if tag == b"fmt ":
            fmt, channels, rate, _, _, bits = struct.unpack("<HHIIHH", body[:16])
            if (fmt, channels, rate, bits) != (1, 1, SAMPLE_RATE, 16):
                raise BadInputError(name, f"audio stream is {'PCM' if fmt == 1 else f'format {fmt}'} {bits}-bit, "
                                          f"{channels} channel(s), {rate} Hz: live takes 16 kHz mono 16-bit PCM "
                                          f"(ffmpeg -i IN -f s16le -ar 16000 -ac 1 -)")


def pcm_blocks(stream: BinaryIO, name: str = "stdin", warn=None) -> Iterator[tuple[np.ndarray, float]]:
    """Blocks (≤ BLOCK,) float32 in [-1, 1] of a s16le byte stream (raw or WAV), each with its arrival time
    (s, monotonic). A stream that ends inside a sample drops the odd byte (``warn`` gets one line)."""
    pending = skip_wav_header(stream, name)
    read = getattr(stream, "read1", stream.read)
    while True:
        chunk = read(2 * BLOCK)
        now = time.monotonic()
        if not chunk:
            break
        pending += chunk
        n = len(pending) // 2
        if n:
            yield np.frombuffer(pending[:2 * n], "<i2").astype(np.float32) / 32768.0, now
            pending = pending[2 * n:]
    if pending and warn is not None:
        warn(f"{name}: the audio stream ended inside a sample (1 odd byte dropped)")


def paced_file(path: str, realtime: bool = True) -> Iterator[tuple[np.ndarray, float]]:
    """Blocks of an audio file (any format PyAV reads, resampled to 16 kHz mono), released at the pace the
    audio plays when ``realtime`` (else at once), each with its release time."""
    from pipeline.io.media import read_audio
    samples, _ = read_audio(path, SAMPLE_RATE)
    start = time.monotonic()
    for a in range(0, len(samples), BLOCK):
        if realtime:
            due = start + (a + BLOCK) / SAMPLE_RATE            # a block exists once its last sample was spoken
            time.sleep(max(0.0, due - time.monotonic()))
        yield samples[a:a + BLOCK], time.monotonic()


class StreamWriter:
    """Interleaved H.264 + AAC into MPEG-TS (``target``: a path or a binary file object) or HLS
    (``hls_dir``). ``write(frame, audio)``: one RGB frame (H, W, 3) uint8 and the audio that plays
    during it (float32 at ``sample_rate``)."""

    def __init__(self, target, fps: float, size: tuple[int, int], sample_rate: int = SAMPLE_RATE,
                 hls_dir: Path | None = None, preset: str = "veryfast", crf: int = 23):
        if hls_dir is not None:
            hls_dir.mkdir(parents=True, exist_ok=True)
            self.container = av.open(str(hls_dir / "index.m3u8"), "w", format="hls",
                                     options=dict(hls_time="1", hls_list_size="0", hls_flags="independent_segments",
                                                  hls_segment_type="mpegts"))
        else:
            self.container = av.open(target, "w", format="mpegts")
        rate = _rate(fps)
        self.video = self.container.add_stream("libx264", rate=rate)
        self.video.width, self.video.height = size
        self.video.pix_fmt = "yuv420p"
        self.video.time_base = 1 / rate
        gop = max(1, int(round(fps)))                       # a key frame each second: HLS cuts segments there
        self.video.codec_context.gop_size = gop
        self.video.options = dict(preset=preset, tune="zerolatency", crf=str(crf), bframes="0",
                                  **{"x264-params": f"keyint={gop}:min-keyint={gop}:scenecut=0"})
        self.audio = self.container.add_stream("aac", rate=sample_rate)
        self.audio.layout = "mono"
        self.sample_rate = sample_rate
        self.frames = self.samples = 0
        self.audio_fifo = av.AudioFifo()

    def write(self, frame: np.ndarray, audio: np.ndarray) -> None:
        i420 = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2YUV_I420)     # as video_writer: ≈ 10× swscale's speed
        vf = av.VideoFrame.from_ndarray(i420, format="yuv420p")
        vf.pts = self.frames
        self.frames += 1
        self._mux(self.video.encode(vf))
        a = np.ascontiguousarray(np.asarray(audio, np.float32)[None])
        af = av.AudioFrame.from_ndarray(a, format="flt", layout="mono")
        af.sample_rate = self.sample_rate
        af.pts = self.samples
        af.time_base = Fraction(1, self.sample_rate)
        self.samples += a.shape[1]
        self.audio_fifo.write(af)
        while self.audio_fifo.samples >= 1024:              # AAC frames are 1024 samples
            self._mux(self.audio.encode(self.audio_fifo.read(1024)))

    def _mux(self, packets) -> None:
        for packet in packets:
            self.container.mux(packet)

    def close(self) -> None:
        """Flush both encoders (the last partial AAC frame padded) and close the container."""
        rest = self.audio_fifo.read()
        if rest is not None:
            self._mux(self.audio.encode(rest))
        self._mux(self.video.encode(None))
        self._mux(self.audio.encode(None))
        self.container.close()

"""Bit-exact MP4 writing (H.264 video + AAC audio) with PyAV."""
from __future__ import annotations

from pathlib import Path

import av
import av.codec.context
import numpy as np

from pipeline.simd_level import x264_params

VIDEO_OPTIONS = {"crf": "18", "preset": "medium", "threads": "1"}
AUDIO_BIT_RATE = 64000
AAC_SAMPLE_RATES = (8000, 11025, 12000, 16000, 22050, 24000, 32000, 44100, 48000)


def write_mp4(path: Path, frames, audio: np.ndarray, fps: int, sample_rate: int,
              width: int, height: int) -> None:
    """Encode frames (H.264 yuv420p, crf 18, 1 thread) and mono AAC audio into an MP4.

    Audio is fed in step with the video (``sample_rate / fps`` samples per frame)
    so the muxer interleaves the streams.

    Parameters
    ----------
    path : Path
    frames : iterable of ndarray, (H, W, 3) uint8 RGB
    audio : ndarray, (N,) float32
    fps, sample_rate, width, height : int
    """
    with av.open(str(path), mode="w", format="mp4", options={"fflags": "+bitexact"}) as container:
        video = container.add_stream("libx264", rate=fps, options=dict(VIDEO_OPTIONS, **x264_params()))
        video.width, video.height, video.pix_fmt = width, height, "yuv420p"
        video.codec_context.thread_count = 1
        video.codec_context.flags |= av.codec.context.Flags.bitexact
        sound = container.add_stream("aac", rate=sample_rate, layout="mono")
        sound.bit_rate = AUDIO_BIT_RATE
        sound.codec_context.flags |= av.codec.context.Flags.bitexact
        audio_written = 0
        for index, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
            frame.pts = index
            container.mux(video.encode(frame))
            audio_until = min(int(round((index + 1) * sample_rate / fps)), len(audio))
            if audio_until > audio_written:
                chunk = av.AudioFrame.from_ndarray(audio[None, audio_written:audio_until],
                                                   format="fltp", layout="mono")
                chunk.sample_rate, chunk.pts = sample_rate, audio_written
                container.mux(sound.encode(chunk))
                audio_written = audio_until
        container.mux(video.encode(None))
        container.mux(sound.encode(None))

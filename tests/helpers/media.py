"""Small media files made on the fly for tests (PyAV), with a real face that dlib finds."""
from fractions import Fraction

import av
import numpy as np
import skimage.data


def face_frames(n, size=(320, 256)):
    """(n, H, W, 3) frames of a real face photo drifting slowly."""
    photo = skimage.data.astronaut()
    w, h = size
    out = []
    for i in range(n):
        dx, dy = int(10 * np.sin(i / 7)), int(6 * np.cos(i / 11))
        out.append(np.ascontiguousarray(photo[40 + dy:40 + dy + h, 60 + dx:60 + dx + w]))
    return np.stack(out)


def make_clip(path, n_frames=50, fps=Fraction(25), audio_rate=16000, channels=1, audio_delay=0.0,
              tone_at=None, frames=None, audio=True):
    """Write an H.264 clip; audio (a low hum, plus a loud tone from ``tone_at`` s of audio time)
    starts ``audio_delay`` s after (or, negative, before) the first video frame."""
    frames = face_frames(n_frames) if frames is None else frames
    with av.open(str(path), "w") as c:
        v = c.add_stream("libx264", rate=fps)
        v.height, v.width = frames.shape[1:3]
        v.pix_fmt = "yuv420p"
        a = None
        if audio:
            a = c.add_stream("aac", rate=audio_rate)
            a.layout = "stereo" if channels == 2 else "mono"
        video_start = int(round(max(0.0, -audio_delay) * float(fps)))   # negative delay: video starts later
        for i, img in enumerate(frames):
            fr = av.VideoFrame.from_ndarray(img, format="rgb24")
            fr.pts = video_start + i
            fr.time_base = 1 / Fraction(fps)
            for p in v.encode(fr):
                c.mux(p)
        for p in v.encode():
            c.mux(p)
        if a is not None:
            seconds = n_frames / float(fps) + 0.5
            t = np.arange(int(seconds * audio_rate)) / audio_rate
            x = 0.01 * np.sin(2 * np.pi * 150 * t)
            if tone_at is not None:
                x = np.where(t >= tone_at, 0.5 * np.sin(2 * np.pi * 440 * t), x)
            pcm = np.repeat(x[None].astype(np.float32), channels, 0)
            start = int(round(max(0.0, audio_delay) * audio_rate))
            step = 1024
            for i in range(0, pcm.shape[1], step):
                fr = av.AudioFrame.from_ndarray(np.ascontiguousarray(pcm[:, i:i + step].T.reshape(1, -1)),
                                                format="flt", layout=a.layout.name)
                fr.sample_rate = audio_rate
                fr.pts = start + i
                fr.time_base = Fraction(1, audio_rate)
                for p in a.encode(fr):
                    c.mux(p)
            for p in a.encode():
                c.mux(p)
    return path


def set_display_rotation(path, degrees: int) -> None:
    """Rewrite an MP4's track header matrix in place so that players turn the video clockwise by
    ``degrees`` (90/180/270), as a phone stores portrait video (frames stored sideways)."""
    import struct
    data = bytearray(open(path, "rb").read())
    i = data.find(b"tkhd")
    assert i > 0 and data[i + 4] == 0, "expected a version-0 tkhd box"
    one = 0x10000
    a, b = {90: (0, one), 180: (-one, 0), 270: (0, -one)}[degrees]
    # [a b 0; c d 0; 0 0 1] with c = -b, d = a (a rotation), 2.30 fixed point in the last column
    data[i + 44:i + 80] = struct.pack(">9i", a, b, 0, -b, a, 0, 0, 0, 0x40000000)
    open(path, "wb").write(bytes(data))


def make_anamorphic_clip(path, frames, sar=Fraction(2, 1), fps=Fraction(25)):
    """Write ``frames`` squeezed horizontally by ``sar`` with that sample aspect ratio in the stream."""
    import cv2
    h, w = frames.shape[1:3]
    narrow = max(2, int(round(w / sar / 2)) * 2)
    with av.open(str(path), "w") as c:
        v = c.add_stream("libx264", rate=fps)
        v.width, v.height, v.pix_fmt = narrow, h, "yuv420p"
        v.codec_context.sample_aspect_ratio = sar
        for img in frames:
            for p in v.encode(av.VideoFrame.from_ndarray(cv2.resize(img, (narrow, h), interpolation=cv2.INTER_AREA),
                                                         format="rgb24")):
                c.mux(p)
        for p in v.encode():
            c.mux(p)


def make_vfr_clip(path, times, size=(96, 64), frames=None, audio=None, sample_rate=48000):
    """Write a video whose frame i is shown at ``times[i]`` s (a variable frame rate, as phones
    record). Frames default to grey level ``4 * i`` (each shows its own index); ``audio`` (mono
    float32 at ``sample_rate``) adds an AAC track from 0 s."""
    if frames is None:
        frames = np.repeat((4 * np.arange(len(times), dtype=np.uint8))[:, None, None, None], 3, -1)
        frames = np.broadcast_to(frames, (len(times), size[1], size[0], 3))
    with av.open(str(path), "w") as c:
        v = c.add_stream("libx264", rate=25)
        v.width, v.height, v.pix_fmt = frames.shape[2], frames.shape[1], "yuv420p"
        v.codec_context.time_base = Fraction(1, 1000)
        v.options = {"crf": "0"}
        a = c.add_stream("aac", rate=sample_rate, layout="mono") if audio is not None else None
        for t, img in zip(times, frames):
            fr = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            fr.pts, fr.time_base = int(round(t * 1000)), Fraction(1, 1000)
            for p in v.encode(fr):
                c.mux(p)
        for p in v.encode():
            c.mux(p)
        if a is not None:
            for i in range(0, len(audio), 1024):
                fr = av.AudioFrame.from_ndarray(np.ascontiguousarray(audio[None, i:i + 1024], np.float32),
                                                format="flt", layout="mono")
                fr.sample_rate, fr.pts, fr.time_base = sample_rate, i, Fraction(1, sample_rate)
                for p in a.encode(fr):
                    c.mux(p)
            for p in a.encode():
                c.mux(p)
    return path


def write_wav(path, samples, rate, channels=1):
    """A 16-bit PCM WAV of ``samples`` (n,) in [-1, 1] at ``rate`` Hz, repeated over ``channels``; its path."""
    import wave
    pcm = np.clip(np.repeat(np.asarray(samples)[:, None], channels, 1) * 32767, -32768, 32767).astype("<i2")
    with wave.open(str(path), "wb") as w:
        w.setnchannels(channels)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(pcm.tobytes())
    return path

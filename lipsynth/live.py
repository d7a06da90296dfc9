"""``lipsynth live`` — a person speaking as the audio arrives: audio stream in, lip-synced video stream out.

    ffmpeg -i speech.m4a -f s16le -ar 16000 -ac 1 - | lipsynth live --target face.mp4 | ffplay -
    lipsynth live --target face.mp4 --audio speech.wav --realtime --out live.ts
    lipsynth live --target face.mp4 --audio speech.wav --realtime --hls live/

The target is preprocessed once (``lipsynth prepare TARGET --model MODEL``; live refuses a target that
is not, naming that command). Audio: 16 kHz mono s16le on stdin (``--audio -``, the default; raw or
WAV) or a named pipe, or any audio file (``--realtime`` replays it at the pace it plays). Video: the
target looping by ping-pong, H.264 + AAC in MPEG-TS on stdout (``--out -``) or a file, or an HLS
folder (``--hls DIR``).

The frames flow through overlapping stages, nothing waits for the whole audio: the causal front end
(``pipeline.audio.streaming_features``: windows of ``--past`` s before, ``--ahead`` s after, one every
``--hop`` s) and the LSTM stepped with its state (``pipeline.models.streaming_mouth``) → texture
synthesis (``stages.synthesize.texture_pool.synthesize_frame``; two-band detail from the nearest real
frame, held while it runs on) → composite (``stages.composite.composite.composite_frame``), on
``--threads`` workers → the muxer, in order. Silence gives the rest mouth; when the audio pauses
(a live stream with nothing arriving for ``--gap`` s) silence is fed at the clock's pace, so the
target keeps playing; when the machine falls behind by more than ``--max-behind`` s, frames repeat
the last one instead of being made, so audio and video never drift apart. ``--stats FILE.json``
writes each frame's latency (an audio sample's arrival → its frame leaving).

The self-check of ``speak`` (dlib re-reading every frame) is not run live: it needs frames after the
one it judges and costs a core's share; the target's 3D fit is checked before streaming starts.

Run as ``lipsynth live``, every numeric library runs at the CPU's full width (``LIPSYNTH_SIMD=native``): a live
stream repeats frames as timing dictates, so it has no bytes to keep the same across machines, and the AVX2
cap slows its Whisper encoder 2–3×. Set ``LIPSYNTH_SIMD`` (to anything) to keep the cap.
"""
from __future__ import annotations

import argparse
import logging
import signal
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from lipsynth.live_stream import STOP, stream
from pipeline.audio.streaming_features import STREAM
from pipeline.errors import BadInputError
from pipeline.io.live_io import paced_file, pcm_blocks
from pipeline.io.runner import run_main, setup_logging
from pipeline.io.store import i420_to_rgb
from pipeline.models.streaming_mouth import StreamingMouth
from pipeline.params import Params, load_params

log = logging.getLogger("lipsynth.live")


def ping_pong(k: int, n: int) -> int:
    """Target frame shown at output frame k when n target frames loop forward, backward, forward…"""
    if n <= 1:
        return 0
    r = k % (2 * (n - 1))
    return r if r < n else 2 * (n - 1) - r


class TargetFrames:
    """The target's frames held in memory as I420 (1.5 bytes per pixel; ping-pong reads them backward,
    which a decoder cannot do cheaply), at most ``max_bytes`` of them."""

    def __init__(self, path: str, max_bytes: float = 1.2e9):
        from pipeline.io.media import iter_frames
        self.frames = []
        size = 0
        for _, img in iter_frames(path):
            yuv = cv2.cvtColor(img, cv2.COLOR_RGB2YUV_I420)
            size += yuv.nbytes
            if size > max_bytes:
                log.warning("%s: only its first %d frames are looped (memory limit %.1f GB)", path, len(self.frames),
                            max_bytes / 1e9)
                break
            self.frames.append(yuv)
        self.shape = (self.frames[0].shape[0] * 2 // 3, self.frames[0].shape[1])

    def __len__(self) -> int:
        return len(self.frames)

    def rgb(self, j: int) -> np.ndarray:
        return i420_to_rgb(self.frames[j])


class DetailPicker:
    """Two-band detail sources chosen causally: the nearest real frame, or the previous source's next
    frame while it is within ``switch_cost`` of the nearest (``two_band.detail_sources`` without the
    future: no Viterbi, no cross-fade)."""

    def __init__(self, pool: np.ndarray, switch_cost: float):
        from stages.synthesize.two_band import next_rows
        self.next = next_rows(pool)
        self.switch_cost = switch_cost
        self.prev = -1

    def pick(self, cost: np.ndarray) -> list[tuple[int, float]]:
        best = int(np.argmin(cost))
        cont = self.next[self.prev] if self.prev >= 0 else -1
        self.prev = int(cont) if cont >= 0 and cost[cont] <= cost[best] + self.switch_cost else best
        return [(self.prev, 1.0)]


class LiveEngine:
    """Mouth shapes → textures → composited frames, for one prepared target (see the module doc)."""

    def __init__(self, p: Params, stores: dict, entry: dict, target: str, model: str, args):
        from stages.composite.composite import Target
        from stages.synthesize import texture as tx
        from stages.synthesize.synthesize import Retarget
        from stages.synthesize.texture_pool import REAL_DETAIL, texture_pool
        self.p, self.tx = p, tx
        self.fps = float(entry["fps"])
        self.mouth = StreamingMouth(model, self.fps, args.past, args.ahead, args.hop, args.pad)
        if self.mouth.retrieval:
            log.warning("%s: its retrieval candidate needs the future (a Viterbi path): live uses its parametric "
                        "read-out", model)
        self.tp = texture_pool(stores, entry, p.synthesize)
        self.tgt = Target(stores["frontalize"], entry, target)
        self.frames = TargetFrames(target)
        self.retarget = None
        if p.synthesize.retarget == "always":
            self.retarget = Retarget.fit(self.reference_lips(target, model), self.mouth.mean_shape, self.tp.shapes,
                                         p.synthesize.max_spread_gain)
        self.detail = DetailPicker(self.tp.pool, p.synthesize.detail_switch_cost) \
            if self.tp.method in REAL_DETAIL else None
        self.thread_ms = dict(texture=[], composite=[], encode=[])      # per frame, thread time
        self.warm_geometry(args.threads)

    def warm_geometry(self, threads: int) -> None:
        """Each target frame's geometry (masks, colour statistics, ray map: ≈ 5 ms a 720p frame), made before the
        stream starts, in the order the first ping-pong pass shows them, as far as the cache holds them. Made on
        demand instead, the first pass through the target costs every frame that much more, while the stream
        is already running."""
        from concurrent.futures import ThreadPoolExecutor
        cache, T, shape = self.tgt.geometry, self.tp.T, (*self.frames.shape, 3)
        todo = [j for j in range(len(self.frames)) if self.tgt.pose_ok[j]]
        if not todo:
            return
        t0 = time.perf_counter()
        each = cache.get(self.tgt, todo[0], T, self.p.composite, shape).nbytes      # the size of one: how many fit
        rest = todo[1:max(1, int(cache.budget // max(each, 1)))]
        with ThreadPoolExecutor(max(1, threads)) as pool:
            list(pool.map(lambda j: cache.get(self.tgt, j, T, self.p.composite, shape), rest))
        log.info("live: the geometry of %d target frames made in %.1f s (%.0f MB)", 1 + len(rest),
                 time.perf_counter() - t0, cache.used / 1e6)

    def reference_lips(self, target: str, model: str) -> np.ndarray:
        """Predicted lips of the target's own audio (the spread the re-targeting widens); the model's mean
        shape when the target has no audio (spread gain 1)."""
        from pipeline.models.mouth_prediction import load_audio, predict_mouth
        try:
            return predict_mouth(load_audio(target), model, self.fps)["lip_points"]
        except BadInputError:
            log.info("%s has no usable audio: re-targeting without widening the spread", target)
            return self.mouth.mean_shape[None]

    def plan(self, lips: np.ndarray) -> tuple[np.ndarray, dict, list | None]:
        """Sequential part of a frame (main thread): the re-targeted shape, its candidate search, its detail."""
        s = self.p.synthesize
        if self.retarget is not None:
            lips = self.retarget(lips)
        search = self.tx.candidate_search(lips, self.tp.shapes, s.n, s.alpha)
        cost = search.pop("all_d2") / (2 * search["sigma"] ** 2)
        return lips, search, self.detail.pick(cost) if self.detail else None

    def frame(self, k: int, lips: np.ndarray, search: dict, sources) -> np.ndarray:
        """Output frame k (worker thread): the texture, composited into its ping-pong target frame."""
        from stages.composite.composite import composite_frame
        from stages.synthesize.texture_pool import synthesize_frame
        j = ping_pong(k, len(self.frames))
        t0 = time.perf_counter()
        texture = synthesize_frame(self.tp, lips, self.p.synthesize, search, sources)
        t1 = time.perf_counter()
        out = composite_frame(self.frames.rgb(j), texture.rgb, j, self.tgt, self.p.composite, None, texture.inpainted)
        self.thread_ms["texture"].append(1000 * (t1 - t0))
        self.thread_ms["composite"].append(1000 * (time.perf_counter() - t1))
        return out


def audio_source(args):
    """The audio blocks with their arrival times. A file read without ``--realtime`` arrives at once: no
    frame is then ever behind its audio (``--max-behind`` is off), the stream is made as fast as it can be."""
    if args.audio == "-":
        return pcm_blocks(sys.stdin.buffer, "stdin", log.warning)
    if not Path(args.audio).exists():
        raise BadInputError(args.audio, "audio file not found")
    if Path(args.audio).is_fifo():
        return pcm_blocks(open(args.audio, "rb"), args.audio, log.warning)
    if not args.realtime:
        args.max_behind = float("inf")
    return paced_file(args.audio, args.realtime)


def run(args, params: Params) -> dict:
    if not Path(args.target).is_file():
        raise BadInputError(args.target, "target video file not found")
    from pipeline.models.mouth_prediction import open_model
    model = open_model(args.model or params.synthesize.model)     # checked once, passed on
    t0 = time.perf_counter()
    from lipsynth.prepare import prepared
    p, stores, entry, report = prepared(args.target, params, model, args.cache, prepared_only=True)
    engine = LiveEngine(p, stores, entry, args.target, model, args)
    server = None
    if args.serve is not None:
        from lipsynth.live_page import serve
        server = serve(Path(args.hls), args.serve)
    log.info("live: ready in %.1f s (%s); %d target frames at %.3f fps, look-ahead %.2f s, hop %.2f s",
             time.perf_counter() - t0, report["path"], len(engine.frames), engine.fps, args.ahead, args.hop)
    stats = stream(engine, audio_source(args), args)
    if server is not None:
        log.info("the stream ended; the page still plays it (Ctrl-C stops)")
        STOP.wait()
        server.shutdown()
    return stats


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth live", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--target", required=True, help="video of the person (prepared with `lipsynth prepare`)")
    ap.add_argument("--audio", default="-", help="- (stdin, the default) or a named pipe: 16 kHz mono s16le PCM, raw "
                    "or WAV; or any audio file (with --realtime: replayed at its real pace)")
    ap.add_argument("--realtime", action="store_true", help="release an audio file's samples at the pace they play")
    ap.add_argument("--out", default="-", help="MPEG-TS output: - (stdout, the default) or a .ts file")
    ap.add_argument("--hls", default=None, metavar="DIR", help="write an HLS stream (DIR/index.m3u8) instead")
    ap.add_argument("--serve", nargs="?", type=int, const=0, default=None, metavar="PORT",
                    help="serve a web page on 127.0.0.1:PORT (default: a free port) that plays the HLS stream with "
                         "sound; implies --hls (a temporary folder unless given); serves on after the audio ends, "
                         "until Ctrl-C")
    ap.add_argument("--model", default=None, help="LSTM model folder (default: synthesize.model of the params file)")
    ap.add_argument("--past", type=float, default=STREAM["past_s"],
                    help="seconds of audio before the new frames each window sees (default %(default)s)")
    ap.add_argument("--ahead", type=float, default=STREAM["ahead_s"],
                    help="look-ahead (s): latency bought for lip sync (default %(default)s)")
    ap.add_argument("--hop", type=float, default=STREAM["hop_s"], help="new audio (s) per front-end window: a "
                    "frame waits for its hop's end, so half of it adds to the median latency (default %(default)s)")
    ap.add_argument("--pad", type=float, default=STREAM["pad_s"],
                    help="whisper windows are padded with silence to this (s) (default %(default)s)")
    ap.add_argument("--threads", type=int, default=2, help="frame workers (texture + composite)")
    ap.add_argument("--preset", default="ultrafast", help="x264 preset of the stream (default ultrafast: the least "
                    "CPU per frame, more bits)")
    ap.add_argument("--gap", type=float, default=0.5, help="seconds without audio after which silence is fed")
    ap.add_argument("--max-behind", type=float, default=1.0,
                    help="a frame whose audio arrived longer ago than this (s) repeats the last frame")
    ap.add_argument("--stats", default=None, metavar="JSON", help="write per-frame latencies, drops and drift")
    ap.add_argument("--params", default=None, help="params file (default: ./params.yaml, else the installed one)")
    ap.add_argument("--cache", type=Path, default=None, help="folder of prepared targets (as speak's --cache)")
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)
    for sig in (signal.SIGINT, signal.SIGTERM):          # Ctrl-C or a kill ends the stream as its audio's end would
        signal.signal(sig, lambda *_: STOP.set())
    if a.out not in ("-", None) and not a.out.endswith(".ts"):
        ap.error(f"--out {a.out}: expected - or a .ts file name")
    if a.serve is not None and not a.hls:
        import tempfile
        a.hls = tempfile.mkdtemp(prefix="lipsynth-live-")
    if a.hls:
        a.out = None
    params = a.params or ("params.yaml" if Path("params.yaml").is_file() else Path(__file__).parents[1] / "params.yaml")
    return run_main(lambda: run(a, load_params(params)))


if __name__ == "__main__":
    raise SystemExit(main())

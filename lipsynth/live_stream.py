"""The stream of ``lipsynth live``: audio blocks in, frames out, in order, until the audio ends.

Three threads: a reader takes the audio source's blocks into a queue; the calling thread feeds them to the
engine's streaming mouth (silence at the clock's pace when the audio pauses for ``--gap`` s), plans each new
frame and hands it to ``--threads`` workers (or repeats the last frame when more than ``--max-behind`` s late);
a writer muxes the frames, in order, with their audio. ``stream`` runs one and returns its stats.
"""
from __future__ import annotations

import bisect
import json
import logging
import os
import queue
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from pipeline.io.live_io import SAMPLE_RATE, StreamWriter
from pipeline.io.threads import library_threads

log = logging.getLogger("lipsynth.live")
STOP = threading.Event()          #: set by Ctrl-C or SIGTERM: the stream ends cleanly, as at the end of its audio
WAIT = object()                   #: ``LiveStream.next_item``: nothing to feed yet


class AudioBuffer:
    """The audio so far (float32), appended by one thread and sliced by another (capacity doubles)."""

    def __init__(self):
        self.data, self.n = np.zeros(SAMPLE_RATE * 60, np.float32), 0

    def append(self, block: np.ndarray) -> None:
        if self.n + len(block) > len(self.data):
            grown = np.zeros(2 * max(len(self.data), self.n + len(block)), np.float32)
            grown[:self.n] = self.data[:self.n]
            self.data = grown
        self.data[self.n:self.n + len(block)] = block
        self.n += len(block)

    def slice(self, a: int, b: int) -> np.ndarray:
        return self.data[a:min(b, self.n)].copy()


class LiveStream:
    """One stream's queues, threads and counters (see the module doc); ``run`` returns when the writer is done.
    ``engine``: a ``lipsynth.live.LiveEngine``; ``source``: the audio blocks with their arrival times."""

    def __init__(self, engine, source, args, writer: StreamWriter):
        self.engine, self.source, self.args, self.writer = engine, source, args, writer
        self.fps = engine.fps
        self.audio_q: queue.Queue = queue.Queue(maxsize=500)
        self.frames_q: queue.Queue = queue.Queue(maxsize=4 * args.threads)
        self.arrivals: list[tuple[int, float]] = []        # (samples received before this block, its arrival)
        self.stats = dict(frames=0, repeated=0, silence_fed_s=0.0, latency_ms=[], shape_ms=[])
        self.failure: list[BaseException] = []
        self.heard = AudioBuffer()
        self.frame_arrival: dict[int, float] = {}
        self.received = 0
        self.started = None

    def read(self) -> None:
        """Reader thread: the source's blocks into the audio queue, then None."""
        try:
            for block, at in self.source:
                self.audio_q.put((block, at))
        except BaseException as exc:
            self.failure.append(exc)
        self.audio_q.put(None)

    def arrival(self, sample: int) -> float:
        """When the block holding audio sample ``sample`` arrived (monotonic s)."""
        recent = self.arrivals[-2000:]
        i = bisect.bisect_right(recent, (sample, float("inf"))) - 1
        return recent[max(i, 0)][1]

    def write_frames(self) -> None:
        """Writer thread: each frame (the last one again for a repeat) with its audio, in order, until None."""
        last = None
        try:
            while (item := self.frames_q.get()) is not None:
                k, fut = item
                frame = fut.result() if fut is not None else last
                a0, a1 = int(round(k * SAMPLE_RATE / self.fps)), int(round((k + 1) * SAMPLE_RATE / self.fps))
                audio = self.heard.slice(a0, a1)
                t0 = time.perf_counter()
                self.writer.write(frame, np.pad(audio, (0, a1 - a0 - len(audio))))
                self.engine.thread_ms["encode"].append(1000 * (time.perf_counter() - t0))
                self.stats["latency_ms"].append(1000 * (time.monotonic() - self.frame_arrival[k]))
                last = frame
        except BaseException as exc:
            self.failure.append(exc)
            while self.frames_q.get() is not None:     # unblock the producer until it sees the failure
                pass

    def next_item(self):
        """The next audio block (samples, arrival), None at the end of the audio (or on STOP), or WAIT. When
        nothing arrived for ``--gap`` s, silence up to the clock's present."""
        try:
            return None if STOP.is_set() else self.audio_q.get(timeout=min(self.args.gap, 0.25))
        except queue.Empty:                            # nothing arrived: silence at the clock's pace
            now = time.monotonic()
            if self.started is None or now - self.arrivals[-1][1] < self.args.gap:
                return WAIT
            due = int((now - self.started) * SAMPLE_RATE) - self.received
            if due <= 0:
                return WAIT
            self.stats["silence_fed_s"] += due / SAMPLE_RATE
            return np.zeros(due, np.float32), now

    def shapes(self, item) -> list:
        """The mouth shapes (frame, time, lips) that the audio block ``item`` completes; at the end (None), the
        rest."""
        if item is None:
            return self.engine.mouth.flush()
        block, at = item
        self.started = self.started if self.started is not None else at - len(block) / SAMPLE_RATE
        self.arrivals.append((self.received, at))
        self.received += len(block)
        self.heard.append(block)
        return self.engine.mouth.push(block)

    def make_frames(self, new: list, pool: ThreadPoolExecutor) -> None:
        """Plan each new shape's frame and hand it to the workers; a frame later than ``--max-behind`` s after
        its audio (never the first) repeats the last one."""
        for k, _, lips in new:
            self.frame_arrival[k] = self.arrival(int(k * SAMPLE_RATE / self.fps))
            self.stats["shape_ms"].append(1000 * (time.monotonic() - self.frame_arrival[k]))
            behind = time.monotonic() - self.frame_arrival[k]
            if self.stats["frames"] and behind > self.args.max_behind:
                self.frames_q.put((k, None))          # falling behind: repeat the last frame, keep the clock
                self.stats["repeated"] += 1
            else:
                lips, search, sources = self.engine.plan(lips)
                self.frames_q.put((k, pool.submit(self.engine.frame, k, lips, search, sources)))
            self.stats["frames"] += 1

    def run(self) -> None:
        """Until the audio ends or a thread fails (``failure``): read, make, write."""
        reader = threading.Thread(target=self.read, daemon=True, name="live-audio")
        writer_thread = threading.Thread(target=self.write_frames, daemon=True, name="live-writer")
        reader.start()
        writer_thread.start()
        ended = False
        try:
            with ThreadPoolExecutor(self.args.threads, thread_name_prefix="live-frame") as pool, library_threads(1):
                while not ended and not self.failure:
                    item = self.next_item()
                    if item is WAIT:
                        continue
                    ended = item is None
                    self.make_frames(self.shapes(item), pool)
                self.frames_q.put(None)
                writer_thread.join()
        finally:
            if writer_thread.is_alive():
                self.frames_q.put(None)


def close_output(writer: StreamWriter, sink, tmp: Path | None, out_path: Path | None,
                 failure: list[BaseException]) -> bool:
    """Finish the stream's output: True when complete (a file output renamed into place), False when the
    consumer went away; a thread's failure other than a broken pipe is raised (a partial file removed)."""
    broken = any(isinstance(e, BrokenPipeError) for e in failure)
    try:
        if not broken:
            writer.close()
    except (BrokenPipeError, OSError):
        broken = True
    finally:
        if tmp:
            sink.close()
    if failure and not broken:
        if tmp:
            tmp.unlink(missing_ok=True)
        raise failure[0]
    if broken:
        if tmp:
            tmp.unlink(missing_ok=True)
        return False
    if tmp:
        os.replace(tmp, out_path)
    return True


def stream(engine, source, args) -> dict:
    """Run the pipeline until the audio ends; returns the stats (latencies, drops, drift)."""
    fps = engine.fps
    h, w = engine.frames.shape
    out_path = None if args.out in (None, "-") else Path(args.out)
    tmp = out_path.with_name(f".{out_path.name}.part") if out_path else None
    sink = open(tmp, "wb") if tmp else sys.stdout.buffer
    writer = StreamWriter(sink, fps, (w, h), SAMPLE_RATE, Path(args.hls) if args.hls else None, preset=args.preset)
    live = LiveStream(engine, source, args, writer)
    live.run()
    stats, received = live.stats, live.received
    if not close_output(writer, sink, tmp, out_path, live.failure):
        log.info("live: the consumer went away after %d frames: stopped", stats["frames"])
        return stats
    lat = np.asarray(stats["latency_ms"])
    stats.update(audio_s=received / SAMPLE_RATE, video_s=stats["frames"] / fps,
                 drift_frames=stats["frames"] - round(received / SAMPLE_RATE * fps),
                 latency_median_ms=float(np.median(lat)) if len(lat) else None,
                 latency_p95_ms=float(np.percentile(lat, 95)) if len(lat) else None,
                 thread_ms_median={k: float(np.median(v)) for k, v in engine.thread_ms.items() if v},
                 method=engine.tp.method, texture_px=engine.tp.T)
    log.info("live: %d frames (%d repeated to keep up), %.1f s of audio; latency median %.0f ms, p95 %.0f ms; "
             "video − audio = %d frames", stats["frames"], stats["repeated"], stats["audio_s"],
             stats["latency_median_ms"] or 0, stats["latency_p95_ms"] or 0, stats["drift_frames"])
    if args.stats:
        Path(args.stats).write_text(json.dumps(stats, indent=1) + "\n")
    return stats

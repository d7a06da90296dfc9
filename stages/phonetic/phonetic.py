"""phonetic — speaker-independent phone indicators for every video (issue 13's phonetic front end).

For each video of the ingest store, pocketsphinx's en-us phone recogniser (``pipeline.audio.phone_features``)
decodes the stored 16 kHz audio into phone segments, stored as one-hot indicators on the MFCC time
axis, so a model trained with ``train.features: phonetic`` or ``mfcc+phonetic`` reads the same
numbers ``lipsynth speak`` computes for new audio.

Store ``store/phonetic.zarr``:
    phones    (M, 40) uint8    1 in the column of the recognised phone (``attrs["phones"]``), per 10 ms
                               frame; same M and per-video offsets as ingest's ``mfcc``
    attrs["videos"]: ingest's per-video index; attrs["phones"]: column names

Each video is one dask task that writes its own shard-aligned region (videos start on MFCC
shard boundaries in the ingest layout).

Run: ``python -m stages.phonetic.phonetic``.
"""
from __future__ import annotations

import logging

import numpy as np

from pipeline.io.parallel import client_for, run_tasks
from pipeline.params import Params
from pipeline.audio.phone_features import PHONE_DIM, PHONES, phone_indicators
from pipeline.io.runner import stage_main
from pipeline.io.store import atomic_output, create_group, create_timed, open_group

log = logging.getLogger("lipsynth.phonetic")


def phones_of_video(job: dict) -> int:
    """Recognise one video's phones and write its rows; returns the number of speech frames."""
    import zarr
    src = open_group(job["ingest"])
    v = job["video"]
    s0, m0 = v["first_sample"], v["first_mfcc"]
    audio = np.asarray(src["audio"][s0:s0 + v["n_samples"]], np.float32) / 32767.0
    rows = phone_indicators(audio, v["n_mfcc"]).astype(np.uint8)
    zarr.open_group(job["out"], mode="r+")["phones"][m0:m0 + len(rows)] = rows
    return int((rows[:, 0] == 0).sum())


def run(params: Params, ingest_path: str, out: str) -> dict:
    src = open_group(ingest_path)
    videos = [v for v in src.attrs["videos"] if not v.get("excluded") and v["n_mfcc"]]
    shard = src["mfcc"].shards[0]                       # the MFCC axis's shards: videos start on them
    with atomic_output(out) as tmp, client_for(params.cluster) as client:
        g = create_group(tmp, {"videos": src.attrs["videos"], "phones": list(PHONES), "rate": 100})
        create_timed(g, "phones", src["mfcc"].shape[0], (PHONE_DIM,), "uint8", shard, shard // 10)
        jobs = [dict(ingest=str(ingest_path), video=v, out=str(tmp)) for v in videos]
        speech = run_tasks(client, phones_of_video, jobs, "phonetic", "s",
                           [v["n_samples"] / 16000 for v in videos])
    total = sum(v["n_mfcc"] for v in videos)
    log.info("phone indicators of %d videos (%.1f min): %.0f%% of frames speech", len(videos), total / 6000,
             100 * sum(speech) / max(total, 1))
    return {"videos": len(videos), "speech_fraction": sum(speech) / max(total, 1)}


def main(argv=None) -> int:
    return stage_main("lipsynth phonetic", __doc__, lambda p: run(p, p.ingest.out, p.phonetic.out), argv)


if __name__ == "__main__":
    raise SystemExit(main())

"""Is this footage one person, with enough of their face tracked? (``lipsynth personalize``, after landmarks).

Per video (or segment) of the preprocessed footage: the seconds in which the face is tracked
(valid landmarks), and who it is — the median dlib face descriptor of a few tracked frames
(``pipeline.face.identity``). A video whose person is farther than ``speak.same_speaker_distance``
from the footage's median person shows someone else; footage with too few tracked seconds cannot
teach a mouth. Either stops with one line naming the files and the usable seconds.
"""
from __future__ import annotations

import logging

import numpy as np

from pipeline.errors import BadInputError, LipsynthError
from pipeline.face import identity

log = logging.getLogger("lipsynth.personalize")
MIN_USABLE_SECONDS = 15.0        #: tracked face needed in all (personalize asks 1.5 segments: 15 s of 10-s segments)
MIN_FLOOR_CORR = 0.5             #: tracked lips of a video and of its re-encoding must agree this well to learn from


def tracker_floor(ingest_path: str, landmark_params, crf: int = 18) -> tuple[str, float]:
    """How well the tracker sees this mouth, on the first held-out video of a store: the correlation
    of the inner-lip opening tracked on its stored face crops with the opening tracked on the same
    crops re-encoded (H.264 CRF ``crf``), over the frames tracked in both — the most any model
    scored by this tracker can reach (1 = noise-free). Returns (the video's path, the correlation;
    NaN when fewer than 10 frames are tracked in both)."""
    import tempfile
    from pathlib import Path

    from lipsynth.lipsync_quality import inner_opening
    from pipeline.io import media
    from pipeline.io.store import open_group
    from stages.landmarks.landmarks import track_video
    src = open_group(ingest_path)
    v = next(v for v in src.attrs["videos"] if v["split"] == "val" and not v.get("excluded"))
    crops = src["crops"][v["first_frame"]:v["first_frame"] + v["n_frames"]]
    side = crops.shape[2]
    grays = np.ascontiguousarray(crops[:, :side])                        # the Y plane of the I420 crops
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "reencoded.mp4"
        media.write_video(copy, (np.repeat(g[..., None], 3, -1) for g in grays), v["fps"], crf=crf)
        again = np.stack([g for _, g in media.iter_frames(copy, "gray")])
    lm_a, _, ok_a, _ = track_video(grays, landmark_params)
    lm_b, _, ok_b, _ = track_video(again, landmark_params)
    n = min(len(lm_a), len(lm_b))
    ok = ok_a[:n] & ok_b[:n]
    if ok.sum() < 10:
        return v["path"], float("nan")
    a, b = inner_opening(np.asarray(lm_a)[:n][ok]), inner_opening(np.asarray(lm_b)[:n][ok])
    return v["path"], float(np.corrcoef(a, b)[0, 1]) if a.std() > 0 and b.std() > 0 else 0.0


def verdict(usable_s: dict[str, float], people: dict[str, np.ndarray], same_person: float,
            min_seconds: float = MIN_USABLE_SECONDS) -> dict[str, float]:
    """Check the footage; returns each video's distance from the footage's person (pure).

    Parameters
    ----------
    usable_s : video path → seconds with a tracked face (every video, excluded ones too).
    people : video path → (128,) median face descriptor, for the videos with a tracked face.
    same_person : descriptors farther apart than this are different people (``speak.same_speaker_distance``).

    Raises
    ------
    BadInputError naming the first video of another person, or every video with its usable seconds
    when they add up to less than ``min_seconds``.
    """
    total = sum(usable_s.values())
    if total < min_seconds:
        listing = ", ".join(f"{p} {s:.1f} s" for p, s in usable_s.items())
        raise LipsynthError(f"only {total:.1f} s of the footage shows a tracked face (at least {min_seconds:.0f} s "
                            f"needed): {listing}")
    if not people:
        return {}
    person = identity.identity(np.stack(list(people.values())))
    dist = {p: identity.distance(d, person) for p, d in people.items()}
    far = [p for p, d in dist.items() if d > same_person]
    if far and len(far) < len(dist):
        worst = max(far, key=dist.get)
        raise BadInputError(worst, f"shows another person than the rest of the footage (face distance {dist[worst]:.2f} "
                                   f"> speak.same_speaker_distance {same_person:.2f}; {len(far)} of {len(dist)} "
                                   f"videos): give footage of one person")
    if far:                         # nobody is near the median: several people throughout
        raise LipsynthError(f"the footage shows several people (every video's face is more than {same_person:.2f} "
                            f"from the median face): give footage of one person")
    return dist


def check(ingest_path: str, landmarks_path: str, same_person: float, min_seconds: float = MIN_USABLE_SECONDS,
          frames_per_video: int = 8) -> dict[str, float]:
    """Read the stores, log each video's tracked seconds and run ``verdict``."""
    from pipeline.io.store import open_group
    src, lmg = open_group(ingest_path), open_group(landmarks_path)
    landmarks, valid = np.asarray(lmg["landmarks"][...]), np.asarray(lmg["valid"][...])
    usable, people = {}, {}
    for v in lmg.attrs["videos"]:
        f0, n = v["first_frame"], v["n_frames"]
        mine = np.zeros_like(valid)                       # this video's tracked frames, store-wide indices
        mine[f0:f0 + n] = valid[f0:f0 + n]
        usable[v["path"]] = float(mine.sum() / v["fps"]) if n else 0.0
        if v.get("excluded") or not mine.any():
            continue
        d = identity.video_descriptor(src["crops"], landmarks, mine, v["crop"], frames_per_video)
        if d is not None:
            people[v["path"]] = identity.identity(d)
    dist = verdict(usable, people, same_person, min_seconds)
    log.info("footage: %.1f s with a tracked face (%s); one person (face distances from the median %s)",
             sum(usable.values()), ", ".join(f"{s:.1f}" for s in usable.values()),
             ", ".join(f"{d:.2f}" for d in dist.values()) or "-")
    return dist

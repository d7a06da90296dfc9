"""personalize refuses footage of several people or with too little tracked face, naming files and seconds."""
import numpy as np
import pytest

from lipsynth.footage_check import verdict
from pipeline.errors import BadInputError, LipsynthError


def person(seed, spread=0.0, k=0):
    """A unit-ish 128-D descriptor; `spread` moves it by about that distance (same person ≲ 0.5)."""
    base = np.random.default_rng(seed).normal(size=128)
    base *= 0.8 / np.linalg.norm(base)
    step = np.random.default_rng([seed, k]).normal(size=128)
    return base + spread * step / np.linalg.norm(step)


def test_one_person_passes_and_reports_distances():
    usable = {f"s{i}.mp4": 10.0 for i in range(5)}
    people = {f"s{i}.mp4": person(1, 0.2, i) for i in range(5)}
    dist = verdict(usable, people, 0.5)
    assert set(dist) == set(people) and max(dist.values()) < 0.5


def test_a_segment_of_another_person_is_named():
    usable = {f"s{i}.mp4": 10.0 for i in range(5)}
    people = {f"s{i}.mp4": person(1, 0.2, i) for i in range(5)}
    people["s3.mp4"] = person(2)                                     # someone else in the fourth segment
    with pytest.raises(BadInputError, match=r"s3\.mp4: shows another person .*1 of 5 videos"):
        verdict(usable, people, 0.5)


def test_too_little_tracked_face_lists_every_files_seconds():
    usable = {"a.mp4": 4.0, "b.mp4": 0.0, "c.mp4": 2.5}
    with pytest.raises(LipsynthError, match=r"only 6\.5 s .*at least 15 s.*a\.mp4 4\.0 s, b\.mp4 0\.0 s, c\.mp4 2\.5 s"):
        verdict(usable, {"a.mp4": person(1), "c.mp4": person(1, 0.1)}, 0.5)


def test_several_people_throughout_is_one_line():
    usable = {f"s{i}.mp4": 10.0 for i in range(4)}
    people = {f"s{i}.mp4": person(10 + i) for i in range(4)}            # four different faces
    with pytest.raises(LipsynthError, match="several people|another person"):
        verdict(usable, people, 0.5)

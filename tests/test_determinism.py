"""The cache is trustworthy: the same pipeline run in two differently named (and differently
long) folders gives identical DVC hashes for every stage's outputs — nothing machine-specific
(absolute paths, timings) ends up in a tracked output."""
import pytest
import yaml

from tests.helpers import copy_project, dvc

TINY = {
    "synthetic_speaker": {"n_videos": 3, "seconds_per_video": 4.0},
    "train": {"steps": 15, "baselines": False},
    "brand": {"states": 6, "iterations": 10, "baseline": False},
    "karras": {"steps": 2, "val_every": 2, "mine_candidates": 200},
    "delay_sweep": {"delays": [0, 20], "steps": 5},
    "synthesize": {"audio": "data/synthetic_speaker/speaker_02.mp4", "pool_min": 100},
    "composite": {"diagnostic": False},
}


def run_copy(folder):
    dvc(copy_project(folder, TINY), "repro")
    return yaml.safe_load((folder / "dvc.lock").read_text())["stages"]


@pytest.mark.slow
def test_two_checkouts_in_different_folders_give_identical_hashes(tmp_path):
    # the two repros run at the same time (two cores): outputs must not depend on the machine's load either
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(2) as pool:
        a, b = pool.map(run_copy, [tmp_path / "a", tmp_path / "checkout_in_a_much_longer_folder_name" / "lipsynth"])
    assert set(a) == set(b) and len(a) == 16
    for stage in a:
        if stage != "report":       # the page carries its generation date, commit and measured timings by design
            assert a[stage].get("outs") == b[stage].get("outs"), f"{stage}: outputs differ between the two folders"
        assert a[stage]["deps"] == b[stage]["deps"], f"{stage}: dependencies differ between the two folders"

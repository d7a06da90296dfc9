"""The cache is trustworthy: the same pipeline run in two differently named (and differently
long) folders gives identical DVC hashes for every stage's outputs — nothing machine-specific
(absolute paths, timings) ends up in a tracked output; and the first stages give the same bytes
whatever SIMD code NumPy and OpenCV pick at run time."""
import pytest
import yaml

from tests.helpers import copy_project, dvc

TINY_PIPELINE = {  # every stage, as small as it runs
    "synthetic_speaker": {"n_videos": 3, "seconds_per_video": 4.0},
    "train": {"steps": 15, "baselines": False},
    "brand": {"states": 6, "iterations": 10, "baseline": False},
    "karras": {"steps": 2, "val_every": 2, "mine_candidates": 200},
    "delay_sweep": {"delays": [0, 20], "steps": 5},
    "synthesize": {"audio": "data/synthetic_speaker/speaker_02.mp4", "pool_min": 100},
    "composite": {"diagnostic": False},
}


def run_copy(folder):
    dvc(copy_project(folder, TINY_PIPELINE), "repro")
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


def lowest_dispatch() -> dict:
    """Environment turning off every run-time SIMD level this CPU has above the x86-64-v2 baseline, in NumPy
    (its X86_V3 / X86_V4 dispatch groups) and OpenCV (AVX, AVX2, AVX-512): what an older CPU would run."""
    import cv2
    from numpy._core._multiarray_umath import __cpu_features__ as npy
    numpy_off = [g for g in ("X86_V4", "X86_V3") if npy.get(g)]
    # e.g. "SSE SSE2 SSE3 *SSE4.1 *SSE4.2 *AVX *FP16 *AVX2 *AVX512-SKX?": * = dispatched, ? = not on this CPU
    dispatched = [t[1:].replace("-", "_") for t in cv2.getCPUFeaturesLine().split() if t.startswith("*") and "?" not in t]
    cv_off = [t for t in dispatched if t.startswith(("AVX", "FP16"))]
    return {"NPY_DISABLE_CPU_FEATURES": " ".join(numpy_off), "OPENCV_CPU_DISABLE": ",".join(cv_off)}


@pytest.mark.slow
def test_first_stages_are_the_same_bytes_with_the_highest_and_the_lowest_simd_dispatch(tmp_path):
    """synthetic_speaker → ingest → landmarks run twice: with everything this CPU offers and with NumPy's and
    OpenCV's run-time dispatch turned down to the baseline; every output hash is the same. (Before the
    bit-exact resampling of ``pipeline.resample`` the synthetic speaker's videos differed from frame 0.)"""
    low = lowest_dispatch()
    assert low["OPENCV_CPU_DISABLE"], "this CPU has no SIMD level above the baseline to turn off"
    small = {"synthetic_speaker": {"n_videos": 2, "seconds_per_video": 3.0}}
    locks = []
    for name, env in (("highest", {}), ("lowest", low)):
        proj = copy_project(tmp_path / name, small)
        dvc(proj, "repro", "landmarks", env=env)
        locks.append(yaml.safe_load((proj / "dvc.lock").read_text())["stages"])
    for stage in ("synthetic_speaker", "ingest", "landmarks"):
        assert locks[0][stage]["outs"] == locks[1][stage]["outs"], f"{stage}: outputs depend on the SIMD dispatch"

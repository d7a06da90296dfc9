"""The first stages give the same bytes whatever SIMD code NumPy and OpenCV pick at run time. (That a run in
another folder, on a loaded machine, gives the committed dvc.lock's hashes is checked on the reproduced demo:
``tests/test_dvc_pipeline.py::test_a_fresh_run_reproduces_the_committed_dvc_lock``.)"""
import shutil
import time

import pytest
import yaml

from pipeline.simd_level import AVX2_CAP, AVX512_OFF, AVX512_SKX, cpu_flags
from bench.cross_vendor import result_of, start_on
from tests.conftest import skip_unless_ci
from tests.helpers import copy_project, dvc

def lowest_dispatch() -> dict:
    """Environment turning off every run-time SIMD level this CPU has above the x86-64-v2 baseline, in NumPy
    (every dispatch group from X86_V3 up) and OpenCV (AVX, AVX2, AVX-512, and its IPP): what an older CPU would run. Read
    from the CPU's flags and OpenCV's dispatch list, not from what this (capped) process runs."""
    import cv2
    flags = cpu_flags()
    numpy_off = [g for g, needs in ((AVX512_OFF["NPY_DISABLE_CPU_FEATURES"], AVX512_SKX),
                                           ("X86_V3", {"avx2", "fma", "bmi2"})) if needs <= flags]
    return {"NPY_DISABLE_CPU_FEATURES": " ".join(numpy_off),
            "OPENCV_CPU_DISABLE": ",".join(opencv_above_baseline(cv2.getCPUFeaturesLine(), flags)),
            "OPENCV_IPP": "sse42"}                   # the IPP inside OpenCV: its SSE4.2 build (y8)


def opencv_above_baseline(features_line: str, flags: set[str]) -> list[str]:
    """OpenCV's dispatched levels above SSE4.2 that a CPU with ``flags`` has, named as OPENCV_CPU_DISABLE reads
    them: its own spelling, "AVX512-SKX" (it ignores "AVX512_SKX" as an unknown feature, so an AVX-512 CPU kept
    its AVX-512 kernels in the "lowest" run). ``features_line``: ``cv2.getCPUFeaturesLine()``, e.g. "SSE SSE2 SSE3
    *SSE4.1 *SSE4.2 *AVX *FP16 *AVX2 *AVX512-SKX?" (* = dispatched, ? = off: absent or capped)."""
    dispatched = [t[1:].rstrip("?") for t in features_line.split() if t.startswith("*")]
    return [t for t in dispatched if t.startswith(("AVX", "FP16")) and (t != "AVX512-SKX" or AVX512_SKX <= flags)]


def test_the_lowest_dispatch_names_opencv_features_as_opencv_reads_them():
    """On an AVX-512 CPU the "lowest" run must turn OpenCV's AVX-512 kernels off too; OpenCV warns "unknown CPU
    feature" for a name it does not know (and then keeps that level) and "unavailable" for one this CPU lacks."""
    import subprocess
    import sys
    skx = {"avx", "avx2", "fma", "bmi2"} | AVX512_SKX
    line = "SSE SSE2 SSE3 *SSE4.1 *SSE4.2 *AVX *FP16 *AVX2 *AVX512-SKX?"
    names = opencv_above_baseline(line, skx)
    assert names == ["AVX", "FP16", "AVX2", "AVX512-SKX"]
    assert opencv_above_baseline(line, {"avx", "avx2", "fma"}) == ["AVX", "FP16", "AVX2"]
    r = subprocess.run([sys.executable, "-c", "import cv2"], env={"OPENCV_CPU_DISABLE": ",".join(names)},
                       capture_output=True, text=True, check=True)
    assert "unknown CPU feature" not in r.stderr, r.stderr


def highest_dispatch() -> dict:
    """Environment with the AVX2 cap lifted (NumPy and OpenCV at all the CPU offers, AVX-512 included), x264
    alone held at its AVX2 sets: its kernels are not bit-exact across sets, so the cap keeps it there on
    every CPU with AVX2."""
    return {"LIPSYNTH_SIMD": "native", "NPY_DISABLE_CPU_FEATURES": "", "OPENCV_CPU_DISABLE": "",
            "LIPSYNTH_X264_ASM": AVX2_CAP["LIPSYNTH_X264_ASM"] if "avx2" in cpu_flags() else ""}


@pytest.mark.slow
def test_first_stages_are_the_same_bytes_with_the_highest_and_the_lowest_simd_dispatch(tmp_path):
    """synthetic_speaker → ingest → landmarks run twice: with everything this CPU offers (the AVX2 cap of
    ``pipeline.simd_level`` lifted) and with NumPy's and OpenCV's run-time dispatch turned down to the baseline;
    every output hash is the same. (Before the
    bit-exact resampling of ``pipeline.resample`` the synthetic speaker's videos differed from frame 0.)"""
    low = lowest_dispatch()
    assert low["OPENCV_CPU_DISABLE"], "this CPU has no SIMD level above the baseline to turn off"
    small = {"synthetic_speaker": {"n_videos": 2, "seconds_per_video": 3.0}}
    locks = []
    for name, env in (("highest", highest_dispatch()), ("lowest", low)):
        proj = copy_project(tmp_path / name, small)
        dvc(proj, "repro", "landmarks", env=env)
        locks.append(yaml.safe_load((proj / "dvc.lock").read_text())["stages"])
    for stage in ("synthetic_speaker", "ingest", "landmarks"):
        assert locks[0][stage]["outs"] == locks[1][stage]["outs"], f"{stage}: outputs depend on the SIMD dispatch"


@pytest.mark.slow
def test_training_steps_are_the_same_bits_on_an_emulated_amd_cpu():
    """The train stage's network, three Adam steps (bench/cross_vendor.py's ``lstm`` probe: PyTorch's LSTM
    through oneDNN, MKL's matrix products, the fused Adam), here and under ``qemu-x86_64 -cpu`` as an AMD
    EPYC (AVX2, no AVX-512): the libraries pick their kernels by the CPUID they see. Before oneDNN's cap
    went to AVX and Adam was fused, it gave other weights than this CPU (an emulated Intel Haswell too:
    ``bench/cross_vendor.py`` runs both)."""
    qemu = shutil.which("qemu-x86_64")
    if qemu is None:
        skip_unless_ci("qemu-x86_64 not installed (Debian package qemu-user; .ci/run installs it)")
    t0 = time.perf_counter()
    children = {cpu: start_on(cpu, ["lstm"]) for cpu in ("native", "EPYC-Rome-v1")}
    weights = {cpu: result_of(cpu, child, t0)["lstm"] for cpu, child in children.items()}
    assert len(set(weights.values())) == 1, weights

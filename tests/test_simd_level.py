"""pipeline.simd_level: one set of kernels on every AVX2 CPU (AVX-512 turned off where present), never over a user's value, and before NumPy loads."""
import ast
import os
import subprocess
import sys

from pipeline.simd_level import AVX2_CAP, cap_for, cpu_flags, pin_avx2, x264_params
from tests.conftest import ROOT
from stages.registry import stage

SKX = {"sse4_2", "avx", "avx2", "fma", "avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"}


def test_an_avx512_cpu_is_capped_at_avx2_in_every_library():
    cap = cap_for(SKX)
    assert cap == dict(AVX2_CAP, NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR", OPENCV_CPU_DISABLE="AVX512-SKX")
    assert {"NPY_DISABLE_CPU_FEATURES", "ATEN_CPU_CAPABILITY", "MKL_CBWR", "ONEDNN_MAX_CPU_ISA"} <= set(cap)


def test_an_avx2_cpu_of_any_vendor_gets_the_same_kernels():
    """An AMD EPYC (AVX2, no AVX-512) and an AVX-512 Xeon run the same MKL branch and CTranslate2 backend:
    MKL's vendor-neutral branch (its AVX2 one exists on Intel only), MKL in CTranslate2 on AMD too (its
    default there is oneDNN), OpenBLAS's Haswell kernels (Zen has its own blocking)."""
    amd, intel = cap_for({"sse4_2", "avx", "avx2", "fma"}), cap_for(SKX)
    shared = {"MKL_CBWR", "CT2_USE_MKL", "OPENBLAS_CORETYPE", "ATEN_CPU_CAPABILITY", "ONEDNN_MAX_CPU_ISA",
              "CT2_FORCE_CPU_ISA", "LIPSYNTH_X264_ASM"}
    assert shared <= set(amd) and all(amd[k] == intel[k] for k in shared)
    assert amd["MKL_CBWR"] == "COMPATIBLE" and amd["CT2_USE_MKL"] == "1"
    assert "NPY_DISABLE_CPU_FEATURES" not in amd and "OPENCV_CPU_DISABLE" not in amd   # nothing to turn off


def test_cpus_without_avx2_are_left_alone():
    assert cap_for({"sse4_2", "avx"}) == {}
    assert cap_for({"sse4_2", "avx512f"}) == {}                 # (no such CPU, but never cap *up*)
    assert "OPENCV_CPU_DISABLE" not in cap_for({"avx2", "avx512f"})     # Xeon Phi: OpenCV would warn


def test_a_value_the_user_set_is_kept():
    env = {"ATEN_CPU_CAPABILITY": "default"}
    added = pin_avx2(env, SKX)
    assert env["ATEN_CPU_CAPABILITY"] == "default" and "ATEN_CPU_CAPABILITY" not in added
    assert env["MKL_CBWR"] == "COMPATIBLE"


def test_native_lifts_the_cap():
    env = {"LIPSYNTH_SIMD": "native"}
    assert pin_avx2(env, SKX) == {} and env == {"LIPSYNTH_SIMD": "native"}


def test_cpu_flags_reads_the_first_processor(tmp_path):
    f = tmp_path / "cpuinfo"
    f.write_text("processor\t: 0\nflags\t\t: fpu sse2 avx2\n\nprocessor\t: 1\nflags\t\t: fpu\n")
    assert cpu_flags(str(f)) == {"fpu", "sse2", "avx2"}
    assert cpu_flags(str(tmp_path / "absent")) == set()


def test_a_stage_module_pins_before_numpy_loads():
    """Entering through ``stages`` (how DVC runs a stage) or ``lipsynth`` imports ``pipeline`` before NumPy."""
    probe = ("import sys, builtins\n"
             "seen = []\n"
             "real = builtins.__import__\n"
             "def spy(name, *a, **k):\n"
             "    if name.split('.')[0] in ('numpy', 'pipeline') and name.split('.')[0] not in seen:\n"
             "        seen.append(name.split('.')[0])\n"
             "    return real(name, *a, **k)\n"
             "builtins.__import__ = spy\n"
             "import {module}\n"
             "print(seen[:2])\n")
    for module in (stage("ingest").module, stage("train").module, "lipsynth.cli"):
        r = subprocess.run([sys.executable, "-c", probe.format(module=module)], cwd=ROOT, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        assert ast.literal_eval(r.stdout.strip())[0] == "pipeline", (module, r.stdout)


def test_under_the_cap_numpy_and_opencvs_ipp_run_no_kernel_above_avx2():
    """What the libraries report they run, in a process that imports ``pipeline`` first: NumPy no dispatch
    group above X86_V3 (the X86_V4-only cap left AVX512_ICL on, on an Ice Lake or a Zen 4), and the Intel IPP
    inside OpenCV its AVX2 build (l9), not its AVX-512 one (k0), which OPENCV_CPU_DISABLE does not reach."""
    probe = ("import pipeline, numpy, cv2\n"
             "from numpy._core._multiarray_umath import __cpu_features__ as on, __cpu_dispatch__ as groups\n"
             "print(repr(([g for g in groups if on.get(g)], cv2.ipp.getIppVersion())))\n")
    ours = set(AVX2_CAP) | {"LIPSYNTH_SIMD", "NPY_DISABLE_CPU_FEATURES", "OPENCV_CPU_DISABLE"}
    env = {k: v for k, v in os.environ.items() if k not in ours}         # the cap as pipeline sets it
    r = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    numpy_groups, ipp = ast.literal_eval(r.stdout.strip())
    assert cpu_flags() >= {"avx2", "fma", "bmi2"}, "the cap holds AVX2 CPUs: this test needs one"
    assert numpy_groups == ["X86_V3"], numpy_groups
    assert "(l9)" in ipp and "AVX-512" not in ipp, ipp


def test_x264_is_held_at_the_capped_instruction_sets(tmp_path):
    """The writers pass LIPSYNTH_X264_ASM to x264's ``asm`` option; x264 accepts the cap's list and then uses
    no AVX-512 kernel (its log names what it uses)."""
    import av
    import av.logging
    import numpy as np
    assert x264_params(environ={"LIPSYNTH_X264_ASM": "SSE2,AVX2"}) == {"x264-params": "asm=SSE2,AVX2"}
    assert x264_params(environ={}) == {} and x264_params(environ={"LIPSYNTH_X264_ASM": "auto"}) == {}
    options = x264_params(environ={"LIPSYNTH_X264_ASM": AVX2_CAP["LIPSYNTH_X264_ASM"]})
    assert cpu_flags() >= {"avx2", "fma", "bmi2"}, "the cap's list names AVX2: this test needs an AVX2 CPU"
    av.logging.set_level(av.logging.VERBOSE)
    try:
        with av.logging.Capture() as logs:
            with av.open(str(tmp_path / "x.mp4"), "w") as c:
                s = c.add_stream("libx264", rate=25, options=options)
                s.width, s.height, s.pix_fmt = 64, 64, "yuv420p"
                for p in s.encode(av.VideoFrame.from_ndarray(np.zeros((64, 64, 3), np.uint8), format="rgb24")):
                    c.mux(p)
                c.mux(s.encode())
    finally:
        av.logging.set_level(None)
    used = [m for _, name, m in logs if name == "libx264" and "cpu capabilities" in m]
    assert len(used) == 1 and "AVX2" in used[0] and "AVX512" not in used[0], used


NUMERIC = ("numpy", "cv2", "torch", "scipy", "sklearn", "ctranslate2")
FIRST_PARTY = ("pipeline", "stages", "lipsynth")


def test_every_bench_caps_the_simd_level_before_a_numeric_library_loads():
    """A bench that imports NumPy before ``pipeline`` runs NumPy uncapped (AVX-512 on such a CPU): its
    figures would not be those of the path users run."""
    late = []
    for path in sorted((ROOT / "bench").glob("*.py")):
        order = []
        for node in ast.parse(path.read_text()).body:          # module level, in order
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            order += [n.split(".")[0] for n in names]
        first_numeric = next((i for i, n in enumerate(order) if n in NUMERIC), None)
        first_ours = next((i for i, n in enumerate(order) if n in FIRST_PARTY), None)
        if first_numeric is not None and (first_ours is None or first_ours > first_numeric):
            late.append(path.name)
    assert late == []


def test_importing_pipeline_turns_numpys_huge_pages_off():
    """Frame loops allocate thousands of ≥ 4 MB arrays; with NumPy's madvise(MADV_HUGEPAGE) each fresh one was
    zeroed 2 MB at a time by the kernel. ``pipeline`` sets NUMPY_MADVISE_HUGEPAGE=0 before NumPy loads."""
    code = ("import pipeline, numpy\nfrom numpy._core.multiarray import _set_madvise_hugepage\n"
            "print(_set_madvise_hugepage(False))")
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"                    # the setting it had: off


def test_live_lifts_the_cap_only_before_a_numeric_library_loads_and_never_over_a_user():
    """``lipsynth live`` (timing decides its frames, so no byte to keep) undoes the cap; a value the user set, or
    ``LIPSYNTH_SIMD`` set to anything, is kept; once NumPy or another numeric library has loaded it is too late."""
    from lipsynth.cli import lift_simd_cap
    capped = dict(cap_for(SKX), MKL_CBWR="AUTO", HOME="/home/u")          # MKL_CBWR: the user's own value
    env = dict(capped)
    assert lift_simd_cap(env, loaded={}, flags=SKX)
    assert env == {"MKL_CBWR": "AUTO", "HOME": "/home/u", "LIPSYNTH_SIMD": "native"}
    for loaded, extra in (({"numpy": None}, {}), ({"ctranslate2": None}, {}), ({}, {"LIPSYNTH_SIMD": "avx2"})):
        env = dict(capped, **extra)
        assert not lift_simd_cap(env, loaded=loaded, flags=SKX) and env == dict(capped, **extra)


def test_the_live_command_runs_uncapped_and_speak_capped():
    probe = ("import os, sys\nfrom lipsynth import cli\nfrom pipeline.simd_level import cap_for, cpu_flags\n"
             "try:\n    cli.main([sys.argv[1], '--help'])\nexcept SystemExit:\n    pass\n"
             "print('CAPPED', sorted(k for k, v in cap_for(cpu_flags()).items() if os.environ.get(k) == v), "
             "os.environ.get('LIPSYNTH_SIMD'))\n")
    env = {k: v for k, v in os.environ.items() if k not in AVX2_CAP and k != "LIPSYNTH_SIMD"}
    lines = {}
    for command in ("live", "speak"):
        r = subprocess.run([sys.executable, "-c", probe, command], cwd=ROOT, env=env, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr[-2000:]
        lines[command] = r.stdout.strip().splitlines()[-1]
    cap = sorted(cap_for(cpu_flags()))
    assert lines["live"] == "CAPPED [] native"
    assert lines["speak"] == f"CAPPED {cap} None"

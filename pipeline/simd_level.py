"""One SIMD level for every numeric library, so a stage writes the same bytes on any x86-64 CPU with AVX2.

NumPy, OpenCV, PyTorch (its ATen kernels, MKL and oneDNN), CTranslate2, OpenBLAS and x264 each pick their
kernels at run time from what the CPU offers — by width, and some by vendor (MKL and CTranslate2 take other
paths on AMD than on Intel). Kernels that differ add floats in different orders, so a CPU with AVX-512, or of
another vendor, would write outputs that differ in the last bits — and training amplifies those bits until every
downstream DVC hash differs. On every CPU with AVX2 this holds each library at one set of kernels: AVX2
(x86-64-v3) for those that dispatch by width, MKL's vendor-neutral branch, and the same backends on every
vendor. It runs when ``pipeline`` is first imported, before NumPy is: the libraries read these variables once,
when they load. A variable the user has set is left alone.

CPUs below AVX2 are not capped up (they cannot be): there the first stages (synthetic speaker, ingest,
landmarks) still write the same bytes — they avoid float kernels whose results depend on the SIMD width
(``pipeline.resample``; ``tests/test_determinism.py``) — and later stages may differ in the last bits.
"""
import os

AVX512_SKX = {"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"}

# each library's own switch, read when the library loads: the same kernels on every x86-64 CPU with AVX2,
# whatever its vendor or its wider units
AVX2_CAP = {
    "ATEN_CPU_CAPABILITY": "avx2",             # PyTorch's vectorised ATen kernels
    # Intel MKL (PyTorch's and CTranslate2's matrix products): its one branch that Intel documents as giving
    # the same results on Intel and Intel-compatible (AMD) CPUs — SSE2 without rcpps/rsqrtps. The AVX2
    # branch exists on Intel CPUs only (elsewhere MKL quietly falls back to its AUTO dispatch). MKL's vector
    # math (torch.sqrt) still runs rsqrtps there: training steps with pipeline/models/adam.py, not torch.sqrt.
    "MKL_CBWR": "COMPATIBLE",
    "CT2_USE_MKL": "1",                        # CTranslate2 (the Whisper encoder) takes MKL on AMD too (else oneDNN)
    # oneDNN (PyTorch's convolutions and its LSTM): AVX, one level lower. Its AVX2 LSTM kernels gave other bits
    # on an AVX-512 Xeon held at AVX2 than on emulated AVX2 CPUs of either vendor; at AVX (and SSE4.1) all
    # agree, and the convolutions agree at both (bench/cross_vendor.py). Cost: an LSTM step ≈ 1.2× (AVX vs AVX2).
    "ONEDNN_MAX_CPU_ISA": "AVX",
    "CT2_FORCE_CPU_ISA": "AVX2",               # CTranslate2's own kernels
    "OPENBLAS_CORETYPE": "Haswell",            # OpenBLAS inside NumPy and SciPy wheels (Zen would get its own blocking)
    # Intel IPP inside OpenCV picks its own level (k0 = AVX-512 where present), whatever OPENCV_CPU_DISABLE says
    "OPENCV_IPP": "avx2",
    # x264 (inside PyAV's FFmpeg) reads no variable: our writers pass this to its ``asm`` option (x264_params).
    # Its AVX-512 kernels change the bitstream (measured: the demo's synthetic speaker clips differ from the
    # AVX2 machine's unless x264 is held at this list, what it detects on an AVX2 CPU).
    "LIPSYNTH_X264_ASM": "MMX2,SSE2Fast,SSSE3,SSE4.2,AVX,FMA3,BMI2,AVX2",
}
# switches that name a feature group, set only on a CPU that has it (naming one it lacks warns)
AVX512_OFF = {
    # NumPy ≥ 2.4: every dispatch group above X86_V3. X86_V4 alone leaves AVX512_ICL (and AVX512_SPR) on: an
    # Ice Lake or Zen 4 kept its AVX-512 kernels under the X86_V4-only cap. A group the CPU lacks is ignored.
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
}


def cpu_flags(cpuinfo: str = "/proc/cpuinfo") -> set[str]:
    """The first processor's feature flags (Linux; an empty set where the file does not exist)."""
    try:
        with open(cpuinfo) as f:
            for line in f:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def cap_for(flags: set[str]) -> dict[str, str]:
    """The environment that holds every library at its AVX2 kernels on a CPU with these flags ({} below AVX2)."""
    if "avx2" not in flags:
        return {}
    cap = dict(AVX2_CAP)
    if "avx512f" in flags:
        cap.update(AVX512_OFF)
    if AVX512_SKX <= flags:                    # OpenCV dispatches one AVX-512 level; naming one the CPU lacks warns
        cap["OPENCV_CPU_DISABLE"] = "AVX512-SKX"
    return cap


def pin_avx2(environ=os.environ, flags: set[str] | None = None) -> dict[str, str]:
    """Set the AVX2 cap in ``environ`` (keeping any value already there); the variables it set.

    ``LIPSYNTH_SIMD=native`` in ``environ`` lifts the cap: every library uses all the CPU offers (faster on
    AVX-512; outputs then differ in the last bits from the committed ``dvc.lock``)."""
    if environ.get("LIPSYNTH_SIMD", "") == "native":
        return {}
    added = {k: v for k, v in cap_for(cpu_flags() if flags is None else flags).items() if k not in environ}
    environ.update(added)
    return added


def x264_params(options: str = "", environ=os.environ) -> dict[str, str]:
    """libx264's ``x264-params``: ``options`` ('key=value:…') and the option holding x264 at the capped
    instruction sets (``LIPSYNTH_X264_ASM``; none when unset: x264 then uses what it detects); {} when both
    are empty. Its kernels are not all bit-exact across sets, so without the cap an AVX-512 CPU writes other
    H.264 bytes than an AVX2 one."""
    asm = environ.get("LIPSYNTH_X264_ASM", "")
    parts = [o for o in (options, f"asm={asm}" if asm and asm != "auto" else "") if o]
    return {"x264-params": ":".join(parts)} if parts else {}

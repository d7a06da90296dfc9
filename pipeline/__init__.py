"""lipsynth's shared library — the bottom layer: it imports no stage and no application.

Its rooms, their order and what each module holds: docs/architecture.md, the one architecture text
(``tests/test_architecture_doc.py`` checks it against this package); each room's API: docs/api/.
"""
import os

from pipeline.simd_level import pin_avx2

pin_avx2()          # before any numeric library loads: the same bytes on every x86-64 CPU with AVX2
# NumPy asks the kernel for transparent huge pages on every array of ≥ 4 MB; each fresh one is then zeroed
# 2 MB at a time, and frame loops allocate such arrays (frames, float layers) by the thousand: `lipsynth speak`
# at 1080p spent 11 % of its CPU in the kernel's clear_page (perf). Read once, when NumPy loads; a user's
# value is kept.
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")

"""lipsynth's shared library — the bottom layer. It imports no stage and no application
(``stages/`` and ``lipsynth/`` build on it; see docs/index.md, "Architecture").

Rooms, lowest first (a module imports its own room and lower rooms only; ``tests/test_layers.py``):

    params.py, errors.py   typed params.yaml sections; the error types every room raises
    io/        media (PyAV), the zarr store, dask execution, the stage runner
    face/      dlib landmarks and index sets, geometry, the canonical frontal frame, identity, face mesh
    audio/     audio features and the front ends models read (MFCC, phones, autocorrelation, voice)
    video/     frame-level rules shared by synthesis and compositing (repeated frames)
    models/    the mouth PCA space, each model family's network/inference, the model folder,
               ensembles, the speaker bank, and ``mouth_prediction`` — the interface every family answers
    measures/  mouth-shape and lip-sync measures
"""
import os

from pipeline.simd_level import pin_avx2

pin_avx2()          # before any numeric library loads: the same bytes on every x86-64 CPU with AVX2
# NumPy asks the kernel for transparent huge pages on every array of ≥ 4 MB; each fresh one is then zeroed
# 2 MB at a time, and frame loops allocate such arrays (frames, float layers) by the thousand: `lipsynth speak`
# at 1080p spent 11 % of its CPU in the kernel's clear_page (perf). Read once, when NumPy loads; a user's
# value is kept.
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")

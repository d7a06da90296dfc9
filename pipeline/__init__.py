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
from pipeline.simd_level import pin_avx2

pin_avx2()          # before any numeric library loads: the same bytes on every x86-64 CPU with AVX2

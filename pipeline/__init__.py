"""lipsynth's shared library — the bottom layer: params, errors, media I/O, the zarr store, dask
execution, face/landmark constants, geometry, the canonical frontal frame, audio features, the
mouth-shape space and the model folder every family answers through. It imports no stage and no
application (``stages/`` and ``lipsynth/`` build on it; see the README's "Architecture")."""

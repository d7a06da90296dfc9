"""lipsynth shared library: params, store, media I/O, parallel execution, geometry."""

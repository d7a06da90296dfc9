"""The benchmarks: each module is a script (``python bench/NAME.py --help``) that measures one thing and
writes its figures to files (results/*.json, bench-written docs pages). The package is installed with the
project (editable), so a bench imports ``pipeline``, ``stages``, ``lipsynth`` and its sibling benches
(``bench.bench_results``) without editing ``sys.path``."""

"""Speed of the §3.3 re-timing DP (``stages.synthesize.retime.retime``).

    python bench/retime.py [--frames 2000 8000] [--repeats 7]

Prints the median wall time over ``--repeats`` runs for N output frames over 0.75 N target
frames (random speech flags and motion speeds).
"""
import argparse
import statistics
import time

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np


from stages.synthesize.retime import retime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, nargs="+", default=[2000, 8000])
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args()
    rng = np.random.default_rng(3)
    for n in a.frames:
        A, V = rng.random(n) < 0.7, rng.random(int(0.75 * n))
        times = []
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            retime(A, V)
            times.append(time.perf_counter() - t0)
        print(f"retime {n} output frames over {len(V)} target frames: median {1000 * statistics.median(times):.1f} ms "
              f"({1e6 * statistics.median(times) / n:.1f} µs/frame, {a.repeats} runs)")


if __name__ == "__main__":
    main()

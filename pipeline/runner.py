"""Common entry-point plumbing: logging, one-line errors, non-zero exit codes."""
from __future__ import annotations

import logging
import sys

from .errors import LipsynthError


def setup_logging(verbose: bool = False) -> None:
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s", datefmt="%H:%M:%S")
    for noisy in ("distributed", "numba", "matplotlib", "PIL"):
        logging.getLogger(noisy).setLevel(logging.WARNING)


def run_main(fn, *args, **kwargs) -> int:
    """Call ``fn``; a LipsynthError becomes one line on stderr and exit code 2."""
    try:
        fn(*args, **kwargs)
    except LipsynthError as exc:
        print(f"lipsynth: error: {exc}", file=sys.stderr)
        return 2
    return 0

"""lipsynth's tests (a regular package, so a third-party top-level `tests` package in site-packages — spafe ships one — cannot shadow it)."""

import pipeline  # noqa: F401  (first: caps the numeric libraries at one SIMD level before they load)

"""lipsynth applications: the command line and ``speak``, on top of the stages and ``pipeline``."""

import pipeline  # noqa: F401  (first: caps the numeric libraries at one SIMD level before they load)

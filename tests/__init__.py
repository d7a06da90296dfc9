"""lipsynth's tests (a regular package, so a third-party top-level `tests` package in site-packages — spafe ships one — cannot shadow it)."""

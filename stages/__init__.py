"""The pipeline stages, one folder each (see dvc.yaml)."""
import pipeline  # noqa: F401  (first: caps the numeric libraries at one SIMD level before they load)

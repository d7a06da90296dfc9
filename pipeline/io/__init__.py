"""I/O and execution: media (PyAV decode/encode), the zarr store (atomic outputs), dask clusters, the stage runner."""

"""Reconstruction of files and runs: a file's reconstruction and its products (2D, 3D
with its plane selection, PSF grids), batches of a run's frames on dask (in this
process or a child process; with a PSF grid) and 3D volumes sharded over dask
workers.
"""

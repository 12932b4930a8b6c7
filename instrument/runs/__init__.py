"""Run storage: the run store (creation, writing, reading, products, paths), what a run
records of itself and its verification (records, description, layout, integrity,
identity, recipe), its OME-Zarr description, per-frame coordinates, PSF stacks in
and out of run stores, and TIFF export.
"""

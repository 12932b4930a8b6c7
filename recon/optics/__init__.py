"""Optics models (layer 1, numerics only): propagation, PSF synthesis and holography."""

"""Calibration plans the bench operator runs (layer 4): dark/flat, PSF sweeps, ...

May import ``instrument`` and ``recon`` (see ARCHITECTURE.md).
"""

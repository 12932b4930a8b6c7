"""Reconstruction layer (layer 1): numerics only, no hardware.

Forward models with adjoints (:mod:`recon.operators`), solvers
(:mod:`recon.solvers`), loading and preprocessing (:mod:`recon.io`,
:mod:`recon.preprocess`) and the notebook API: :func:`recon.reconstruct` (2D) and
:func:`recon.reconstruct_volume` (3D).
"""

from .api import Reconstruction, reconstruct
from .volume.api import VolumeReconstruction, reconstruct_volume

__all__ = ["Reconstruction", "VolumeReconstruction", "reconstruct", "reconstruct_volume"]

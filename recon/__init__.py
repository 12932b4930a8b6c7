"""Reconstruction layer (layer 1): numerics only, no hardware.

Forward models with adjoints (:mod:`recon.operators`), solvers
(:mod:`recon.solvers`), loading and preprocessing (:mod:`recon.io`,
:mod:`recon.preprocess`) and the notebook API :func:`recon.reconstruct`.
"""

from .api import Reconstruction, reconstruct

__all__ = ["Reconstruction", "reconstruct"]

"""Reconstruction layer (layer 1): numerics only, no hardware.

Forward models with adjoints (:mod:`recon.operators`), solvers
(:mod:`recon.solvers`), loading and preprocessing (:mod:`recon.io`,
:mod:`recon.preprocess`) and the notebook API: :func:`recon.reconstruct` (2D) and
:func:`recon.reconstruct_volume` (3D).

The names below are imported on first use (PEP 562), so that importing a light
submodule (``recon.errors``, ``recon.io``) does not load numba and the solvers: the
command line's ``--help`` and its commands that do not reconstruct start fast.
"""

from typing import TYPE_CHECKING

from diffuserlab.lazy import lazy_attributes

__all__ = ["Reconstruction", "VolumeReconstruction", "reconstruct", "reconstruct_volume"]

_LAZY = {"Reconstruction": ".api", "reconstruct": ".api",
         "VolumeReconstruction": ".volume.api", "reconstruct_volume": ".volume.api"}

if TYPE_CHECKING:  # pragma: no cover
    from .api import Reconstruction, reconstruct
    from .volume.api import VolumeReconstruction, reconstruct_volume


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, globals(), __all__)

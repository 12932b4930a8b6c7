"""Reconstruction layer (layer 1): numerics only, no hardware.

Forward models with adjoints (:mod:`recon.operators`), solvers
(:mod:`recon.solvers`), loading and preprocessing (:mod:`recon.io`,
:mod:`recon.preprocess`) and the front door: :func:`recon.reconstruct` for a PSF
(2D), a :class:`recon.PsfStack` (3D) or a :class:`recon.spatial.PsfGrid` (spatially
varying), one :class:`recon.Reconstruction` result (``reconstruct_volume`` and
``reconstruct_grid`` are its short spellings for a stack and a grid).

The names below are imported on first use (PEP 562), so that importing a light
submodule (``recon.errors``, ``recon.io``) does not load numba and the solvers: the
command line's ``--help`` and its commands that do not reconstruct start fast.
"""

from typing import TYPE_CHECKING

from diffuserlab.lazy import lazy_attributes

__all__ = ["PsfStack", "ReconInfo", "Reconstruction", "reconstruct", "reconstruct_grid",
           "reconstruct_volume"]

_LAZY = {name: ".api" for name in __all__}

if TYPE_CHECKING:  # pragma: no cover
    from .api import (
        PsfStack,
        ReconInfo,
        Reconstruction,
        reconstruct,
        reconstruct_grid,
        reconstruct_volume,
    )


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, globals(), __all__)

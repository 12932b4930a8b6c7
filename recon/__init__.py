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

__all__ = ["Reconstruction", "VolumeReconstruction", "reconstruct", "reconstruct_volume"]

_LAZY = {"Reconstruction": ".api", "reconstruct": ".api",
         "VolumeReconstruction": ".volume.api", "reconstruct_volume": ".volume.api"}

if TYPE_CHECKING:  # pragma: no cover
    from .api import Reconstruction, reconstruct
    from .volume.api import VolumeReconstruction, reconstruct_volume


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

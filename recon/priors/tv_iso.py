"""Isotropic total variation: the group soft threshold of each pixel's gradient."""

from __future__ import annotations

import numpy as np

from ..backend import total
from ._kernels import group_shrink_2
from .base import TotalVariation

__all__ = ["IsotropicTV"]


class IsotropicTV(TotalVariation):
    """Isotropic TV (Rudin, Osher & Fatemi 1992): g = sum over pixels of |grad x|, the
    Euclidean norm of the forward differences along every axis of the split (the
    plan's Psi: 2D the x and y differences; a volume's three).

    G_u is the plan's finite differences, as for :class:`~recon.priors.TotalVariation`
    (one split array per axis, the same x-update; a subclass of it that changes the
    shrinkage and the value); the prox of ``(weight / mu2) ||.||_{2,1}`` is the group
    soft threshold ``t max(1 - thr / |t|, 0)`` of each pixel's difference vector t,
    thr = weight / mu2. On NumPy the ADMM runs it inside the fused
    split pass of anisotropic TV (``recon._kernels.admm_split_updates_2d`` with
    ``iso``, the plan's :meth:`~recon.solvers.admm.AdmmPlan.isotropic_view`); this
    prox serves the generic kernel set: one numba pass on two NumPy arrays
    (``recon.priors._kernels.group_shrink_2``), whole-array operations otherwise.
    Unlike anisotropic TV it does not favour edges along the grid's axes.

    Examples
    --------
    >>> import numpy as np
    >>> t = (np.array([0.3, 0.01], np.float32), np.array([0.4, 0.0], np.float32))
    >>> [a.round(6) for a in IsotropicTV().prox(np, t, 1e-3, 1e-2)]  # |(.3, .4)| = .5
    [array([0.24, 0.  ], dtype=float32), array([0.32, 0.  ], dtype=float32)]
    """

    name = "tv-iso"

    def shrink(self, xp, t: tuple, thr: float) -> tuple:
        """The group soft threshold at ``thr`` > 0 of the pixels' vectors across ``t``."""
        if len(t) == 2 and all(isinstance(s, np.ndarray) and s.dtype == np.float32
                               and s.ndim == 2 and s.flags.c_contiguous for s in t):
            out = (np.empty_like(t[0]), np.empty_like(t[1]))
            group_shrink_2(t[0], t[1], np.float32(thr), *out)
            return out
        norm = xp.sqrt(sum(s * s for s in t))
        scale = xp.clip(1.0 - thr / xp.clip(norm, min=1e-30), min=0.0)
        return tuple(s * scale for s in t)

    def value(self, xp, x, g: tuple) -> float:
        return total(xp, xp.sqrt(sum(d * d for d in g)))

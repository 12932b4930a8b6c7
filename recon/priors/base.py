"""The prior interface of the ADMM's u split, and total variation."""

from __future__ import annotations

import numpy as np

from ..backend import device_of, to_numpy, total

__all__ = ["Prior", "TotalVariation", "on_host", "put_like"]


def on_host(t) -> np.ndarray:
    """``t`` (any array-API array, any shape) as a C-contiguous float32 NumPy array of
    the same shape (a copy off a device; ``t`` itself when it is one already)."""
    return np.ascontiguousarray(to_numpy(t), np.float32)


def put_like(xp, a: np.ndarray, like):
    """NumPy ``a`` (any shape and dtype) as an array of namespace ``xp`` on the device of
    ``like``; ``a`` itself when ``like`` is a NumPy array."""
    if isinstance(like, np.ndarray):
        return a
    return xp.asarray(a, device=device_of(like))


class Prior:
    """One prior of the u split: its G_u kind and its proximal step.

    Attributes
    ----------
    name : str
        Its name on the command line and in records.
    identity_split : bool
        G_u is the identity (u = x, one split array); False: the plan's finite
        differences (TV, one array per axis).

    Notes
    -----
    The u-update of scaled-dual ADMM (Boyd et al. 2011, Sec. 3.1.1) is
    ``z = prox_{weight g / mu2}(G_u x + a_u)``; :meth:`prox` gets the arrays ``t`` =
    G_u x + a_u (a tuple, one per split array) and returns ``z`` like them.
    """

    name = "prior"
    identity_split = True

    def prox(self, xp, t: tuple, weight: float, mu2: float) -> tuple:
        """The u-update: ``prox_{weight g / mu2}(t)``, arrays like ``t``."""
        raise NotImplementedError

    def value(self, xp, x, g: tuple) -> float:
        """g(G_u x) without the weight (the objective's term), from x and ``g`` = G_u x;
        0.0 for a prior without an explicit g (a plug-and-play denoiser)."""
        raise NotImplementedError

    def record(self) -> dict:
        """The prior's settings for a result's record."""
        return {"prior": self.name}

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class TotalVariation(Prior):
    """Anisotropic TV (Eq. 3.9): g = ||Psi x||_1 with Psi the plan's forward
    differences; the prox is the soft threshold at ``weight / mu2``, the same float32
    arithmetic as the fused numba pass of the NumPy path
    (``recon._kernels.admm_split_updates_2d``).

    Examples
    --------
    >>> import numpy as np
    >>> t = (np.array([-0.3, 0.05, 0.2], np.float32),)
    >>> TotalVariation().prox(np, t, 1e-3, 1e-2)[0].round(6)  # soft threshold at 0.1
    array([-0.2,  0. ,  0.1], dtype=float32)
    """

    name = "tv"
    identity_split = False

    def prox(self, xp, t: tuple, weight: float, mu2: float) -> tuple:
        thr = weight / mu2
        if thr <= 0:
            return tuple(t)
        return self.shrink(xp, t, thr)

    def shrink(self, xp, t: tuple, thr: float) -> tuple:
        """The prox at threshold ``thr`` > 0: each array soft-thresholded."""
        return tuple(s - xp.clip(s, min=-thr, max=thr) for s in t)

    def value(self, xp, x, g: tuple) -> float:
        return sum(total(xp, xp.abs(d)) for d in g)

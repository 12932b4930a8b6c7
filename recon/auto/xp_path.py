"""The automatic weight's path on the measurement's backend: the few whole-array steps
of :func:`recon.auto.weight.admm_auto` outside its ADMM solves (held-out score, copies
of the iterates, norms), on NumPy or on a device through the array API, so that the
path's iterates and scores stay on the device between its warm-started solves.
"""

from __future__ import annotations

import math

import numpy as np

from ..backend import array_namespace, device_of, is_numpy, total

__all__ = ["PathArrays", "device_plan_of"]


def device_plan_of(like, numpy_plan_of):
    """``plan_of`` of the 2D convolution on ``like``'s device: the generic plans
    (:class:`recon.solvers.xp_admm.XpAdmmPlan`) of ``numpy_plan_of``'s plans."""
    from ..solvers.xp_admm import XpAdmmPlan

    return XpAdmmPlan.maker(like, numpy_plan_of)


class PathArrays:
    """The few whole-array steps of :func:`recon.auto.weight.admm_auto` outside the
    plan's solves, on the measurement's backend: NumPy (the path's own arithmetic), or
    the array-API namespace of a device array (the iterates and the held-out scores
    stay on that device).

    Parameters
    ----------
    b : array
        The path's measurement (``numpy.ndarray``, or an array of another backend).
    """

    def __init__(self, b):
        self.numpy = is_numpy(b)
        if not self.numpy:
            self.xp, self.device = array_namespace(b), device_of(b)

    def put(self, a: np.ndarray, dtype=np.float32):
        """A host array as an array of the measurement's backend."""
        a = np.ascontiguousarray(a, dtype)
        return a if self.numpy else self.xp.asarray(a, device=self.device)

    def norm(self, a) -> float:
        """||a|| as a float."""
        if self.numpy:
            return float(np.linalg.norm(a))
        return math.sqrt(total(self.xp, a * a))

    def copy(self, a):
        """A copy of ``a`` (on its device)."""
        return a.copy() if self.numpy else self.xp.asarray(a, copy=True)

    def held_error(self, pred, b, held, n_held: int) -> tuple[float, float]:
        """Sum of ``(pred - b)^2`` over the held-out pixels (float64) and its standard
        error (``std * sqrt(n)``); ``held`` a bool mask (NumPy) or its float64 0/1
        array (a device)."""
        if self.numpy:
            e = np.square(pred - b, dtype=np.float64)[held]
            return float(e.sum()), float(e.std() * math.sqrt(e.size)) if e.size else 0.0
        if not n_held:
            return 0.0, 0.0
        xp = self.xp
        d = xp.astype(pred - b, xp.float64)
        e = d * d * held
        s = total(xp, e)
        dev = (e - s / n_held) * held  # two-pass, as numpy.std
        return s, math.sqrt(total(xp, dev * dev) / n_held) * math.sqrt(n_held)

    def clip0(self, a):
        """max(a, 0)."""
        return np.maximum(a, 0) if self.numpy else self.xp.clip(a, min=0.0)


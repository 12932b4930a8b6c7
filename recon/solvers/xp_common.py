"""Array-API building blocks shared by the generic solvers: the ADMM split proxes in
q-form, their residual-balancing terms, TV, the monitor and array helpers.

Each function is the whole-array form of a numba kernel of the NumPy path
(:mod:`recon.jit`, :mod:`recon._kernels`, :mod:`recon.volume._admm_kernels3d`) with the
same arithmetic in float32, so the two paths agree to float32 rounding.
"""

from __future__ import annotations

import math

from ..backend import array_namespace, to_numpy, total
from ..errors import DivergenceError, ReconInputError
from .common import Monitor

__all__ = ["XpMonitor", "balance_terms", "check_measurement_xp", "data_split",
           "forward_difference", "shrink_split", "total", "tv_circular"]


def shrink_split(xp, g, q, thr: float, nonneg: bool):
    """One shrinkage split in q-form, whole arrays (:func:`recon.jit.shrink_split`).

    ``a = g - q``, ``z = soft(g + a, thr)`` (then ``max(., 0)`` with ``nonneg``),
    ``q_new = z - a``.

    Returns
    -------
    q_new, a, z : arrays like ``g``
    """
    a = g - q
    t = g + a
    z = t - xp.clip(t, min=-thr, max=thr) if thr > 0 else t
    if nonneg:
        z = xp.clip(z, min=0.0)
    return z - a, a, z


def data_split(g, q, wp, bp, mu1: float):
    """The data split ``v = M x`` in q-form (:func:`recon.jit.data_split`).

    Returns
    -------
    q_new, a, z, r : arrays
        ``r = w g - b`` (the data misfit before squaring).
    """
    a = g - q
    t = g + a
    z = (wp * bp + mu1 * t) / (wp * wp + mu1)
    return z - a, a, z, wp * g - bp


def balance_terms(xp, g, q, a, z, a_old) -> tuple[float, float, float, float]:
    """Residual-balancing sums of one split (:func:`recon.jit.balance_terms`):
    ``sum (a - a_old)^2, sum (z - q - a_old)^2, sum max(g^2, z^2), sum a^2``."""
    d = a - a_old
    e = z - q - a_old
    return (total(xp, d * d), total(xp, e * e), total(xp, xp.maximum(g * g, z * z)),
            total(xp, a * a))


def forward_difference(xp, z, axis: int, wrap: bool = True):
    """``z[i + 1] - z[i]`` along ``axis``: circular (``wrap``), or open (zero across the
    last slice: a volume's depth, which does not wrap), like ``z``."""
    if wrap:
        return xp.roll(z, -1, axis=axis) - z
    lo = [slice(None)] * z.ndim
    hi = [slice(None)] * z.ndim
    edge = [slice(None)] * z.ndim
    lo[axis], hi[axis], edge[axis] = slice(0, -1), slice(1, None), slice(0, 1)
    return xp.concat([z[tuple(hi)] - z[tuple(lo)], xp.zeros_like(z[tuple(edge)])], axis=axis)


def tv_circular(xp, x, axes) -> float:
    """Anisotropic TV along ``axes`` with circular forward differences."""
    return sum(total(xp, xp.abs(xp.roll(x, -1, axis=ax) - x)) for ax in axes)


def check_measurement_xp(b, shape: tuple[int, ...]):
    """A measurement of the generic path: float32, the right shape, finite, not all
    zero (:func:`recon.solvers.common.check_measurement`'s checks).

    Raises
    ------
    ReconInputError
        Wrong shape or dtype, NaN/inf values, or all zero.
    """
    xp = array_namespace(b)
    if tuple(b.shape) != tuple(shape):
        raise ReconInputError(f"measurement has shape {tuple(b.shape)}, the forward model "
                              f"expects {tuple(shape)}; bin or crop the raw image like the PSF")
    if b.dtype != xp.float32:
        b = xp.astype(b, xp.float32)
    bad = math.prod(b.shape) - total(xp, xp.astype(xp.isfinite(b), xp.float32))
    if bad:
        raise ReconInputError(f"measurement contains {int(bad)} NaN/inf values; fix or mask "
                              "those pixels (erasure mask) before reconstructing")
    if not total(xp, xp.abs(b)) > 0:
        raise ReconInputError("measurement is all zero after preprocessing; check the exposure "
                              "and the dark level")
    return b


class XpMonitor(Monitor):
    """:class:`~recon.solvers.common.Monitor` for any backend: the last good estimate
    is kept on the array's device and copied to the host only when a divergence is
    reported (:class:`~recon.errors.DivergenceError` carries a NumPy array)."""

    def __init__(self, xp, b_norm_sq: float, method: str, growth_limit: float = 100.0):
        super().__init__(b_norm_sq, method, growth_limit)
        self.xp = xp
        self._snap = None

    def record(self, objective: float, data_sq: float, x=None, hint: str = "") -> None:
        """As :meth:`Monitor.record`; the snapshot stays on the device."""
        k = len(self.history.objective) + 1
        try:
            super().record(objective, data_sq, None, hint)
        except DivergenceError as exc:
            exc.last_good = None if self._snap is None else to_numpy(self._snap)
            raise
        if x is not None and (k - 1) % self.snapshot_every == 0:
            self._snap = self.xp.asarray(x, copy=True)

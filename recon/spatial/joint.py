"""What the NumPy and the array-API paths of the joint object and background FISTA
(Kuo 2020, Eq. 6.2; :func:`recon.spatial.fista_background`,
:func:`recon.spatial.xp_background.fista_background_xp`) share: the background's
span, the lowest ``n x n`` orthonormal DCT-II basis images (``g = By c Bx^T``) with
Dykstra's projection onto that span intersected with ``g >= 0``, the step's
Lipschitz constant and the result.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft

from ..backend import array_namespace, device_of
from ..errors import ReconInputError
from ..solvers.common import Monitor, SolveResult
from ..validate import as_int

__all__ = ["LowFrequency", "dct_basis", "joint_lipschitz", "joint_result", "low_frequency"]


def dct_basis(length: int, n_low: int) -> np.ndarray:
    """The ``n_low`` lowest orthonormal DCT-II basis vectors of a length, (length, n_low).

    Columns are orthonormal, so ``B B^T`` projects onto their span and ``B^T x``
    are the DCT coefficients of :func:`scipy.fft.dct` (``norm="ortho"``).
    """
    eye = np.eye(length, n_low)
    return sfft.idct(eye, type=2, norm="ortho", axis=0)


class LowFrequency:
    """The span of the ``n x n`` lowest DCT basis images of a (rows, cols) frame, on
    the backend and device of ``like`` (default NumPy).

    Parameters
    ----------
    shape : (rows, cols)
    n_low : int
        ``n``, 1..min(shape).
    like : array, optional
        An array of the target backend and device (default: NumPy).

    Attributes
    ----------
    by, bx : arrays, float32, (rows, n) and (cols, n)
        Orthonormal columns (:func:`dct_basis`).

    Raises
    ------
    ReconInputError
        ``n_low`` not an integer >= 1, or larger than the frame.
    """

    def __init__(self, shape, n_low: int, like=None):
        n_low = as_int(n_low, "background DCT size n_low", 1)
        if n_low > min(shape):
            raise ReconInputError(f"background DCT size {n_low} exceeds the sensor {shape}")
        by = dct_basis(shape[0], n_low).astype(np.float32)
        bx = dct_basis(shape[1], n_low).astype(np.float32)
        self.xp = np if like is None or isinstance(like, np.ndarray) else array_namespace(like)
        if self.xp is not np:
            by, bx = (self.xp.asarray(a, device=device_of(like)) for a in (by, bx))
        self.by, self.bx = by, bx

    def coefficients(self, g):
        """DCT coefficients ``By^T g Bx`` (n, n) of a frame ``g`` (rows, cols)."""
        return self.by.T @ g @ self.bx

    def image(self, c):
        """The frame ``By c Bx^T`` (rows, cols) float32 of coefficients ``c`` (n, n)."""
        return self.xp.astype(self.by @ c @ self.bx.T, self.xp.float32)

    def project(self, g):
        """Orthogonal projection of a frame onto the span."""
        return self.image(self.coefficients(g))

    def project_nonneg(self, g, rounds: int = 8):
        """Dykstra's projection onto span & {g >= 0}; the result lies in the span."""
        xp = self.xp
        x = g
        p = xp.zeros_like(g)
        q = xp.zeros_like(g)
        for _ in range(rounds):
            yk = xp.maximum(x + p, 0.0)
            p = x + p - yk
            x = self.project(yk + q)
            q = yk + q - x
            if xp.min(x) >= 0:
                break
        return x


def low_frequency(b, n_low: int) -> LowFrequency:
    """The background's span for a measurement ``b`` (any backend).

    Raises
    ------
    ReconInputError
        ``b`` not 2D, or a bad ``n_low`` (:class:`LowFrequency`).
    """
    if len(b.shape) != 2:
        raise ReconInputError("the background model needs a 2D sensor image")
    return LowFrequency(tuple(b.shape), n_low, like=b)


def joint_lipschitz(op, known: float | None) -> float:
    """``known``, or the power iteration's L of ``A^T A`` (``op.lipschitz()``, NumPy or
    generic operator).

    Raises
    ------
    ReconInputError
        L is 0 or not finite (a zero forward model).
    """
    if known is not None:
        return known
    lip_a = op.lipschitz()
    if not (lip_a > 0 and math.isfinite(lip_a)):
        raise ReconInputError("forward model is zero (Lipschitz constant 0): check the PSFs")
    return lip_a


def joint_result(x, g, mon: Monitor, data_sq: float, x_sum: float, low: LowFrequency,
                 params: dict, restarts: list[int]) -> SolveResult:
    """The :class:`SolveResult` of a joint object and background solve (any backend).

    ``final_objective = 1/2 data_sq + l1 x_sum``; ``params`` gets ``background``
    (``g``) and ``background_dct`` (its coefficients, on ``g``'s device); the history
    ``restarts``.
    """
    mon.history.extra["restarts"] = restarts
    final = 0.5 * data_sq + params["l1"] * x_sum
    params = {**params, "background": g, "background_dct": low.coefficients(g)}
    return SolveResult(x, mon.history, final, math.sqrt(data_sq) / mon.b_norm, params)

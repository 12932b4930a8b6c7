"""Wiener / Tikhonov deconvolution on any array-API backend: one FFT pair on the device.

:func:`recon.solvers.wiener` for a measurement of another backend: the same filter
``conj(H) / (|H|^2 + lambda)`` (complex64, computed once on the host from the NumPy
operator's spectrum, so both paths multiply by the same numbers), applied on the
device to the zero-padded measurement (one rfft2 + one irfft2).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..xp_operators import XpConvolution
from .common import History, SolveResult
from .xp_common import check_measurement_xp, total

__all__ = ["memory_bytes", "wiener_xp"]


def memory_bytes(padded_shape: tuple[int, int]) -> int:
    """Peak device memory of :func:`wiener_xp` (bytes): about 8 float32 planes of the
    padded grid (the padded measurement, the estimate, the residual's forward model
    and the operator's weights) and 4 complex half-spectra (filter, operator's
    spectra, the measurement's)."""
    plane = 4 * padded_shape[0] * padded_shape[1]
    return 8 * plane + 4 * plane


def wiener_xp(op, b, lam: float) -> SolveResult:
    """Wiener deconvolution of :func:`recon.solvers.wiener` on ``b``'s backend.

    Parameters
    ----------
    op : ConvolutionOperator
        The NumPy forward model (validated by the caller).
    b : array (array API), float32, ``op.shape_out``
        Measurement on the target device (already weighted).
    lam : float
        lambda (> 0), in units of |H|^2.

    Returns
    -------
    SolveResult
        ``x`` (P0, P1) float32 on ``b``'s device; ``history.seconds`` the solve (the
        device synchronised by reading one element back).

    Raises
    ------
    ReconInputError
        Misshapen, non-finite or all-zero ``b``.
    """
    xop = XpConvolution(op, b)
    xp = xop.xp
    b = check_measurement_xp(b, op.shape_out)
    spec = op.spectrum
    filt = xop.asarray((op.spectrum_conj / (spec.real**2 + spec.imag**2 + lam)
                        ).astype(np.complex64))
    t0 = time.perf_counter()
    x = xp.fft.irfftn(xp.fft.rfftn(xop.pad(b), axes=(-2, -1)) * filt, s=xop.padded_shape,
                      axes=(-2, -1))
    float(x[0, 0])  # wait for the device
    seconds = time.perf_counter() - t0
    r = xop.forward(x) - b
    data_sq = total(xp, r * r)
    b_norm = math.sqrt(total(xp, b * b))
    relative = math.sqrt(data_sq) / b_norm
    hist = History(objective=[0.5 * data_sq], data_residual=[relative], seconds=[seconds])
    return SolveResult(x, hist, 0.5 * data_sq, relative,
                       {"regularization": lam, "backend": xp.__name__})

"""Wiener / Tikhonov deconvolution on the padded domain: the fast preview."""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import ReconInputError
from ..fft import irfftn, rfftn
from ..operators import ConvolutionOperator
from ..validate import positive
from .common import History, SolveResult, check_measurement


def auto_regularization(b: np.ndarray) -> float:
    """Noise-to-signal power ratio sigma_n^2 / mean(b^2) of a measurement.

    The noise standard deviation is estimated with
    :func:`skimage.restoration.estimate_sigma` (wavelet MAD). For a PSF normalised to
    unit sum (|H| <= 1) this is the Tikhonov weight of a Wiener filter with a white
    object spectrum of the measurement's power. Floored at 1e-4.

    Parameters
    ----------
    b : ndarray, (rows, cols), float32

    Returns
    -------
    float
    """
    from skimage.restoration import estimate_sigma

    sigma = float(estimate_sigma(b.astype(np.float64)))
    power = float(np.mean(np.square(b, dtype=np.float64)))
    return max(sigma * sigma / power if power > 0 else 1.0, 1e-4)


def wiener(op: ConvolutionOperator, b: np.ndarray, regularization: float | None = None
           ) -> SolveResult:
    """Wiener / Tikhonov deconvolution x = F^-1 [conj(H) F(P w b) / (|H|^2 + lambda)].

    A one-shot solve on the padded domain: the measurement is zero-padded (the crop
    of Eq. 3.4 is ignored), so it is a preview, not a least-squares solution of the
    cropped model.

    Parameters
    ----------
    op : ConvolutionOperator
        Forward model (its PSF spectrum and sensor weights are used).
    b : ndarray, shape ``op.shape_out``, float32
        Measurement (already multiplied by the sensor weights). An array of another
        array-API backend (CuPy, PyTorch) runs ``recon.solvers.xp_wiener.wiener_xp``
        on its device and returns ``x`` there (the automatic lambda is estimated
        from a host copy).
    regularization : float, optional
        lambda, in units of |H|^2; default :func:`auto_regularization`.

    Returns
    -------
    SolveResult
        ``history.seconds`` holds the solve time (filter precomputation excluded).

    Raises
    ------
    ReconInputError
        If the operator is not a convolution, lambda is not positive, or b is
        misshapen, not finite or all zero.
    """
    if not isinstance(op, ConvolutionOperator):
        raise ReconInputError("Wiener deconvolution needs a ConvolutionOperator forward model")
    if not isinstance(b, np.ndarray):  # another backend: the array-API path
        from ..backend import to_numpy
        from .xp_common import check_measurement_xp
        from .xp_wiener import wiener_xp

        b = check_measurement_xp(b, op.shape_out)
        # the noise estimate (wavelet MAD, scikit-image) reads the measurement on the host
        lam = (auto_regularization(to_numpy(b)) if regularization is None
               else positive(regularization, "regularization"))
        return wiener_xp(op, b, lam)
    b = check_measurement(b, op.shape_out)
    lam = (auto_regularization(b) if regularization is None
           else positive(regularization, "regularization"))
    spec = op.spectrum
    filt = (op.spectrum_conj / (spec.real**2 + spec.imag**2 + lam)).astype(np.complex64)
    padded = op.pad_buffer()
    b32 = b
    t0 = time.perf_counter()
    padded[op.crop] = b32
    spectrum = rfftn(padded)
    np.multiply(spectrum, filt, out=spectrum)
    x = irfftn(spectrum, op.padded_shape)
    seconds = time.perf_counter() - t0
    r = op.forward(x) - b32
    data_sq = float(np.vdot(r, r))
    b_norm = float(np.linalg.norm(b32))
    hist = History(objective=[0.5 * data_sq], data_residual=[math.sqrt(data_sq) / b_norm],
                   seconds=[seconds])
    return SolveResult(x, hist, 0.5 * data_sq, math.sqrt(data_sq) / b_norm,
                       {"regularization": lam})

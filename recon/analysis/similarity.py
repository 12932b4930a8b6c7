"""PSF similarity across a calibration stack: auto- and cross-correlations, inner products.

Following G. Kuo, *Exploiting Randomness in Computational Cameras and Displays*
(PhD dissertation, UC Berkeley, 2020), App. A.2 ("PSF similarity", Fig. A.3):

- :func:`cross_correlation` -- normalised linear cross-correlation of two PSFs
  (an autocorrelation when both are the same PSF: peak 1 at zero lag).
- :func:`inner_products_with` -- the normalised inner product of one PSF of a stack
  with every PSF of the stack (Fig. A.3b).
- :func:`stack_similarity` -- everything Fig. A.3 shows, in one dictionary: each
  PSF's autocorrelation central lines, the cross-correlation between the nearest
  and farthest depths, and the inner products with one PSF.

Correlations are not mean-subtracted (as :func:`~recon.analysis.psf.inner_product`):
remove background light first (:func:`~recon.analysis.psf.remove_background_dct`).
Every refusal raises :class:`recon.errors.ReconInputError` whose message says what
is wrong and how to fix it. Results are float64.
"""

from __future__ import annotations

import numbers
import os
from typing import Any

import numpy as np
import scipy.fft

from recon.analysis.psf import inner_product
from recon.errors import ReconInputError
from recon.validate import float_array

__all__ = ["cross_correlation", "inner_products_with", "stack_similarity"]


# ----------------------------------------------------------------------------- helpers


def check_image(value: Any, name: str) -> np.ndarray:
    """A 2D PSF image as float64, refusing what :func:`recon.validate.float_array` refuses.

    Raises
    ------
    ReconInputError
        Not a finite 2D numeric array, or all zero (its correlation is undefined).
    """
    h = float_array(value, name)
    if not np.any(h):
        raise ReconInputError(
            f"{name} is all zero, so its correlation is undefined; pass a PSF with signal "
            "(check exposure and background removal)"
        )
    return h


def check_stack(value: Any, name: str = "stack") -> np.ndarray:
    """A PSF stack ``(n, rows, cols)`` as float64 with no all-zero PSF.

    Raises
    ------
    ReconInputError
        Not a finite 3D numeric array, no PSF, or an all-zero PSF (its index is named).
    """
    s = float_array(value, name, ndims=(3,))
    if s.shape[0] < 1:
        raise ReconInputError(f"{name} holds no PSF; pass a stack (n, rows, cols) with n >= 1")
    empty = [i for i in range(s.shape[0]) if not np.any(s[i])]
    if empty:
        raise ReconInputError(
            f"{name}[{empty[0]}] is all zero ({len(empty)} empty PSF(s) in the stack); drop "
            "them or re-acquire (check exposure and background removal)"
        )
    return s


def _index(value: Any, n: int, name: str = "index") -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ReconInputError(f"{name} must be an integer, got {value!r}")
    i = int(value)
    if not -n <= i < n:
        raise ReconInputError(
            f"{name} = {i} is outside the stack of {n} PSF(s); pass 0 .. {n - 1} (or a "
            "negative index from the end)"
        )
    return i % n


def full_xcorr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unnormalised ``c[t] = sum_u a[u] b[u + t]`` for all lags, zero lag at the centre."""
    rows, cols = a.shape
    shape = (
        scipy.fft.next_fast_len(2 * rows - 1, real=True),
        scipy.fft.next_fast_len(2 * cols - 1, real=True),
    )
    workers = os.cpu_count()
    fa = scipy.fft.rfft2(a, s=shape, workers=workers)
    fb = fa if b is a else scipy.fft.rfft2(b, s=shape, workers=workers)
    circ = scipy.fft.irfft2(np.conj(fa) * fb, s=shape, workers=workers)
    # circular lag t sits at index t mod shape; move lag -(n-1) to index 0 and crop
    circ = np.roll(circ, (rows - 1, cols - 1), axis=(0, 1))
    return np.ascontiguousarray(circ[: 2 * rows - 1, : 2 * cols - 1])


def line_spectrum(h: np.ndarray, axis: int) -> tuple[np.ndarray, int]:
    """Power spectrum along `axis`, summed over the other axis, zero-padded to >= 2 n - 1.

    Its inverse real FFT is the central line (zero lag along the other axis) of the
    linear autocorrelation of `h` along `axis`.
    """
    length = h.shape[axis]
    n = scipy.fft.next_fast_len(2 * length - 1, real=True)
    spec = scipy.fft.rfft(h, n=n, axis=axis, workers=os.cpu_count())
    power = np.sum(spec.real**2 + spec.imag**2, axis=1 - axis)
    return power, n


def _central_line(h: np.ndarray, axis: int) -> np.ndarray:
    """Central line of the normalised linear autocorrelation along `axis`, lags -(n-1)..n-1."""
    power, n = line_spectrum(h, axis)
    circ = scipy.fft.irfft(power, n=n)
    length = h.shape[axis]
    line = np.concatenate([circ[n - (length - 1) :], circ[:length]])
    return line / float(np.sum(h * h))


# ----------------------------------------------------------------------------- functions


def cross_correlation(a: Any, b: Any) -> np.ndarray:
    """Normalised linear cross-correlation of two images, zero lag at the centre.

    Parameters
    ----------
    a, b : array_like
        Shape (rows, cols) each, same shape, real, finite, not all zero (e.g. two
        background-removed PSFs).

    Returns
    -------
    numpy.ndarray
        float64, shape (2 rows - 1, 2 cols - 1):
        ``C[dy + rows - 1, dx + cols - 1] = sum_u a[u] b[u + (dy, dx)] / (|a| |b|)``
        for every lag ``|dy| < rows``, ``|dx| < cols`` (zero outside the arrays).
        By Cauchy-Schwarz ``|C| <= 1``; ``cross_correlation(h, h)`` has its peak 1
        at the centre ``(rows - 1, cols - 1)``. If ``b`` is ``a`` shifted by
        ``(+dy, +dx)`` the peak is at lag ``(dy, dx)`` (the convention of
        :func:`~recon.analysis.psf.register_shift`).

    Raises
    ------
    ReconInputError
        If an input is not a finite 2D array, is all zero, or the shapes differ.

    Notes
    -----
    Computed with real FFTs zero-padded to at least ``(2 rows - 1, 2 cols - 1)``,
    so no lag wraps around. The value at lag ``t`` is the normalised inner product
    ``<a, b(. + t)>`` of Eq. 3.11 when nothing of ``b`` leaves the frame; App. A.2
    uses it between the nearest and farthest PSFs of a stack ("the cross-correlation
    has no values greater than 50 %").
    """
    a_ = check_image(a, "a")
    b_ = a_ if b is a else check_image(b, "b")
    if a_.shape != b_.shape:
        raise ReconInputError(
            f"a has shape {a_.shape} but b has shape {b_.shape}; crop or pad them to the same shape"
        )
    norm = float(np.linalg.norm(a_)) * float(np.linalg.norm(b_))
    return full_xcorr(a_, b_) / norm


def inner_products_with(stack: Any, index: int) -> np.ndarray:
    """Normalised inner product of one PSF of a stack with every PSF of the stack.

    Parameters
    ----------
    stack : array_like
        Shape (n, rows, cols), real, finite; no PSF all zero. Usually ordered by
        depth.
    index : int
        Which PSF to compare with all the others (negative counts from the end).

    Returns
    -------
    numpy.ndarray
        float64, shape (n,): ``inner_product(stack[index], stack[k])``
        (:func:`~recon.analysis.psf.inner_product`, not mean-subtracted); 1 at
        ``k = index``.

    Raises
    ------
    ReconInputError
        If `stack` is not a finite 3D array without empty PSFs, or `index` is not an
        integer inside the stack.

    Notes
    -----
    Fig. A.3b: the inner product of the PSF from the middle of the volume with all
    other PSFs; a sharp peak with side lobes around 0.5 shows the caustics from
    different depths are distinct.
    """
    s = check_stack(stack)
    i = _index(index, s.shape[0])
    return np.array([inner_product(s[i], s[k]) for k in range(s.shape[0])], dtype=np.float64)


def stack_similarity(
    stack: Any, depths_mm: Any | None = None, *, index: int | None = None
) -> dict[str, Any]:
    """PSF similarity across a depth stack, as in Fig. A.3 (App. A.2).

    Parameters
    ----------
    stack : array_like
        Shape (n, rows, cols), real, finite, no PSF all zero; background removed.
    depths_mm : array_like, optional
        Shape (n,), object-to-diffuser distance of each PSF in mm (> 0, distinct).
        Used to pick the nearest and farthest PSF; without it the first and last
        PSF are taken as nearest and farthest.
    index : int, optional
        The PSF compared with all others by inner product; default the middle one,
        ``n // 2`` (in the stack's order).

    Returns
    -------
    dict
        ``lags_x_px`` : float64 (2 cols - 1,), lags of the x lines, px.
        ``lags_y_px`` : float64 (2 rows - 1,), lags of the y lines, px.
        ``autocorrelation_x`` : float64 (n, 2 cols - 1), central row (zero y lag)
        of each PSF's normalised autocorrelation (peak 1 at lag 0).
        ``autocorrelation_y`` : float64 (n, 2 rows - 1), central column likewise.
        ``nearest``, ``farthest`` : int, stack indices of the nearest / farthest PSF.
        ``cross_correlation_max`` : float, maximum over all lags of
        :func:`cross_correlation` of the nearest and farthest PSFs.
        ``cross_correlation_argmax_px`` : (int, int), its lag (dy, dx) in px.
        ``cross_correlation_x`` : float64 (2 cols - 1,), the cross-correlation's
        central row (zero y lag), as plotted in Fig. A.3a.
        ``index`` : int, the PSF used for the inner products.
        ``inner_products`` : float64 (n,), :func:`inner_products_with` of `index`.
        ``depths_mm`` : float64 (n,) or None, as given.

    Raises
    ------
    ReconInputError
        If `stack` is invalid, `depths_mm` does not hold n distinct positive finite
        depths, or `index` is outside the stack.

    Notes
    -----
    The autocorrelation lines are computed without the full 2D correlation: the
    central row of ``sum_u h[u] h[u + t]`` is the inverse FFT of the row power
    spectra summed over rows (zero-padded to ``2 cols - 1`` and beyond), one 1D FFT
    per row. Fig. A.3a shows these lines for the nearest and farthest PSF with
    their cross-correlation: a sharp central peak, side lobes near 0.5, and a
    cross-correlation below 0.5 means any shift of one depth's caustics is unlike
    the other depth's.
    """
    s = check_stack(stack)
    n, rows, cols = s.shape
    z = None
    if depths_mm is not None:
        z = float_array(depths_mm, "depths_mm", ndims=(1,))
        if z.size != n:
            raise ReconInputError(
                f"depths_mm has {z.size} values but the stack holds {n} PSFs; pass one "
                "depth per PSF"
            )
        if np.any(z <= 0) or np.unique(z).size != n:
            raise ReconInputError(
                "depths_mm must be positive and distinct (object-to-diffuser distances in mm)"
            )
        nearest, farthest = int(np.argmin(z)), int(np.argmax(z))
    else:
        nearest, farthest = 0, n - 1
    i = n // 2 if index is None else _index(index, n)
    auto_x = np.stack([_central_line(s[k], axis=1) for k in range(n)])
    auto_y = np.stack([_central_line(s[k], axis=0) for k in range(n)])
    cc = cross_correlation(s[nearest], s[farthest])
    peak = np.unravel_index(int(np.argmax(cc)), cc.shape)
    return {
        "lags_x_px": np.arange(-(cols - 1), cols, dtype=np.float64),
        "lags_y_px": np.arange(-(rows - 1), rows, dtype=np.float64),
        "autocorrelation_x": auto_x,
        "autocorrelation_y": auto_y,
        "nearest": nearest,
        "farthest": farthest,
        "cross_correlation_max": float(cc[peak]),
        "cross_correlation_argmax_px": (int(peak[0]) - (rows - 1), int(peak[1]) - (cols - 1)),
        "cross_correlation_x": np.ascontiguousarray(cc[rows - 1]),
        "index": i,
        "inner_products": inner_products_with(s, i),
        "depths_mm": z,
    }

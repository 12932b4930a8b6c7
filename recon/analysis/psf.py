"""PSF measurements: DCT background removal, similarity, registration, border energy.

Plain numpy/scipy functions on calibration images, following G. Kuo, *Exploiting
Randomness in Computational Cameras and Displays* (PhD dissertation, UC Berkeley,
2020):

- :func:`remove_background_dct` -- Sec. 6.2/6.4: zero the lowest DCT coefficients of
  a calibration image to remove background light, then clip negatives.
- :func:`inner_product` -- the normalised inner product ("similarity", Eq. 3.11;
  the resolution predictor of Sec. 6.4).
- :func:`normalized_correlation` -- Pearson correlation of the pixels.
- :func:`register_shift` -- the translation maximising the cross-correlation with
  a reference PSF (Sec. 5.2, the registration of Eq. 5.2).
- :func:`border_energy_fraction` -- how much of a PSF falls near the image edge,
  i.e. whether the PSF fits on the sensor (App. A.2).

Every refusal raises :class:`recon.errors.ReconInputError` whose message says what
is wrong and how to fix it. Results are float64.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import scipy.fft

from recon.errors import ReconInputError
from recon.validate import as_int, float_array

__all__ = [
    "border_energy_fraction",
    "inner_product",
    "normalized_correlation",
    "register_shift",
    "remove_background_dct",
]


# ----------------------------------------------------------------------------- helpers


def _same_shape(a: np.ndarray, b: np.ndarray, name_a: str, name_b: str) -> None:
    if a.shape != b.shape:
        raise ReconInputError(
            f"{name_a} has shape {a.shape} but {name_b} has shape {b.shape}; crop or "
            "resample them to the same shape"
        )


# ----------------------------------------------------------------------------- functions


def remove_background_dct(
    image: Any, n_low: int | tuple[int, int] = 5, *, clip_negative: bool = True
) -> np.ndarray:
    """Remove slowly varying background light by zeroing the lowest DCT coefficients.

    Parameters
    ----------
    image : array_like
        Shape (rows, cols) or a stack (n, rows, cols), real numeric dtype, any
        intensity units (e.g. sensor counts). Each frame is processed separately.
    n_low : int or tuple of int, optional
        Size of the low-frequency block of DCT coefficients set to zero: an int for
        an ``n_low x n_low`` block, or a ``(ny, nx)`` pair. Default 5 (the "5 x 5
        lowest frequency components" of Sec. 6.2; Sec. 6.4 used 10 x 10 for the
        calibration images). ``n_low=1`` removes exactly the mean of each frame.
    clip_negative : bool, optional
        If True (default), set negative values after subtraction to 0, as done for
        the calibration images of Sec. 6.4.

    Returns
    -------
    numpy.ndarray
        float64, same shape as `image`, in the units of `image`.

    Raises
    ------
    ReconInputError
        If `image` is not a non-empty numeric 2D/3D array, contains NaN/inf, or if
        `n_low` is not a positive int or pair of ints, or is larger than the frame.

    Notes
    -----
    Implements ``b' = D^-1 (m * D b)`` with ``D`` the orthonormal 2D DCT-II
    (:func:`scipy.fft.dctn`, ``norm="ortho"``, axes (-2, -1)) and ``m`` a mask that
    is 0 on the ``ny x nx`` lowest-frequency coefficients and 1 elsewhere; this is
    the background model of Eq. 6.2 (``D g = 0`` outside a low-frequency support)
    applied as a one-shot high-pass, as in Sec. 6.4 ("the lowest frequency
    10 x 10 DCT coefficients were set to zero ... Negative values after background
    subtraction were set to zero").
    """
    img = float_array(image, "image", ndims=(2, 3))
    rows, cols = img.shape[-2:]
    if isinstance(n_low, tuple | list):
        if len(n_low) != 2:
            raise ReconInputError(
                f"n_low must be an int or a (ny, nx) pair, got {n_low!r}; e.g. 5 or (5, 5)"
            )
        ny = as_int(n_low[0], "n_low[0]")
        nx = as_int(n_low[1], "n_low[1]")
    else:
        ny = nx = as_int(n_low, "n_low")
    if ny > rows or nx > cols:
        raise ReconInputError(
            f"n_low ({ny}, {nx}) is larger than the image frame ({rows}, {cols}); "
            "choose a smaller block, e.g. 5 or 10"
        )
    coeffs = scipy.fft.dctn(img, type=2, norm="ortho", axes=(-2, -1), workers=os.cpu_count())
    coeffs[..., :ny, :nx] = 0.0
    out = scipy.fft.idctn(coeffs, type=2, norm="ortho", axes=(-2, -1), workers=os.cpu_count())
    if clip_negative:
        np.maximum(out, 0.0, out=out)
    return out


def inner_product(a: Any, b: Any) -> float:
    """Normalised inner product ``<a, b> / (|a| |b|)`` of two images (not mean-subtracted).

    Parameters
    ----------
    a, b : array_like
        Real numeric arrays of the same shape (any rank), e.g. two PSFs (rows, cols).

    Returns
    -------
    float
        In [-1, 1]; 1 for identical (up to a positive factor) images, 0 for images
        on disjoint pixels. Computed in float64.

    Raises
    ------
    ReconInputError
        If the shapes differ, an array is empty, non-numeric or non-finite, or
        either image is all zero (the normalisation is undefined).

    Notes
    -----
    The similarity ``mu`` of Eq. 3.11 (Sec. 3.2) for normalised PSFs, and the
    "normalized inner product" resolution predictor of Sec. 6.4 (points resolvable
    when it falls below 0.8). No mean is subtracted: a dark background counts as
    zero, a bright pedestal raises the value (Sec. 6.3).
    """
    a_ = float_array(a, "a", ndims=None)
    b_ = float_array(b, "b", ndims=None)
    _same_shape(a_, b_, "a", "b")
    na = float(np.linalg.norm(a_.ravel()))
    nb = float(np.linalg.norm(b_.ravel()))
    if na == 0.0 or nb == 0.0:
        which = "a" if na == 0.0 else "b"
        raise ReconInputError(
            f"{which} is all zero, so the normalised inner product is undefined; pass an "
            "image with signal (check exposure and background removal)"
        )
    return float(np.dot(a_.ravel(), b_.ravel()) / (na * nb))


def normalized_correlation(a: Any, b: Any) -> float:
    """Zero-mean normalised cross-correlation at zero shift (Pearson r of the pixels).

    Parameters
    ----------
    a, b : array_like
        Real numeric arrays of the same shape (any rank).

    Returns
    -------
    float
        ``<a - mean(a), b - mean(b)> / (|a - mean(a)| |b - mean(b)|)`` in [-1, 1].

    Raises
    ------
    ReconInputError
        If the shapes differ, an array is empty, non-numeric or non-finite, or
        either image is constant (zero variance).

    Notes
    -----
    Unlike :func:`inner_product`, a uniform pedestal (background light, dark level)
    does not change the result.
    """
    a_ = float_array(a, "a", ndims=None)
    b_ = float_array(b, "b", ndims=None)
    _same_shape(a_, b_, "a", "b")
    a0 = (a_ - a_.mean()).ravel()
    b0 = (b_ - b_.mean()).ravel()
    na = float(np.linalg.norm(a0))
    nb = float(np.linalg.norm(b0))
    if na == 0.0 or nb == 0.0:
        which = "a" if na == 0.0 else "b"
        raise ReconInputError(
            f"{which} is constant (zero variance), so the correlation is undefined; pass an "
            "image with structure (check exposure and that the source is in view)"
        )
    return float(np.dot(a0, b0) / (na * nb))


def register_shift(reference: Any, image: Any, *, upsample: int = 20) -> tuple[float, float]:
    """Translation of `image` relative to `reference` that maximises their cross-correlation.

    Parameters
    ----------
    reference : array_like
        Shape (rows, cols), real numeric, e.g. the on-axis (central) PSF.
    image : array_like
        Shape (rows, cols), same shape as `reference`, e.g. an off-axis PSF.
    upsample : int, optional
        Sub-pixel precision is ``1 / upsample`` pixel (DFT upsampling of the
        correlation peak, Guizar-Sicairos et al. 2008). Default 20.

    Returns
    -------
    tuple of float
        ``(dy, dx)`` in pixels (rows, cols) such that ``image`` is approximately
        ``reference`` shifted by ``(+dy, +dx)``: ``image[r, c] ~ reference[r - dy, c - dx]``
        (the convention of ``scipy.ndimage.shift(reference, (dy, dx))`` and, for
        whole pixels, ``np.roll(reference, (dy, dx), axis=(0, 1))``). Both lie in
        ``[-rows, rows)`` and ``[-cols, cols)``.

    Raises
    ------
    ReconInputError
        If the inputs are not 2D, differ in shape, are non-finite or all zero, or
        `upsample` is not an integer >= 1.

    Notes
    -----
    Sec. 5.2: "we calculate Delta u_i by determining the translation that maximizes
    the cross-correlation with this central PSF", the shift used by the registration
    of Eq. 5.2. Implemented with :func:`skimage.registration.phase_cross_correlation`
    with ``normalization=None`` (plain, not phase, correlation) after zero-padding
    both images to twice their size, so large shifts do not wrap around.
    Because the correlation is not mean-subtracted, remove background light first
    (e.g. :func:`remove_background_dct`): a uniform pedestal biases the peak towards
    zero shift.
    """
    from skimage.registration import phase_cross_correlation

    ref = float_array(reference, "reference")
    img = float_array(image, "image")
    _same_shape(ref, img, "reference", "image")
    upsample = as_int(upsample, "upsample")
    for name, arr in (("reference", ref), ("image", img)):
        if not np.any(arr):
            raise ReconInputError(
                f"{name} is all zero, so there is nothing to register; pass an image with "
                "signal (check exposure and background removal)"
            )
    pad = ((0, ref.shape[0]), (0, ref.shape[1]))
    shift, _, _ = phase_cross_correlation(
        np.pad(ref, pad), np.pad(img, pad), normalization=None, upsample_factor=upsample
    )
    # skimage returns the shift that registers the moving image (here `image`) onto
    # the reference, i.e. minus the displacement of `image` relative to `reference`.
    dy, dx = (-float(s) for s in shift)
    return (dy + 0.0, dx + 0.0)  # + 0.0 turns -0.0 into 0.0


def border_energy_fraction(psf: Any, border_px: int) -> float:
    """Fraction of a PSF's energy within `border_px` pixels of the image edge.

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), real, non-negative intensities (e.g. after
        :func:`remove_background_dct` with ``clip_negative=True``).
    border_px : int
        Width in pixels of the frame along all four edges; 0 gives 0.0, and a
        border covering the whole image gives 1.0.

    Returns
    -------
    float
        ``sum(psf[border]) / sum(psf)`` in [0, 1]. Near 0 means the PSF fits on the
        sensor; a large value means part of the caustic pattern is probably cut
        off by the sensor edge (move the source further away or add an aperture).

    Raises
    ------
    ReconInputError
        If `psf` is not a finite 2D array, has negative values or zero total, or
        `border_px` is not an integer >= 0.

    Notes
    -----
    Used to check the condition of Sec. 4.4 / App. A.2 that the whole PSF is
    captured in each calibration image (the aperture makes caustics from the
    nearest source just fill the sensor). "Energy" is the summed intensity.
    """
    h = float_array(psf, "psf")
    border = as_int(border_px, "border_px", minimum=0)
    if np.any(h < 0):
        raise ReconInputError(
            "psf has negative values; clip them first (np.clip(psf, 0, None) or "
            "remove_background_dct(..., clip_negative=True))"
        )
    total = float(h.sum())
    if total <= 0.0:
        raise ReconInputError(
            "psf is all zero; pass a PSF with signal (check exposure and background removal)"
        )
    rows, cols = h.shape
    if 2 * border >= rows or 2 * border >= cols:
        return 1.0
    interior = float(h[border : rows - border, border : cols - border].sum())
    return float(min(max((total - interior) / total, 0.0), 1.0))

"""Image quality metrics for reconstructions against a known truth.

A lensless reconstruction is only defined up to a global scale: the solvers work
with a PSF normalised to unit sum and a measurement divided by its maximum, so the
estimate's brightness depends on those normalisations (and on exposure, gain and
the PSF's calibration brightness), not on the scene. Both metrics therefore first
fit the estimate to the truth with a single least-squares gain,
``g = <estimate, truth> / <estimate, estimate>``, and then compare ``g * estimate``
with the truth using :mod:`skimage.metrics` with ``data_range`` taken from the
truth (``truth.max() - truth.min()``). Only the gain is fitted (no offset), so a
background bias still counts as error.
"""

from __future__ import annotations

import numpy as np

from .errors import ReconInputError

__all__ = ["fit_gain", "psnr", "register_truth", "ssim"]


def _pair(estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e = np.asarray(estimate, dtype=np.float64)
    t = np.asarray(truth, dtype=np.float64)
    if e.ndim != 2 or t.ndim != 2:
        raise ReconInputError(
            f"metrics need 2D images, got shapes {e.shape} and {t.shape}; compare "
            "x[op.crop] with truth[op.crop]"
        )
    if e.shape != t.shape:
        raise ReconInputError(f"estimate shape {e.shape} differs from truth shape {t.shape}")
    if not (np.all(np.isfinite(e)) and np.all(np.isfinite(t))):
        raise ReconInputError("estimate or truth contains NaN/inf")
    return e, t


def _range(t: np.ndarray) -> float:
    data_range = float(t.max() - t.min())
    if not data_range > 0:
        raise ReconInputError("the truth is constant (data range 0): PSNR/SSIM undefined")
    return data_range


def fit_gain(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Least-squares gain ``g`` minimising ``||g * estimate - truth||^2``.

    Parameters
    ----------
    estimate, truth : numpy.ndarray
        2D float images of the same shape.

    Returns
    -------
    float
        ``<estimate, truth> / <estimate, estimate>``; 0 for an all-zero estimate.
    """
    e, t = _pair(estimate, truth)
    den = float(np.vdot(e, e))
    return float(np.vdot(e, t)) / den if den > 0 else 0.0


def psnr(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Peak signal-to-noise ratio (dB) after a least-squares gain fit.

    Parameters
    ----------
    estimate : numpy.ndarray
        2D float image, e.g. ``x[op.crop]`` of a reconstruction (any global scale).
    truth : numpy.ndarray
        2D float image of the same shape; its range sets ``data_range``.

    Returns
    -------
    float
        :func:`skimage.metrics.peak_signal_noise_ratio` of ``fit_gain(estimate,
        truth) * estimate`` against ``truth``; ``inf`` when they agree exactly.

    Raises
    ------
    ReconInputError
        Non-2D or mismatched inputs, NaN/inf, or a constant truth.

    Notes
    -----
    The gain fit makes the metric invariant to the estimate's global scale (see the
    module docstring); it is not invariant to an offset.

    Examples
    --------
    >>> import numpy as np
    >>> from recon.metrics import psnr
    >>> truth = np.linspace(0, 1, 64 * 64).reshape(64, 64)
    >>> psnr(3.0 * truth, truth) > 300  # a global gain is fitted out (rounding only)
    True
    >>> noisy = truth + 0.01 * np.random.default_rng(0).standard_normal(truth.shape)
    >>> 39 < psnr(noisy, truth) < 41  # noise of 1 % of the range: 40 dB
    True
    """
    from skimage.metrics import peak_signal_noise_ratio

    e, t = _pair(estimate, truth)
    data_range = _range(t)
    g = fit_gain(e, t)
    if np.array_equal(g * e, t):
        return float("inf")
    return float(peak_signal_noise_ratio(t, g * e, data_range=data_range))


def register_truth(estimate: np.ndarray, truth: np.ndarray, max_shift: int = 2
                   ) -> tuple[tuple[int, int], np.ndarray]:
    """The integer shift of ``truth`` that best matches ``estimate`` (highest
    :func:`psnr`), for scoring a reconstruction whose object grid may sit half a pixel
    or a pixel off the truth's (the centring of an even-sized grid).

    Parameters
    ----------
    estimate, truth : ndarray, 2D, same shape
    max_shift : int
        Largest shift tried along each axis, px (>= 0).

    Returns
    -------
    shift : (dy, dx)
        The circular shift applied to ``truth`` (:func:`numpy.roll`).
    shifted : ndarray
        ``truth`` shifted by it.

    Raises
    ------
    ReconInputError
        As :func:`psnr`.
    """
    best = None
    for dy in range(-max_shift, max_shift + 1):
        for dx in range(-max_shift, max_shift + 1):
            t = np.roll(truth, (dy, dx), axis=(0, 1))
            score = psnr(estimate, t)
            if best is None or score > best[0]:
                best = (score, (dy, dx), t)
    return best[1], best[2]


def ssim(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Structural similarity after a least-squares gain fit.

    Parameters
    ----------
    estimate : numpy.ndarray
        2D float image (any global scale), at least 7 x 7.
    truth : numpy.ndarray
        2D float image of the same shape; its range sets ``data_range``.

    Returns
    -------
    float
        :func:`skimage.metrics.structural_similarity` (default 7 x 7 window) of
        ``fit_gain(estimate, truth) * estimate`` against ``truth``; 1 for identical
        images.

    Raises
    ------
    ReconInputError
        Non-2D or mismatched inputs, NaN/inf, a constant truth, or an image
        smaller than the 7 x 7 window.

    Examples
    --------
    >>> import numpy as np
    >>> from recon.metrics import ssim
    >>> truth = np.add.outer(np.sin(np.arange(32) / 3.0), np.cos(np.arange(32) / 5.0))
    >>> round(ssim(2.0 * truth, truth), 6)
    1.0
    """
    from skimage.metrics import structural_similarity

    e, t = _pair(estimate, truth)
    data_range = _range(t)
    if min(t.shape) < 7:
        raise ReconInputError(f"SSIM needs images of at least 7x7, got {t.shape}")
    g = fit_gain(e, t)
    return float(structural_similarity(t, g * e, data_range=data_range))

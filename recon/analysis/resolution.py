"""Resolution from a PSF: autocorrelation width, inner-product predictor, depth of field.

Following G. Kuo, *Exploiting Randomness in Computational Cameras and Displays*
(PhD dissertation, UC Berkeley, 2020):

- :func:`autocorrelation` -- normalised PSF autocorrelation, the similarity
  ``mu(Delta x)`` of Eq. 3.11 for a shift-invariant system (Sec. 3.2).
- :func:`lateral_resolution_px` -- half width of the autocorrelation peak at 70 %
  of its maximum along x and y (Sec. 3.2, "a good predictor of resolution"), and
  :func:`lateral_resolution_object_mm` / :func:`lateral_resolution_deg` to convert
  it to object space with the magnification ``m = d/z``.
- :func:`lateral_inner_product_resolution_px` and :func:`axial_inner_product_scale`
  -- the Sec. 6.4 predictor (Fig. 6.4): the shift / scale of a PSF at which its
  normalised inner product with the original falls to 0.8.
- :func:`hyperfocal_distance_mm` and :func:`depth_of_field_mm` -- the depth of
  field of Sec. 3.2 (Fig. 3.4b) from the depth sensitivity of one PSF.

Lags and shifts are in sensor pixels, distances in mm. PSFs should be
background-removed (:func:`~recon.analysis.psf.remove_background_dct`): the
correlations are not mean-subtracted, so a pedestal widens every peak. Every refusal
raises :class:`recon.errors.ReconInputError` whose message says what is wrong and
how to fix it. Results are float64.
"""

from __future__ import annotations

import math
import numbers
from typing import Any, NamedTuple

import numpy as np
import scipy.optimize

from recon.analysis.sampling import inverse_depth_step_per_mm, scale_at_threshold
from recon.analysis.similarity import check_image, full_xcorr, line_spectrum
from recon.errors import ReconInputError
from recon.validate import float_array, positive

__all__ = [
    "LateralResolution",
    "autocorrelation",
    "axial_inner_product_scale",
    "depth_of_field_mm",
    "hyperfocal_distance_mm",
    "lateral_inner_product_resolution_px",
    "lateral_resolution_deg",
    "lateral_resolution_object_mm",
    "lateral_resolution_px",
]

#: Autocorrelation level that defines the resolution (Sec. 3.2).
RESOLUTION_LEVEL = 0.7

#: Inner-product threshold below which two points are resolvable (Sec. 6.4).
INNER_PRODUCT_THRESHOLD = 0.8


class LateralResolution(NamedTuple):
    """A width along the sensor's x (columns) and y (rows) axes, in pixels."""

    x_px: float
    y_px: float


def check_level(value: Any, name: str) -> float:
    """A correlation threshold level: a real number strictly between 0 and 1, as float.

    Raises
    ------
    ReconInputError
        Not a real number (bools refused) or outside (0, 1).
    """
    if (
        isinstance(value, bool)
        or not isinstance(value, numbers.Real)
        or not (0.0 < float(value) < 1.0)
    ):
        raise ReconInputError(f"{name} must be in (0, 1), got {value!r}; e.g. 0.7 or 0.8")
    return float(value)


def crossing_lag(h: np.ndarray, axis: int, level: float) -> float:
    """First lag > 0 at which the normalised autocorrelation along `axis` falls to `level`.

    The autocorrelation between integer lags is the band-limited (trigonometric)
    interpolation of its integer-lag samples, which is exactly the normalised inner
    product of ``h`` with a Fourier-shifted copy of itself on a zero-padded frame.
    """
    power, n = line_spectrum(h, axis)
    weights = np.full(power.size, 2.0)
    weights[0] = 1.0
    if n % 2 == 0:
        weights[-1] = 1.0
    wp = weights * power
    total = float(wp.sum())
    freq = 2.0 * np.pi * np.arange(power.size) / n

    def mu(t: float) -> float:
        return float(np.dot(wp, np.cos(freq * t))) / total

    length = h.shape[axis]
    line = np.fft.irfft(power, n=n)[:length]
    line = line / line[0]
    below = np.flatnonzero(line[1:] <= level)
    if below.size == 0:
        name = "x" if axis == 1 else "y"
        raise ReconInputError(
            f"the PSF autocorrelation along {name} stays above {level} for every shift up to "
            f"{length - 1} px; the PSF has no fine structure at this level -- remove the "
            "background (remove_background_dct), check focus and exposure, or lower the level"
        )
    j = int(below[0]) + 1
    if mu(float(j)) == level:
        return float(j)
    return float(scipy.optimize.brentq(lambda t: mu(t) - level, j - 1.0, float(j), xtol=1e-10))


# ----------------------------------------------------------------------------- lateral


def autocorrelation(psf: Any) -> np.ndarray:
    """Normalised autocorrelation of a PSF, peak 1 at the centre.

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), real, finite, not all zero; background removed.

    Returns
    -------
    numpy.ndarray
        float64, shape (2 rows - 1, 2 cols - 1):
        ``A[dy + rows - 1, dx + cols - 1] = sum_u h[u] h[u + (dy, dx)] / sum_u h[u]^2``,
        the linear autocorrelation (zero outside the frame) for every lag; its
        maximum 1 is at the centre ``(rows - 1, cols - 1)`` and ``A`` is symmetric
        under ``(dy, dx) -> (-dy, -dx)``.

    Raises
    ------
    ReconInputError
        If `psf` is not a finite 2D array or is all zero.

    Notes
    -----
    Sec. 3.2: for a shift-invariant system the similarity of two point sources
    ``Delta x`` apart, ``mu(Delta x) = <h0(u), h0(u + m Delta x)>`` (Eq. 3.11), is
    the autocorrelation of the PSF at lag ``m Delta x``. Computed with real FFTs
    zero-padded to at least ``(2 rows - 1, 2 cols - 1)`` (no wrap-around), as
    :func:`~recon.analysis.similarity.cross_correlation` of the PSF with itself.
    """
    h = check_image(psf, "psf")
    return full_xcorr(h, h) / float(np.sum(h * h))


def lateral_resolution_px(psf: Any, level: float = RESOLUTION_LEVEL) -> LateralResolution:
    """Half width of the autocorrelation peak at `level` of its maximum, along x and y.

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), real, finite, not all zero; background removed.
    level : float, optional
        Fraction of the peak in (0, 1). Default 0.7 (Sec. 3.2).

    Returns
    -------
    LateralResolution
        ``(x_px, y_px)``: the smallest lag ``t > 0`` (sensor pixels, sub-pixel) at
        which the central row (x, zero y lag) / central column (y) of
        :func:`autocorrelation` falls to `level`. Example: a Gaussian PSF of
        standard deviation ``s`` px has a Gaussian autocorrelation of standard
        deviation ``s sqrt(2)``, so the 70 % half width is
        ``s sqrt(2) sqrt(2 ln(1/0.7))`` = 1.1945 s.

    Raises
    ------
    ReconInputError
        If `psf` is invalid, `level` is not in (0, 1), or the autocorrelation never
        falls to `level` inside the frame.

    Notes
    -----
    Sec. 3.2: "the autocorrelation half-width at 70 % of maximum is a good predictor
    of resolution". The central lines are computed from 1D FFTs (row power spectra
    summed over rows) and the crossing is found between the integer lags that
    bracket it with Brent's method on the band-limited interpolation of the line.
    Convert to object space with :func:`lateral_resolution_object_mm`.
    """
    h = check_image(psf, "psf")
    lev = check_level(level, "level")
    return LateralResolution(x_px=crossing_lag(h, 1, lev), y_px=crossing_lag(h, 0, lev))


def lateral_inner_product_resolution_px(
    psf: Any, threshold: float = INNER_PRODUCT_THRESHOLD
) -> LateralResolution:
    """Shift at which the inner product of a PSF with its shifted copy falls to `threshold`.

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), real, finite, not all zero; background removed.
    threshold : float, optional
        Normalised inner product below which two points are resolvable, in (0, 1).
        Default 0.8 (Sec. 6.4).

    Returns
    -------
    LateralResolution
        ``(x_px, y_px)``: the smallest shift ``t > 0`` in sensor pixels (sub-pixel)
        along x (columns) / y (rows) with
        ``<h, h(. + t)> / (|h| |h(. + t)|) = threshold``.

    Raises
    ------
    ReconInputError
        As :func:`lateral_resolution_px`.

    Notes
    -----
    Sec. 6.4 (Fig. 6.4a): "we shift ... a central PSF and calculate the inner
    product with the original ... a normalized inner product of 0.8 is a good
    predictor of the resolution". The shift is made on a frame zero-padded to
    ``2 n - 1``, so the shifted copy keeps all its energy and the inner product
    equals the normalised autocorrelation at that lag; fractional shifts are
    Fourier (band-limited) shifts. It is therefore :func:`lateral_resolution_px`
    at ``level = threshold``; at integer shifts it equals
    :func:`~recon.analysis.psf.inner_product` of the zero-padded PSF and its
    ``np.roll``-ed copy.
    """
    h = check_image(psf, "psf")
    thr = check_level(threshold, "threshold")
    return LateralResolution(x_px=crossing_lag(h, 1, thr), y_px=crossing_lag(h, 0, thr))


def lateral_resolution_object_mm(res_px: Any, pitch_mm: float, d_mm: float, z_mm: Any) -> Any:
    """Convert a sensor-plane resolution in pixels to object space with ``m = d/z``.

    Parameters
    ----------
    res_px : float or array_like
        Resolution on the sensor in pixels (e.g. a :class:`LateralResolution`, or
        one of its fields), >= 0.
    pitch_mm : float
        Sensor pixel pitch in mm (> 0), e.g. 0.0065 for 6.5 um pixels (after any
        binning: multiply by the bin factor).
    d_mm : float
        Diffuser-to-sensor distance in mm (> 0).
    z_mm : float or array_like
        Object-to-diffuser distance(s) in mm (> 0).

    Returns
    -------
    float or numpy.ndarray
        ``res_px * pitch_mm * z_mm / d_mm`` in mm, broadcast over `res_px` and
        `z_mm` (a float when both are scalars). Example: 2 px of 5 um at
        ``d = 5 mm``, ``z = 20 mm`` is 0.04 mm.

    Raises
    ------
    ReconInputError
        If a value is not finite, `res_px` is negative, or another is not positive.

    Notes
    -----
    A point source moved by ``Delta x`` at depth ``z`` translates the caustic
    pattern on the sensor by ``m Delta x`` with ``m = d/z`` (Sec. 3.2, Eq. 3.11's
    rewrite ``<h0(u), h0(u + m Delta x)>``), so an object-space size is the
    sensor-plane size times ``z / d``; the lateral resolution grows linearly with
    depth (Sec. 4.4).
    """
    r = float_array(res_px, "res_px", ndims=None)
    if np.any(r < 0):
        raise ReconInputError("res_px must be >= 0 (a width in pixels)")
    p = positive(pitch_mm, "pitch_mm", unit=" mm")
    d = positive(d_mm, "d_mm", unit=" mm")
    z = float_array(z_mm, "z_mm", ndims=None)
    if np.any(z <= 0):
        raise ReconInputError("z_mm must be > 0 (object-to-diffuser distance in mm)")
    out = r * p * z / d
    return float(out) if out.ndim == 0 else out


def lateral_resolution_deg(res_px: Any, pitch_mm: float, d_mm: float) -> Any:
    """Angular resolution ``atan(res_px * pitch / d)`` in degrees (independent of depth).

    Parameters
    ----------
    res_px : float or array_like
        Resolution on the sensor in pixels (>= 0).
    pitch_mm, d_mm : float
        Pixel pitch and diffuser-to-sensor distance in mm (> 0).

    Returns
    -------
    float or numpy.ndarray
        Degrees; Sec. 3.3 quotes 0.16 deg for both prototypes.

    Raises
    ------
    ReconInputError
        If a value is not finite, `res_px` is negative, or another is not positive.
    """
    r = float_array(res_px, "res_px", ndims=None)
    if np.any(r < 0):
        raise ReconInputError("res_px must be >= 0 (a width in pixels)")
    p = positive(pitch_mm, "pitch_mm", unit=" mm")
    d = positive(d_mm, "d_mm", unit=" mm")
    out = np.degrees(np.arctan(r * p / d))
    return float(out) if out.ndim == 0 else out


# ----------------------------------------------------------------------------- axial


def axial_inner_product_scale(
    psf: Any, threshold: float = INNER_PRODUCT_THRESHOLD, *, max_scale: float = 2.0
) -> float:
    """Scale ``s* > 1`` at which the inner product of a PSF with its scaled copy is `threshold`.

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), background-removed PSF centred on the array.
    threshold : float, optional
        In (0, 1). Default 0.8 (Sec. 6.4).
    max_scale : float, optional
        Largest scale searched (> 1). Default 2.

    Returns
    -------
    float
        ``s*`` (dimensionless), from :func:`~recon.analysis.sampling.scale_at_threshold`.

    Raises
    ------
    ReconInputError
        As :func:`~recon.analysis.sampling.scale_at_threshold`.

    Notes
    -----
    The axial half of the Sec. 6.4 predictor: "we ... scale (for axial resolution)
    a central PSF and calculate the inner product with the original". Two depths
    ``z1 < z2`` are resolvable when ``(1 + d/z1) / (1 + d/z2) >= s*``; see
    :func:`~recon.analysis.sampling.inverse_depth_step_per_mm` for the 1/z step.
    """
    return scale_at_threshold(psf, threshold, max_scale=max_scale)


def _s_star_minus_one(psf: Any, d: float, psf_z: float, threshold: float) -> float:
    # inverse_depth_step_per_mm returns c = (s* - 1)(1/d + 1/z_psf); invert it.
    c = inverse_depth_step_per_mm(psf, d, psf_z, threshold)
    return c / (1.0 / d + 1.0 / psf_z)


def hyperfocal_distance_mm(
    psf: Any, *, d_mm: float, psf_z_mm: float, threshold: float = INNER_PRODUCT_THRESHOLD
) -> float:
    """Hyperfocal distance: beyond it no depth can be told from infinity (Sec. 3.2, 4.4).

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), background-removed on-axis PSF centred on the array.
    d_mm : float
        Diffuser-to-sensor distance in mm (> 0).
    psf_z_mm : float
        Depth at which `psf` was measured, mm (> 0).
    threshold : float, optional
        Inner-product threshold of distinguishability, in (0, 1). Default 0.8.

    Returns
    -------
    float
        ``z_H = (1 + d/z_psf) / c = d / (s* - 1)`` in mm.

    Raises
    ------
    ReconInputError
        As :func:`~recon.analysis.sampling.inverse_depth_step_per_mm`.

    Notes
    -----
    Derivation. The caustics of a point at depth ``z`` are the pattern at infinity
    magnified by ``u(z) = 1 + d/z`` (Fig. 4.2, Eq. 5.2), so two depths are told apart
    when the ratio of their ``u`` reaches ``s*``, the scale at which the PSF's inner
    product with its scaled copy falls to `threshold`
    (:func:`~recon.analysis.sampling.scale_at_threshold`). Moving away from a depth
    ``z``, the nearest distinguishable farther depth ``z_f`` has
    ``1 + d/z_f = (1 + d/z) / s*``, i.e. the 1/z step needed to be distinguishable is
    ``1/z - 1/z_f``. That step reaches ``1/z`` itself (``z_f`` at infinity) when
    ``1 + d/z = s*``, so ``z_H = d / (s* - 1)``; beyond ``z_H`` every farther depth,
    infinity included, looks the same. With
    :func:`~recon.analysis.sampling.inverse_depth_step_per_mm`'s
    ``c = (s* - 1)(1/d + 1/z_psf)`` (the 1/z step at the measured depth, Eq. 4.7)
    this is ``z_H = (1 + d/z_psf) / c``. Example: Sec. 3.3's PCO prototype
    (``d = 8.8`` mm, hyperfocal 2929 mm) corresponds to ``s* - 1 = 0.0030``.
    """
    d = positive(d_mm, "d_mm", unit=" mm")
    z = positive(psf_z_mm, "psf_z_mm", unit=" mm")
    return d / _s_star_minus_one(psf, d, z, threshold)


def depth_of_field_mm(
    psf: Any,
    z_mm: Any,
    *,
    d_mm: float,
    psf_z_mm: float,
    threshold: float = INNER_PRODUCT_THRESHOLD,
    side: str = "far",
) -> np.ndarray:
    """Smallest detectable axial separation at each depth (the DoF of Sec. 3.2, Fig. 3.4b).

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), background-removed on-axis PSF centred on the array.
    z_mm : float or array_like
        Depths (object-to-diffuser, mm, > 0) at which to evaluate the DoF.
    d_mm, psf_z_mm : float
        Diffuser-to-sensor distance, and the depth at which `psf` was measured, in mm
        (> 0), as in :func:`hyperfocal_distance_mm`.
    threshold : float, optional
        Inner-product threshold of distinguishability, in (0, 1). Default 0.8.
    side : {"far", "near"}, optional
        ``"far"`` (default): ``z_f - z`` to the nearest distinguishable farther
        depth, ``inf`` at and beyond the hyperfocal distance. ``"near"``:
        ``z - z_n`` to the nearest distinguishable nearer depth (always finite,
        smaller than the far-side value).

    Returns
    -------
    numpy.ndarray
        float64, shape of ``np.atleast_1d(z_mm)``, in mm.

    Raises
    ------
    ReconInputError
        If an input is invalid (see :func:`hyperfocal_distance_mm`) or `side` is
        not "far" or "near".

    Notes
    -----
    With ``u(z) = 1 + d/z`` and ``s*`` as in :func:`hyperfocal_distance_mm`:
    ``1 + d/z_f = u / s*`` (``z_f = inf`` when ``u <= s*``) and
    ``1 + d/z_n = s* u``. Because the DoF grows roughly as ``z^2`` (the 1/z step is
    nearly constant, Eq. 4.7), depth planes belong on a grid uniform in 1/z
    (:func:`~recon.analysis.sampling.inverse_depths`).
    """
    if side not in ("far", "near"):
        raise ReconInputError(f"side must be 'far' or 'near', got {side!r}")
    d = positive(d_mm, "d_mm", unit=" mm")
    zp = positive(psf_z_mm, "psf_z_mm", unit=" mm")
    z = np.atleast_1d(float_array(z_mm, "z_mm", ndims=(0, 1)))
    if np.any(z <= 0):
        raise ReconInputError("z_mm must be > 0 (object-to-diffuser distances in mm)")
    s_star = 1.0 + _s_star_minus_one(psf, d, zp, threshold)
    u = 1.0 + d / z
    if side == "near":
        return z - d / (s_star * u - 1.0)
    out = np.full(z.shape, math.inf)
    finite = u / s_star > 1.0
    out[finite] = d / (u[finite] / s_star - 1.0) - z[finite]
    return out

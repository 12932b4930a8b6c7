"""Sensor angular response: Gaussian fall-off fit and angular field of view.

Following G. Kuo, *Exploiting Randomness in Computational Cameras and Displays*
(PhD dissertation, UC Berkeley, 2020):

- :func:`fit_gaussian_falloff` -- fit the pixel angular response measured by
  moving a calibration source (Fig. 3.5, Fig. 4.3b, Fig. 5.3a: "fit to a Gaussian
  curve with sigma = 13 deg") and report the 20 % angular cutoff ``alpha_c``.
- :func:`fov_half_angle_deg` -- the angular half field of view (Eq. 3.12 / Eq. 4.6).

Angles are in degrees. Every refusal raises :class:`recon.errors.ReconInputError`
whose message says what is wrong and how to fix it.
"""

from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize

from recon.errors import ReconInputError
from recon.validate import float_array

__all__ = ["FalloffFit", "fit_gaussian_falloff", "fov_half_angle_deg"]

#: Relative response that defines the angular cutoff alpha_c (Sec. 3.3, Sec. 4.4).
CUTOFF_LEVEL = 0.2

#: A fitted sigma larger than this many times the largest measured |angle| is refused.
_MAX_SIGMA_OVER_RANGE = 5.0


@dataclass(frozen=True)
class FalloffFit:
    """Result of :func:`fit_gaussian_falloff`.

    Attributes
    ----------
    sigma_deg : float
        Fitted standard deviation ``sigma`` of ``A exp(-(theta - theta0)^2 / (2 sigma^2))``,
        degrees.
    amplitude : float
        Fitted peak ``A``, in the units of the intensities.
    cutoff_deg : float
        Angle from ``theta0`` where the fitted Gaussian is 20 % of its peak,
        ``sigma sqrt(2 ln 5)`` (about 1.794 sigma), degrees: ``alpha_c`` of Eq. 3.12.
    cutoff_measured_deg : float
        Angle from ``theta0`` where the data divided by ``A`` first fall to 0.2,
        taking points in order of ``|theta - theta0|`` (both sides together) and
        interpolating linearly; NaN if they never do (or start at or below 0.2).
    rms_residual : float
        Root-mean-square of data minus fit, in the units of the intensities.
    """

    sigma_deg: float
    amplitude: float
    cutoff_deg: float
    cutoff_measured_deg: float
    rms_residual: float


def _gaussian(theta: np.ndarray, amplitude: float, sigma: float) -> np.ndarray:
    return amplitude * np.exp(-(theta**2) / (2.0 * sigma**2))


def _measured_crossing(offset: np.ndarray, normalised: np.ndarray) -> float:
    order = np.argsort(offset, kind="stable")
    r, y = offset[order], normalised[order]
    if y[0] <= CUTOFF_LEVEL:
        return math.nan
    below = np.flatnonzero(y <= CUTOFF_LEVEL)
    if below.size == 0:
        return math.nan
    i = int(below[0])
    r0, r1, y0, y1 = float(r[i - 1]), float(r[i]), float(y[i - 1]), float(y[i])
    return r0 + (y0 - CUTOFF_LEVEL) / (y0 - y1) * (r1 - r0)


def fit_gaussian_falloff(angles_deg: Any, intensity: Any, *, center_deg: float = 0.0) -> FalloffFit:
    """Least-squares fit of a Gaussian to a measured pixel angular response.

    Parameters
    ----------
    angles_deg : array_like
        Shape (n,), n >= 3, angles of incidence in degrees; may cover both sides of
        ``center_deg`` (negative angles).
    intensity : array_like
        Shape (n,), measured response (any units, dark level removed), same length.
    center_deg : float, optional
        ``theta0``, the angle of peak response, held fixed in the fit. Default 0
        (normal incidence).

    Returns
    -------
    FalloffFit
        ``sigma_deg``, ``amplitude``, ``cutoff_deg`` (fit, 20 % level),
        ``cutoff_measured_deg`` (data, 20 % level) and ``rms_residual``.

    Raises
    ------
    ReconInputError
        If the inputs are not 1D of equal length >= 3, are non-finite, the
        intensities have no positive value, fewer than 3 distinct angles are
        given, the fit fails, or the fitted sigma exceeds 5 times the largest
        measured ``|theta - theta0|`` (the data barely fall off: measure to larger
        angles).

    Notes
    -----
    Fits ``I(theta) = A exp(-(theta - theta0)^2 / (2 sigma^2))`` with
    :func:`scipy.optimize.curve_fit` (``A, sigma > 0``, ``theta0`` fixed) as for
    Fig. 5.3a; the angular cutoff ``alpha_c`` is where the response falls to 20 %
    of normal incidence (Sec. 3.3, Sec. 4.4), i.e. ``sigma sqrt(2 ln 5)`` for the fit.
    """
    theta = float_array(angles_deg, "angles_deg", ndims=(1,))
    y = float_array(intensity, "intensity", ndims=(1,))
    if theta.shape != y.shape:
        raise ReconInputError(
            f"angles_deg has {theta.size} values but intensity has {y.size}; pass one "
            "intensity per angle"
        )
    if (
        isinstance(center_deg, bool)
        or not isinstance(center_deg, numbers.Real)
        or not (math.isfinite(float(center_deg)))
    ):
        raise ReconInputError(f"center_deg must be a finite number, got {center_deg!r}")
    offset = theta - float(center_deg)
    if np.unique(offset).size < 3:
        raise ReconInputError(
            f"need at least 3 distinct angles to fit a Gaussian, got {np.unique(offset).size}; "
            "measure the response at more angles"
        )
    if not np.any(y > 0):
        raise ReconInputError(
            "intensity has no positive value (all zero or negative); check the exposure, "
            "the dark subtraction and that the source is in view"
        )
    r = np.abs(offset)
    r_max = float(r.max())
    weights = np.clip(y, 0.0, None)
    sigma0 = math.sqrt(float(np.sum(weights * r**2) / np.sum(weights)))
    if not sigma0 > 0:
        sigma0 = r_max / 2.0
    p0 = (float(y.max()), max(sigma0, 1e-3 * r_max))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", scipy.optimize.OptimizeWarning)
            popt, _ = scipy.optimize.curve_fit(
                _gaussian, offset, y, p0=p0, bounds=([0.0, 1e-9 * r_max], [np.inf, np.inf])
            )
    except (RuntimeError, ValueError, scipy.optimize.OptimizeWarning) as exc:
        raise ReconInputError(
            f"the Gaussian fit of the angular response failed ({exc}); measure to larger "
            "angles (down to well below 20 % of the peak) and check center_deg"
        ) from exc
    amplitude, sigma = float(popt[0]), float(popt[1])
    if not (math.isfinite(amplitude) and math.isfinite(sigma) and amplitude > 0):
        raise ReconInputError(
            "the Gaussian fit of the angular response gave no usable peak; measure to larger "
            "angles and check center_deg and the dark subtraction"
        )
    if sigma > _MAX_SIGMA_OVER_RANGE * r_max:
        raise ReconInputError(
            f"the fitted fall-off (sigma = {sigma:.3g} deg) is much wider than the measured "
            f"range (+/-{r_max:.3g} deg from center_deg), so it is not determined; measure to "
            "larger angles"
        )
    residual = y - _gaussian(offset, amplitude, sigma)
    return FalloffFit(
        sigma_deg=sigma,
        amplitude=amplitude,
        cutoff_deg=sigma * math.sqrt(2.0 * math.log(1.0 / CUTOFF_LEVEL)),
        cutoff_measured_deg=_measured_crossing(r, y / amplitude),
        rms_residual=float(np.sqrt(np.mean(residual**2))),
    )


def _number(value: Any, name: str, unit: str, *, minimum: float, strict: bool) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ReconInputError(f"{name} must be a real number, got {value!r}")
    v = float(value)
    ok = math.isfinite(v) and (v > minimum if strict else v >= minimum)
    if not ok:
        rel = ">" if strict else ">="
        raise ReconInputError(f"{name} must be finite and {rel} {minimum}{unit}, got {value!r}")
    return v


def fov_half_angle_deg(
    alpha_c_deg: float,
    *,
    beta_deg: float,
    sensor_width_mm: float,
    psf_width_mm: float,
    d_mm: float,
) -> float:
    """Angular half field of view of a lensless diffuser camera (Eq. 3.12 / Eq. 4.6).

    Parameters
    ----------
    alpha_c_deg : float
        Sensor angular cutoff ``alpha_c`` in degrees (response at 20 % of normal
        incidence, e.g. ``FalloffFit.cutoff_deg``), in (0, 90].
    beta_deg : float
        Maximum deflection angle ``beta`` of the diffuser in degrees, in [0, 90).
    sensor_width_mm : float
        Full sensor width along the axis of interest in mm (> 0).
    psf_width_mm : float
        Full width of the PSF support (the aperture at the diffuser) in mm (>= 0).
    d_mm : float
        Diffuser-to-sensor distance in mm (> 0).

    Returns
    -------
    float
        ``beta + min(alpha_c, atan((sensor_width + psf_width) / (2 d)))`` in degrees.
        Example (Sec. 4.4): ``alpha_c`` 41.5 deg, ``beta`` 0.5 deg and a geometric
        limit above 41.5 deg give 42 deg.

    Raises
    ------
    ReconInputError
        If an argument is not finite or outside its range.

    Notes
    -----
    Eq. 3.12 writes ``alpha = beta + min[alpha_c, atan((l + w) / d)]`` with ``2l`` the
    sensor width and ``2w`` the PSF support width; Eq. 4.6 writes
    ``beta + min[alpha_c, atan((l + w) / (2d))]`` with ``l`` and ``w`` the full
    widths. Both are ``atan((full sensor width + full PSF width) / (2 d))``, the
    formula implemented here. The two limits: the geometric ray through the
    aperture edge to the far sensor edge, and the pixels' angular acceptance.
    """
    alpha_c = _number(alpha_c_deg, "alpha_c_deg", " deg", minimum=0.0, strict=True)
    if alpha_c > 90.0:
        raise ReconInputError(f"alpha_c_deg must be <= 90 deg, got {alpha_c_deg!r}")
    beta = _number(beta_deg, "beta_deg", " deg", minimum=0.0, strict=False)
    if beta >= 90.0:
        raise ReconInputError(f"beta_deg must be < 90 deg, got {beta_deg!r}")
    sensor = _number(sensor_width_mm, "sensor_width_mm", " mm", minimum=0.0, strict=True)
    psf = _number(psf_width_mm, "psf_width_mm", " mm", minimum=0.0, strict=False)
    d = _number(d_mm, "d_mm", " mm", minimum=0.0, strict=True)
    geometric = math.degrees(math.atan((sensor + psf) / (2.0 * d)))
    return beta + min(alpha_c, geometric)

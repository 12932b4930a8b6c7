"""Calibration sampling: depth grids, depth sensitivity and lateral calibration spacing.

Plain numpy/scipy functions that choose where to measure PSFs, following G. Kuo,
*Exploiting Randomness in Computational Cameras and Displays* (PhD dissertation,
UC Berkeley, 2020):

- :func:`uniform_depths`, :func:`inverse_depths` -- depth grids; the second has a
  constant step in 1/z (Eq. 4.7, Eq. 5.10).
- :func:`axial_step_eq510_per_mm` -- the microlens axial sampling bound of Eq. 5.10.
- :func:`depth_sensitivity`, :func:`scale_at_threshold`,
  :func:`inverse_depth_step_per_mm` -- the depth-of-field analysis of Sec. 3.2
  (similarity of a PSF with scaled copies of itself, Sec. 6.4's 0.8 predictor),
  turned into the constant ``c`` of Eq. 4.7.
- :func:`lateral_calibration_spacing_mm` -- Nyquist spacing of lateral calibration
  points set by the sensor's angular fall-off (Sec. 5.3, Eq. 5.9).

Depths ``z`` are object-to-diffuser distances and ``d`` the diffuser-to-sensor
distance, all in mm. Results are float64.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np
import scipy.fft
import scipy.ndimage
import scipy.optimize

from recon.errors import ReconInputError
from recon.validate import as_int, float_array, positive

__all__ = [
    "axial_step_eq510_per_mm",
    "depth_sensitivity",
    "inverse_depth_step_per_mm",
    "inverse_depths",
    "lateral_calibration_spacing_mm",
    "scale_at_threshold",
    "uniform_depths",
]

#: Most depths an inverse-depth grid may hold before it is refused as a mistake.
_MAX_DEPTHS = 1_000_000

#: Scales searched by scale_at_threshold before refining the first crossing.
_GRID_POINTS = 49


def _depth_range(z_min_mm: Any, z_max_mm: Any) -> tuple[float, float]:
    z0 = positive(z_min_mm, "z_min_mm", unit=" mm")
    z1 = positive(z_max_mm, "z_max_mm", unit=" mm")
    if z0 >= z1:
        raise ReconInputError(
            f"z_min_mm ({z0}) must be smaller than z_max_mm ({z1}); swap them or widen the range"
        )
    return z0, z1


# ----------------------------------------------------------------------------- depth grids


def uniform_depths(z_min_mm: float, z_max_mm: float, n: int) -> np.ndarray:
    """Evenly spaced depths from `z_min_mm` to `z_max_mm`, both included.

    Parameters
    ----------
    z_min_mm, z_max_mm : float
        Nearest and farthest depth in mm, ``0 < z_min_mm < z_max_mm``.
    n : int
        Number of depths, >= 2.

    Returns
    -------
    numpy.ndarray
        float64, shape (n,), ascending, in mm; first and last exactly the ends.

    Raises
    ------
    ReconInputError
        If a depth is not finite and positive, ``z_min_mm >= z_max_mm``, or `n` is
        not an integer >= 2.
    """
    z0, z1 = _depth_range(z_min_mm, z_max_mm)
    count = as_int(n, "n", minimum=2)
    return np.linspace(z0, z1, count, dtype=np.float64)


def inverse_depths(
    z_min_mm: float,
    z_max_mm: float,
    *,
    n: int | None = None,
    c_per_mm: float | None = None,
) -> np.ndarray:
    """Depths with a constant step in inverse depth ``1/z`` (dioptric sampling).

    Parameters
    ----------
    z_min_mm, z_max_mm : float
        Nearest and farthest depth in mm, ``0 < z_min_mm < z_max_mm``.
    n : int, optional
        Number of depths (>= 2): ``1/z`` evenly spaced from ``1/z_min_mm`` to
        ``1/z_max_mm``, both ends included. Give exactly one of `n` and `c_per_mm`.
    c_per_mm : float, optional
        Step ``c = 1/z_k - 1/z_{k+1}`` in 1/mm (> 0), e.g. from
        :func:`inverse_depth_step_per_mm` or :func:`axial_step_eq510_per_mm`.
        The grid is ``1/z_k = 1/z_min_mm - k c`` for ``k = 0, 1, ...`` while
        ``z_k <= z_max_mm`` (a range that is a whole number of steps, to 1e-9 of
        a step, ends exactly on ``z_max_mm``); if the last such depth is short of
        ``z_max_mm`` by more than 1e-9 relative, ``z_max_mm`` is appended, so the
        last step is smaller than `c` (never larger: the grid still satisfies the
        sampling bound).

    Returns
    -------
    numpy.ndarray
        float64, shape (m,), ascending, in mm; first element exactly `z_min_mm`,
        last exactly `z_max_mm`.

    Raises
    ------
    ReconInputError
        If a depth is not finite and positive, ``z_min_mm >= z_max_mm``, not
        exactly one of `n` / `c_per_mm` is given, `n` < 2, `c_per_mm` <= 0, or the
        grid would hold more than 1,000,000 depths.

    Notes
    -----
    Eq. 4.7, ``c = 1/z_1 - 1/z_2`` for neighbouring depths (constant difference in
    PSF support width), and Eq. 5.10, ``1/z_1 - 1/z_2 <= 4 lambda / p^2``.
    """
    z0, z1 = _depth_range(z_min_mm, z_max_mm)
    if (n is None) == (c_per_mm is None):
        raise ReconInputError(
            "give exactly one of n (number of depths) and c_per_mm (1/z step in 1/mm)"
        )
    inv0, inv1 = 1.0 / z0, 1.0 / z1
    if n is not None:
        count = as_int(n, "n", minimum=2)
        if count > _MAX_DEPTHS:
            raise ReconInputError(f"n = {count} depths is too many; use at most {_MAX_DEPTHS}")
        z = 1.0 / np.linspace(inv0, inv1, count, dtype=np.float64)
    else:
        c = positive(c_per_mm, "c_per_mm", unit=" 1/mm")
        steps = (inv0 - inv1) / c
        if steps > _MAX_DEPTHS:
            raise ReconInputError(
                f"c_per_mm = {c} gives {steps:.3g} steps between {z0} and {z1} mm, more than "
                f"{_MAX_DEPTHS}; use a larger step or a narrower depth range"
            )
        k_last = math.floor(steps + 1e-9)  # a whole number of steps up to rounding
        inv = inv0 - c * np.arange(k_last + 1, dtype=np.float64)
        z = 1.0 / inv[inv > 0.0]
        if z[-1] < z1 * (1.0 - 1e-9):
            z = np.append(z, z1)
    z[0] = z0
    z[-1] = z1
    return z


def axial_step_eq510_per_mm(wavelength_nm: float, lenslet_pitch_um: float) -> float:
    """Largest 1/z step between calibration depths for a microlens diffuser (Eq. 5.10).

    Parameters
    ----------
    wavelength_nm : float
        Wavelength of the light in nm (> 0).
    lenslet_pitch_um : float
        Microlens diameter ``p`` in micrometres (> 0).

    Returns
    -------
    float
        ``4 lambda / p**2`` in 1/mm. Example (Sec. 6.4): 520 nm and 250 um give
        0.0333 1/mm (33 1/m).

    Raises
    ------
    ReconInputError
        If an argument is not finite and positive.

    Notes
    -----
    Eq. 5.10: the circle of confusion of a lenslet may change by no more than the
    diffraction-limited spot ``lambda / NA ~ 2 d lambda / p`` between neighbouring
    depths, giving ``1/z_1 - 1/z_2 <= 4 lambda / p^2``.
    """
    lam_mm = positive(wavelength_nm, "wavelength_nm", unit=" nm") * 1e-6
    p_mm = positive(lenslet_pitch_um, "lenslet_pitch_um", unit=" um") * 1e-3
    return 4.0 * lam_mm / (p_mm * p_mm)


# ----------------------------------------------------------------------------- depth of field


def _scaled(psf: np.ndarray, s: float) -> np.ndarray:
    """``h(s x)`` about the array centre, bilinear, zeros outside."""
    center = (np.asarray(psf.shape, dtype=np.float64) - 1.0) / 2.0
    return scipy.ndimage.affine_transform(
        psf, np.full(2, s), offset=center * (1.0 - s), order=1, mode="grid-constant", cval=0.0
    )


def _mu(psf: np.ndarray, s: float) -> float:
    """:func:`inner_product` of ``h(s x)`` and ``h(x)``; 0 if the scaled copy is empty."""
    scaled = _scaled(psf, s)
    norm_scaled = math.sqrt(float(np.sum(scaled * scaled)))
    if norm_scaled == 0.0:
        return 0.0
    norm = math.sqrt(float(np.sum(psf * psf)))
    return float(np.sum(scaled * psf)) / (norm_scaled * norm)


def _check_psf(psf: Any) -> np.ndarray:
    h = float_array(psf, "psf")
    if not np.any(h):
        raise ReconInputError(
            "psf is all zero; pass a PSF with signal (check exposure and background removal)"
        )
    return h


def depth_sensitivity(psf: Any, scales: Any) -> np.ndarray:
    """Similarity of a PSF with coordinate-scaled copies of itself, ``mu(s)`` (Sec. 3.2).

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), real, finite, not all zero; ideally background-removed
        (:func:`~recon.analysis.psf.remove_background_dct`) and centred on the array.
    scales : array_like
        Scale factors ``s`` (> 0), scalar or 1D.

    Returns
    -------
    numpy.ndarray
        float64, shape (len(scales),): ``mu(s) = <h(s x), h(x)> / (|h(s x)| |h|)``;
        1 at ``s = 1``. 0 where the scaled copy is empty (all samples outside).

    Raises
    ------
    ReconInputError
        If `psf` is not a finite 2D array with signal, or a scale is not finite
        and positive.

    Notes
    -----
    Sec. 3.2 (depth-of-field): on-axis PSFs at two depths are related by a
    coordinate scaling, ``h0(s x; z1) = h0(x; z2)``, so the depth sensitivity is
    ``mu(s) = <h0(s x), h0(x)>`` (Eq. 3.11 with a scale instead of a shift),
    normalised as in :func:`~recon.analysis.psf.inner_product`. ``h(s x)`` is
    evaluated about the array centre ``((rows - 1)/2, (cols - 1)/2)`` -- not the
    PSF's centre of mass -- with bilinear interpolation
    (:func:`scipy.ndimage.affine_transform`, ``order=1``,
    ``mode="grid-constant"``), same output shape and zeros outside the array
    (blended bilinearly at the edge, so ``mu`` is continuous in ``s``). For
    ``s > 1`` the pattern shrinks towards the centre, so none of it is lost off
    the array; for continuous functions the normalised ``mu`` is the same for
    ``s`` and ``1/s``.
    """
    h = _check_psf(psf)
    s = float_array(scales, "scales", ndims=(0, 1)).ravel()
    if np.any(s <= 0):
        raise ReconInputError("scales must be > 0; pass scale factors such as 1.0, 1.05, 1.1")
    return np.array([_mu(h, float(v)) for v in s], dtype=np.float64)


def scale_at_threshold(psf: Any, threshold: float = 0.8, *, max_scale: float = 2.0) -> float:
    """Smallest scale ``s > 1`` at which the depth sensitivity ``mu(s)`` drops to `threshold`.

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), as for :func:`depth_sensitivity`.
    threshold : float, optional
        Similarity below which two depths are distinguishable, in (0, 1). Default
        0.8, the predictor of Sec. 6.4.
    max_scale : float, optional
        Largest scale searched (> 1). Default 2.

    Returns
    -------
    float
        ``s*`` with ``mu(s*) = threshold`` (to ~1e-9 in ``s``), the first crossing.

    Raises
    ------
    ReconInputError
        If `psf` is invalid, `threshold` is not in (0, 1), `max_scale` <= 1, or
        ``mu`` stays above `threshold` up to `max_scale`.

    Notes
    -----
    ``mu`` (:func:`depth_sensitivity`) is evaluated on 49 scales geometrically
    spaced in ``s - 1`` (about 21 % apart) from ``1e-4 (max_scale - 1)`` to
    ``max_scale - 1``, stopping at the first scale where it is at or below
    `threshold`; that bracket is refined with Brent's method
    (:func:`scipy.optimize.brentq`). A dip narrower than one grid step could be
    missed; for a speckle or caustic PSF ``mu`` falls monotonically near ``s = 1``.
    Each evaluation is one bilinear resampling of the PSF, so a 1000 x 1000 PSF
    takes about a second.
    """
    h = _check_psf(psf)
    if (
        isinstance(threshold, bool)
        or not isinstance(threshold, numbers.Real)
        or not (0.0 < float(threshold) < 1.0)
    ):
        raise ReconInputError(f"threshold must be in (0, 1), got {threshold!r}; e.g. 0.8")
    thr = float(threshold)
    top = positive(max_scale, "max_scale")
    if top <= 1.0:
        raise ReconInputError(f"max_scale must be > 1, got {max_scale!r}; e.g. 2.0")
    grid = 1.0 + (top - 1.0) * np.geomspace(1e-4, 1.0, _GRID_POINTS)
    prev = 1.0
    for s in grid:
        value = _mu(h, float(s))
        if value <= thr:
            if value == thr:
                return float(s)
            return float(
                scipy.optimize.brentq(
                    lambda v: _mu(h, v) - thr, prev, float(s), xtol=1e-9, rtol=1e-9
                )
            )
        prev = float(s)
    raise ReconInputError(
        f"the depth sensitivity stays above {thr} up to scale {top}; raise max_scale, check "
        "that the PSF has fine structure (background removed, in focus), or use a lower "
        "threshold"
    )


def inverse_depth_step_per_mm(psf: Any, d_mm: float, z_mm: float, threshold: float = 0.8) -> float:
    """Inverse-depth step ``c`` of Eq. 4.7 at which a PSF measured at `z_mm` becomes distinct.

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), the on-axis PSF measured at depth `z_mm`, as for
        :func:`depth_sensitivity`.
    d_mm : float
        Diffuser-to-sensor distance in mm (> 0).
    z_mm : float
        Object (source)-to-diffuser distance of the measurement in mm (> 0).
    threshold : float, optional
        Similarity threshold passed to :func:`scale_at_threshold`. Default 0.8.

    Returns
    -------
    float
        ``c = 1/z_near - 1/z_mm`` in 1/mm: the nearer neighbouring depth
        ``z_near`` whose PSF has similarity `threshold` with this one. Use it as
        ``c_per_mm`` of :func:`inverse_depths`.

    Raises
    ------
    ReconInputError
        As :func:`scale_at_threshold`, or if `d_mm` / `z_mm` is not finite and
        positive.

    Notes
    -----
    Caustics from a point source at distance ``z`` are magnified by ``1 + d/z``
    (Fig. 4.2; Eq. 5.2, ``s_i = z (d + z_i) / (z_i (d + z)) = (1 + d/z_i)/(1 + d/z)``),
    so the PSFs at ``z_1 < z_2`` are related by the scale
    ``s = (1 + d/z_1) / (1 + d/z_2)``. With ``z_2 = z`` (the measurement) and
    ``s = s*`` from :func:`scale_at_threshold`,
    ``1 + d/z_1 = s* (1 + d/z)``, hence
    ``c = 1/z_1 - 1/z = (s* - 1)(1 + d/z)/d = (s* - 1)(1/d + 1/z)``.
    """
    d = positive(d_mm, "d_mm", unit=" mm")
    z = positive(z_mm, "z_mm", unit=" mm")
    s_star = scale_at_threshold(psf, threshold)
    return (s_star - 1.0) * (1.0 / d + 1.0 / z)


# ----------------------------------------------------------------------------- lateral


def lateral_calibration_spacing_mm(
    falloff_sigma_deg: float, z_mm: float, *, rel_threshold: float = 1e-2
) -> float:
    """Nyquist spacing of lateral calibration points set by a Gaussian pixel fall-off (Eq. 5.9).

    Parameters
    ----------
    falloff_sigma_deg : float
        Standard deviation ``sigma`` in degrees of the pixel angular response
        ``f(theta) = exp(-theta^2 / (2 sigma^2))`` (e.g. ``FalloffFit.sigma_deg``).
    z_mm : float
        Object-to-diffuser distance of the calibration plane in mm (> 0).
    rel_threshold : float, optional
        The bandwidth ``f_max`` is the highest spatial frequency at which the
        amplitude spectrum is still >= `rel_threshold` times its DC value, in
        (1e-9, 1). Default 1e-2.

    Returns
    -------
    float
        ``1 / (2 f_max)`` in mm. Example: sigma = 13 deg, z = 1.7 mm gives about
        0.38 mm (Sec. 5.3 / Fig. 5.3 quote 0.4 mm); for small angles ``f~`` is a
        Gaussian of width ``sigma_x = z sigma_rad`` and the result tends to
        ``sqrt(2 / ln(1/rel_threshold)) * pi / 2 * sigma_x`` (1.035 sigma_x at 1e-2).

    Raises
    ------
    ReconInputError
        If an argument is not finite and positive, `rel_threshold` is outside
        (1e-9, 1), or ``f(89 deg) >= rel_threshold`` (the fall-off has not decayed
        by grazing incidence, so its bandwidth is set by the truncation, not the
        sensor).

    Notes
    -----
    Eq. 5.9: after registration (Eq. 5.2) the fall-off seen by one pixel is
    ``f~(x) = f(atan(x / z))``. It is sampled on ``|x| <= z tan(theta_max)`` with
    ``theta_max = min(89 deg, angle where f < 1e-12)``, with step
    ``z sigma_rad / 64``, zero-padded to >= 131072 points, and its amplitude
    spectrum (:func:`scipy.fft.rfft`) is searched for the last frequency at or
    above `rel_threshold` of DC (linear interpolation between bins). Nyquist
    sampling of ``f~`` then needs calibration points ``1 / (2 f_max)`` apart.
    """
    sigma = math.radians(positive(falloff_sigma_deg, "falloff_sigma_deg", unit=" deg"))
    z = positive(z_mm, "z_mm", unit=" mm")
    thr = positive(rel_threshold, "rel_threshold")
    if not 1e-9 < thr < 1.0:
        raise ReconInputError(f"rel_threshold must be in (1e-9, 1), got {rel_threshold!r}")
    grazing = math.radians(89.0)
    edge = math.exp(-(grazing**2) / (2.0 * sigma**2))
    if edge >= thr:
        raise ReconInputError(
            f"the fall-off is still {edge:.3g} of its peak at 89 deg (sigma = "
            f"{falloff_sigma_deg} deg), not below rel_threshold = {thr}; the sensor barely "
            "limits the angles, so Eq. 5.9 sets no spacing -- check sigma or lower "
            "rel_threshold below that value"
        )
    theta_max = min(grazing, sigma * math.sqrt(2.0 * math.log(1e12)))
    sigma_x = z * sigma
    dx = sigma_x / 64.0
    half = int(math.ceil(z * math.tan(theta_max) / dx))
    x = np.arange(-half, half + 1, dtype=np.float64) * dx
    ftilde = np.exp(-(np.arctan(x / z) ** 2) / (2.0 * sigma**2))
    n_fft = scipy.fft.next_fast_len(max(x.size, 131072), real=True)
    amp = np.abs(scipy.fft.rfft(ftilde, n_fft))
    freq = scipy.fft.rfftfreq(n_fft, dx)
    rel = amp / amp[0]
    i = int(np.flatnonzero(rel >= thr)[-1])
    if i + 1 >= rel.size:  # cannot happen with 64 samples per sigma_x; be safe
        f_max = float(freq[i])
    else:
        a0, a1 = float(rel[i]), float(rel[i + 1])
        f_max = float(freq[i] + (a0 - thr) / (a0 - a1) * (freq[i + 1] - freq[i]))
    return 1.0 / (2.0 * f_max)

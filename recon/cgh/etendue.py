"""Étendue, field of view and eyebox of a holographic display (Kuo 2020, Eq. 7.1-7.6, 7.10).

A holographic display's étendue is set by its pixel count: the product of the 1D
field of view and the eyebox is ``lambda N`` (Eq. 7.6). A scattering mask with
pixels ``Delta_m`` smaller than the SLM's ``Delta`` multiplies the étendue by
``q = (Delta / Delta_m)^2`` (Eq. 7.10) without changing the eyebox.

Two conventions for the FoV-eyebox product are offered, because the dissertation
uses both when it quotes numbers (Sec. 7.3, "Field-of-View and Eyebox Tradeoff"):

* ``"paraxial"`` (Eq. 7.6): ``FoV [rad] x eyebox = lambda N``. It gives the quoted
  1.05 mm eyebox for 4160 px at 120 deg and 532 nm, and 12.7 deg for a 10 mm eyebox.
* ``"sine"`` (the étendue of Eq. 7.1 in 1D, ``2 w sin(theta)``):
  ``2 sin(FoV / 2) x eyebox = lambda N``. It gives the quoted ~32,500 px for 120 deg
  with a 10 mm eyebox (and the same 12.7 deg at small angles).

Units: pitches in micrometres, wavelengths in nanometres, lengths in millimetres,
angles in degrees unless a name says otherwise.
"""

from __future__ import annotations

import math
import numbers

from ..errors import ReconInputError
from ..validate import positive

__all__ = [
    "etendue_mm2",
    "expansion_factor",
    "eyebox_for_fov",
    "fov_eyebox",
    "fov_for_eyebox",
    "max_diffraction_angle_deg",
    "pixels_for",
    "slm_etendue_mm2",
]

_MODELS = ("paraxial", "sine")


def _model(model: str) -> str:
    if model not in _MODELS:
        raise ReconInputError(f"model must be one of {_MODELS}, got {model!r}")
    return model


def _fov_rad(fov_deg: float) -> float:
    fov = positive(fov_deg, "fov_deg")
    if fov >= 180.0:
        raise ReconInputError(f"fov_deg must be below 180 degrees, got {fov}")
    return math.radians(fov)


def max_diffraction_angle_deg(pitch_um: float, wavelength_nm: float) -> float:
    """Maximum deflection angle of a pixelated modulator, ``sin(theta) = lambda / (2 Delta)``.

    Eq. 7.2.

    Parameters
    ----------
    pitch_um : float
        Pixel pitch ``Delta`` (um), > 0.
    wavelength_nm : float
        Wavelength ``lambda`` (nm), > 0.

    Returns
    -------
    float
        ``theta`` in degrees.

    Raises
    ------
    ReconInputError
        Non-positive inputs, or ``lambda > 2 Delta`` (no propagating first order: use
        a larger pitch or a shorter wavelength).
    """
    d = positive(pitch_um, "pitch_um")
    lam = positive(wavelength_nm, "wavelength_nm") * 1e-3
    if lam > 2.0 * d:
        raise ReconInputError(
            f"wavelength {lam * 1e3:g} nm exceeds twice the pitch {d:g} um: no propagating "
            "diffraction order; use a pitch of at least lambda / 2")
    return math.degrees(math.asin(lam / (2.0 * d)))


def etendue_mm2(width_mm: float, height_mm: float, half_angle_deg: float) -> float:
    """Étendue ``G = 4 A sin^2(theta)`` of a planar emitter (Eq. 7.1).

    Parameters
    ----------
    width_mm, height_mm : float
        Emitter size (mm), area ``A = width x height``.
    half_angle_deg : float
        Half-width ``theta`` of the square emission pyramid (degrees, in (0, 90]).

    Returns
    -------
    float
        ``G`` in mm^2 (times the dimensionless ``4 sin^2``).
    """
    a = positive(width_mm, "width_mm") * positive(height_mm, "height_mm")
    th = positive(half_angle_deg, "half_angle_deg")
    if th > 90.0:
        raise ReconInputError(f"half_angle_deg must be at most 90, got {th}")
    return 4.0 * a * math.sin(math.radians(th)) ** 2


def slm_etendue_mm2(shape, wavelength_nm: float) -> float:
    """Étendue of a holographic display ``G = (lambda N_x) (lambda N_y)`` (Eq. 7.3).

    Parameters
    ----------
    shape : (int, int)
        SLM pixels ``(N_y, N_x)``.
    wavelength_nm : float
        Wavelength (nm).

    Returns
    -------
    float
        ``G`` in mm^2; equal to :func:`etendue_mm2` of the SLM area with the angle of
        :func:`max_diffraction_angle_deg` (independent of the pitch).
    """
    try:
        ny, nx = (int(v) for v in shape)
    except (TypeError, ValueError):
        raise ReconInputError(f"shape must be (N_y, N_x) pixels, got {shape!r}") from None
    if ny < 1 or nx < 1:
        raise ReconInputError(f"shape must have positive pixel counts, got {shape!r}")
    lam_mm = positive(wavelength_nm, "wavelength_nm") * 1e-6
    return (lam_mm * nx) * (lam_mm * ny)


def expansion_factor(slm_pitch_um: float, mask_pitch_um: float) -> float:
    """Étendue expansion of a scattering mask, ``q = (Delta / Delta_m)^2`` (Eq. 7.10).

    Parameters
    ----------
    slm_pitch_um : float
        SLM pixel pitch ``Delta`` as imaged on the mask (um).
    mask_pitch_um : float
        Mask pixel pitch ``Delta_m`` (um).

    Returns
    -------
    float
        ``q``; e.g. 16 um / 4 um gives 16 (the dissertation's prototype).
    """
    return (positive(slm_pitch_um, "slm_pitch_um")
            / positive(mask_pitch_um, "mask_pitch_um")) ** 2


def fov_eyebox(n_pixels: int, pitch_um: float, wavelength_nm: float, f1_mm: float,
               f2_mm: float, mask_pitch_um: float | None = None) -> tuple[float, float]:
    """1D field of view and eyebox of a Fourier holographic display (Eq. 7.4, 7.5).

    ``FoV = 2 atan((f1 / f2) tan(theta))`` with ``theta`` from the finest pitch
    (the mask's if given, Eq. 7.2) and ``eyebox = (f2 / f1) w`` with ``w = N Delta``
    the SLM width: a mask widens the FoV and leaves the eyebox unchanged.

    Parameters
    ----------
    n_pixels : int
        SLM pixels along the axis.
    pitch_um : float
        SLM pixel pitch (um).
    wavelength_nm : float
        Wavelength (nm).
    f1_mm, f2_mm : float
        Focal lengths of the Fourier lens and of the eyepiece (mm).
    mask_pitch_um : float, optional
        Pixel pitch of a scattering mask conjugate to the SLM (um).

    Returns
    -------
    (float, float)
        ``(fov_deg, eyebox_mm)``.
    """
    n = _pixels(n_pixels)
    d = positive(pitch_um, "pitch_um")
    finest = d if mask_pitch_um is None else positive(mask_pitch_um, "mask_pitch_um")
    theta = math.radians(max_diffraction_angle_deg(finest, wavelength_nm))
    f1 = positive(f1_mm, "f1_mm")
    f2 = positive(f2_mm, "f2_mm")
    fov = 2.0 * math.atan(f1 / f2 * math.tan(theta))
    return math.degrees(fov), f2 / f1 * n * d * 1e-3


def _pixels(n) -> int:
    if isinstance(n, bool) or not isinstance(n, numbers.Real) or not math.isfinite(n) \
            or n < 1 or n != int(n):
        raise ReconInputError(f"n_pixels must be a positive integer, got {n!r}")
    return int(n)


def _angular(fov_rad: float, model: str) -> float:
    return fov_rad if _model(model) == "paraxial" else 2.0 * math.sin(fov_rad / 2.0)


def eyebox_for_fov(n_pixels: int, fov_deg: float, wavelength_nm: float,
                   model: str = "paraxial") -> float:
    """Eyebox (mm) left by an ``N``-pixel display at a given 1D FoV (Eq. 7.6).

    Parameters
    ----------
    n_pixels : int
        Pixels along the axis (e.g. 4160 for the Holoeye GAEA-2).
    fov_deg : float
        Field of view (degrees, in (0, 180)).
    wavelength_nm : float
        Wavelength (nm).
    model : {"paraxial", "sine"}
        ``FoV x eyebox = lambda N`` with the FoV in radians (Eq. 7.6), or with
        ``2 sin(FoV/2)`` (Eq. 7.1). See the module docstring.

    Returns
    -------
    float
        Eyebox (mm); 4160 px, 120 deg, 532 nm give 1.057 mm (paraxial).
    """
    lam_n = positive(wavelength_nm, "wavelength_nm") * 1e-6 * _pixels(n_pixels)
    return lam_n / _angular(_fov_rad(fov_deg), model)


def fov_for_eyebox(n_pixels: int, eyebox_mm: float, wavelength_nm: float,
                   model: str = "paraxial") -> float:
    """1D FoV (degrees) left by an ``N``-pixel display at a given eyebox (Eq. 7.6).

    Parameters
    ----------
    n_pixels : int
        Pixels along the axis.
    eyebox_mm : float
        Eyebox (mm).
    wavelength_nm : float
        Wavelength (nm).
    model : {"paraxial", "sine"}
        See :func:`eyebox_for_fov`.

    Returns
    -------
    float
        FoV in degrees; 4160 px, 10 mm, 532 nm give 12.7 deg.

    Raises
    ------
    ReconInputError
        If the étendue cannot reach the eyebox at any angle (``"sine"`` model with
        ``lambda N / eyebox > 2``).
    """
    a = positive(wavelength_nm, "wavelength_nm") * 1e-6 * _pixels(n_pixels) / positive(
        eyebox_mm, "eyebox_mm")
    if _model(model) == "paraxial":
        return math.degrees(a)
    if a > 2.0:
        raise ReconInputError(
            f"lambda N / eyebox = {a:.3g} exceeds 2: the display's étendue covers more "
            "than a hemisphere at this eyebox; choose a larger eyebox")
    return math.degrees(2.0 * math.asin(a / 2.0))


def pixels_for(fov_deg: float, eyebox_mm: float, wavelength_nm: float,
               model: str = "sine") -> float:
    """Pixels needed along one axis for a FoV and an eyebox (Eq. 7.1 / 7.6).

    Parameters
    ----------
    fov_deg : float
        Field of view (degrees).
    eyebox_mm : float
        Eyebox (mm).
    wavelength_nm : float
        Wavelength (nm).
    model : {"sine", "paraxial"}
        Default ``"sine"``: 120 deg, 10 mm, 532 nm need about 32,500 px.

    Returns
    -------
    float
        ``N`` (not rounded).
    """
    lam_mm = positive(wavelength_nm, "wavelength_nm") * 1e-6
    return _angular(_fov_rad(fov_deg), model) * positive(eyebox_mm, "eyebox_mm") / lam_mm

"""Geometry of a lensless (DiffuserCam) bench and the default bench geometries.

:class:`LenslessGeometry` holds the diffuser surface, its distance to the sensor,
the aperture, the sensor and the pixel angular response, and finds the closest
source whose PSF fits on the sensor (Kuo 2020, App. A.2). :func:`default_geometry`
and :func:`diffuser_for_sensor` build the small benches of the tests, the demo and
the virtual bench. Conventions (axes, units, sign of the image shift) are those of
:mod:`recon.optics.lensless`, which renders PSFs and scenes of a geometry; the
argument checks shared with it are here too.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from ..errors import ReconInputError
from .diffuser import DiffuserSurface, finite_positive

__all__ = [
    "LenslessGeometry",
    "default_geometry",
    "diffuser_for_sensor",
    "oversample_factor",
    "positive_number",
    "size_pair_mm",
    "source_position",
]


# ----------------------------------------------------------------------------- checks
def positive_number(value, name: str, example: str) -> float:
    """``recon.optics.diffuser.finite_positive``, refusing bools too."""
    if isinstance(value, bool):
        raise ReconInputError(f"{name} must be a number, got {value!r}; e.g. {example}")
    return finite_positive(value, name, example)


def size_pair_mm(value, name: str, example: str) -> tuple[float, float]:
    """``value`` as a pair (width_mm, height_mm) of finite positive floats; else
    ReconInputError naming ``name`` and an ``example``."""
    try:
        a, b = value
    except (TypeError, ValueError) as exc:
        raise ReconInputError(f"{name} must be a pair (width_mm, height_mm), e.g. "
                              f"{example}; got {value!r}") from exc
    a = positive_number(a, f"{name} width", example)
    b = positive_number(b, f"{name} height", example)
    return a, b


def oversample_factor(value) -> int:
    """``value`` as an integer fine-grid factor >= 1; else ReconInputError."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise ReconInputError(
            f"oversample must be an integer >= 1, got {value!r}; e.g. 2 (render on a grid "
            "twice as fine as the sensor, then bin)"
        )
    return int(value)


def source_position(xyz) -> tuple[float, float, float]:
    """``xyz`` as three finite floats (x, y, z) mm with z > 0 (in front of the
    diffuser); else ReconInputError."""
    try:
        if any(isinstance(v, bool | np.bool_ | str | bytes) for v in xyz):
            raise TypeError(xyz)  # numpy would read True as 1.0 and "30" as 30.0
        arr = np.asarray(xyz, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ReconInputError(f"source position {xyz!r} must be (x, y, z) in mm") from exc
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ReconInputError(
            f"source position must be three finite numbers (x, y, z) in mm, got {xyz!r}"
        )
    x, y, z = (float(v) for v in arr)
    if z <= 0:
        raise ReconInputError(
            f"source z = {z} mm is not in front of the diffuser; z is the distance from the "
            "diffuser towards the scene and must be positive (e.g. 30.0)"
        )
    return x, y, z


# ----------------------------------------------------------------------------- geometry
@dataclass(frozen=True, eq=False)
class LenslessGeometry:
    """A DiffuserCam bench: diffuser, aperture, sensor and pixel angular response.

    Parameters
    ----------
    surface : DiffuserSurface
        Textured face of the diffuser; must cover the aperture.
    d_mm : float
        Diffuser-to-sensor distance, mm (> 0).
    aperture_mm : (width_mm, height_mm)
        Rectangular aperture on the diffuser, centred on the axis (width along x /
        sensor columns, height along y / rows), mm.
    sensor_shape : (rows, cols)
        Sensor pixels.
    sensor_pitch_um : float
        Pixel pitch, um.
    falloff_sigma_deg : float or None
        Standard deviation ``sigma`` of the pixel angular response
        ``f(theta) = exp(-theta^2 / (2 sigma^2))`` (Eq. 5.1), degrees; None disables
        the fall-off. Default 20 deg: ``f`` falls to 20 % (the cut-off of Fig. 3.5)
        at ``sigma sqrt(2 ln 5) = 36 deg``, between the PCO prototype's measured 30.5
        and 42 deg (Sec. 3.3).

    Raises
    ------
    ReconInputError
        Non-positive or non-finite distances, sizes or pitch, an empty aperture, an
        aperture the surface does not cover, a bad sensor shape or fall-off.
    """

    surface: DiffuserSurface
    d_mm: float
    aperture_mm: tuple[float, float]
    sensor_shape: tuple[int, int]
    sensor_pitch_um: float
    falloff_sigma_deg: float | None = 20.0

    def __post_init__(self):
        if not isinstance(self.surface, DiffuserSurface):
            raise ReconInputError(
                "surface must be a DiffuserSurface, e.g. DiffuserSurface.smooth_random(4.0)"
            )
        set_ = object.__setattr__
        set_(self, "d_mm", positive_number(self.d_mm, "diffuser-to-sensor distance d_mm",
                                            "8.9"))
        try:
            aw, ah = (float(v) for v in self.aperture_mm)
        except (TypeError, ValueError) as exc:
            raise ReconInputError(
                f"aperture must be (width_mm, height_mm), got {self.aperture_mm!r}") from exc
        if not (math.isfinite(aw) and math.isfinite(ah)) or aw <= 0 or ah <= 0:
            raise ReconInputError(
                f"aperture ({aw}, {ah}) mm is empty or invalid; give a positive (width_mm, "
                "height_mm) such as (2.2, 2.8)"
            )
        set_(self, "aperture_mm", (aw, ah))
        try:
            rows, cols = (int(v) for v in self.sensor_shape)
            ok = all(float(v) == int(v) for v in self.sensor_shape)
        except (TypeError, ValueError):
            ok = False
        if not ok or rows < 2 or cols < 2:
            raise ReconInputError(
                f"sensor_shape must be (rows, cols) integers >= 2, got {self.sensor_shape!r}"
            )
        set_(self, "sensor_shape", (rows, cols))
        set_(self, "sensor_pitch_um", positive_number(self.sensor_pitch_um, "sensor pitch",
                                                       "13.0 um"))
        if self.falloff_sigma_deg is not None:
            set_(self, "falloff_sigma_deg", positive_number(
                self.falloff_sigma_deg, "fall-off sigma", "20.0 deg, or None for no fall-off"))
        sw, sh = self.surface.extent_mm
        if aw > sw + 1e-9 or ah > sh + 1e-9:
            raise ReconInputError(
                f"aperture {aw:g} x {ah:g} mm is larger than the diffuser surface "
                f"{sw:g} x {sh:g} mm; make a larger surface or a smaller aperture"
            )

    @property
    def sensor_size_mm(self) -> tuple[float, float]:
        """(width_mm, height_mm) of the sensor."""
        rows, cols = self.sensor_shape
        return cols * self.sensor_pitch_um * 1e-3, rows * self.sensor_pitch_um * 1e-3

    def max_deflection_deg(self) -> float:
        """Largest deflection ``beta`` of the diffuser inside the aperture, degrees."""
        return self.surface.max_deflection_deg(self.aperture_mm)

    def min_z_mm(self) -> float:
        """Closest on-axis source distance whose PSF still fits on the sensor (App. A.2).

        A ray from an on-axis source at ``z`` through aperture point ``x`` lands at
        ``x (1 + d / z) + d tan(delta(x))`` (paraxially in the incidence, ``delta``
        the thin-prism deflection :meth:`DiffuserSurface.deflection_rad`). The
        PSF fits when, on both axes and both sides, the extreme landing point over
        the surface samples inside the aperture stays within the sensor half-size.
        Each of the four conditions is solved for ``z`` with Brent's method (the
        extreme landing point comes from the aperture's far edge, so it decreases
        with ``z``), and ``z_min`` is the largest of the four solutions. At ``z_min``
        the caustic pattern just fills the sensor along its limiting axis.

        Returns
        -------
        float
            mm; ``math.inf`` if even a distant source's PSF (the aperture plus the
            deflections) is larger than the sensor.
        """
        from scipy.optimize import brentq

        x, y = self.surface.coordinates_mm()
        aw, ah = self.aperture_mm
        cols = np.abs(x) <= aw / 2 + 1e-12
        rows = np.abs(y) <= ah / 2 + 1e-12
        tan_dev = np.tan(self.surface.deflection_rad()[:, rows][:, :, cols])
        d = self.d_mm
        sw, sh = self.sensor_size_mm
        z_min = 0.0
        # per position along an axis only the extreme deflection across the other
        # axis matters: (positions, largest tan, smallest tan, sensor half-size)
        for pos, hi, lo, half in ((x[cols], tan_dev[0].max(0), tan_dev[0].min(0), sw / 2),
                                  (y[rows], tan_dev[1].max(1), tan_dev[1].min(1), sh / 2)):
            for p, t in ((pos, hi), (-pos, -lo)):
                def excess(z, p=p, t=t, half=half):
                    return float(np.max(p * (1.0 + d / z) + d * t)) - half

                if excess(1e12) >= 0:
                    return math.inf
                if excess(1e-6 * d) <= 0:
                    continue
                z_min = max(z_min, brentq(excess, 1e-6 * d, 1e12, xtol=1e-9, rtol=1e-12))
        return z_min


# ----------------------------------------------------------------------------- defaults
def _fit_half_aperture(pos, tan_dev, axis, half, d, z0) -> float:
    """Largest half-width A (mm, on the surface grid) such that no ray through
    ``|p| <= A`` from an on-axis source at ``z0`` lands beyond ``half`` on the sensor
    (see :meth:`LenslessGeometry.min_z_mm`); ``tan_dev`` (rows, cols) is tan of the
    deflection along ``axis`` (0: x along columns, 1: y along rows), its extremes
    taken across the other axis (reducing over ``axis`` of the array; a superset of
    the final aperture, so conservative)."""
    reach = np.maximum(pos * (1 + d / z0) + d * tan_dev.max(axis=axis),
                       -(pos * (1 + d / z0) + d * tan_dev.min(axis=axis)))
    bad = reach > half
    if not np.any(bad):
        return float(np.abs(pos).max())
    ok = np.abs(pos) < np.abs(pos[bad]).min() - 1e-12
    if not np.any(ok):
        raise ReconInputError("the diffuser deflects too much for this sensor")
    return float(np.abs(pos[ok]).max())


def diffuser_for_sensor(kind: str, sensor_size_mm: tuple[float, float],
                        seed: int = 0) -> DiffuserSurface:
    """The default diffuser surface of a kind, covering a sensor plus 0.1 mm.

    ``"smooth"``: :meth:`DiffuserSurface.smooth_random` (140 um features, mean slope
    0.7 deg, n = 1.58) sampled at 5 um; ``"microlens"``:
    :meth:`DiffuserSurface.random_microlens` (250 um lenslets, f = 1.5 mm) at 2.5 um.

    Parameters
    ----------
    kind : {"smooth", "microlens"}
    sensor_size_mm : (width_mm, height_mm)
    seed : int

    Returns
    -------
    DiffuserSurface

    Raises
    ------
    ReconInputError
        Unknown kind.
    """
    size = (sensor_size_mm[0] + 0.1, sensor_size_mm[1] + 0.1)
    if kind == "smooth":
        return DiffuserSurface.smooth_random(size, pitch_um=5.0, seed=seed)
    if kind == "microlens":
        return DiffuserSurface.random_microlens(size, 2.5, seed=seed)
    raise ReconInputError(f"unknown diffuser kind {kind!r}; use 'smooth' or 'microlens'")


def default_geometry(kind: str = "smooth", seed: int = 0) -> LenslessGeometry:
    """A small bench geometry for tests and demos.

    Both kinds: sensor 256 x 320 px at 13 um (3.33 x 4.16 mm; the PCO.edge 6.5 um
    pixels binned 2 x 2 as in Ch. 4), pixel fall-off sigma 20 deg, aperture sized
    per axis so that the PSF of an on-axis source at 20 mm just fits on the sensor
    (App. A.2): the largest centred rectangle, on the surface grid, for which no
    ray lands off the sensor (the criterion of :meth:`LenslessGeometry.min_z_mm`,
    with deflections taken over the whole sensor-sized surface, so
    ``min_z_mm()`` comes out at or just below 20 mm).

    * ``"smooth"``: :meth:`DiffuserSurface.smooth_random` (140 um features, mean
      slope 0.7 deg, n = 1.58, 5 um pitch), ``d = 8.9`` mm (the Ch. 4 prototype).
    * ``"microlens"``: :meth:`DiffuserSurface.random_microlens` (250 um lenslets,
      f = 1.5 mm, n = 1.5, 2.5 um pitch), ``d = 1.6`` mm (lenslets focus a source at
      ~24 mm onto the sensor: ``1/d = 1/f - 1/z``).

    Parameters
    ----------
    kind : {"smooth", "microlens"}
    seed : int
        Seed of the diffuser surface.

    Returns
    -------
    LenslessGeometry
    """
    sensor, pitch_um, z_fill = (256, 320), 13.0, 20.0
    sw, sh = sensor[1] * pitch_um * 1e-3, sensor[0] * pitch_um * 1e-3
    surface = diffuser_for_sensor(kind, (sw, sh), seed)
    d = 8.9 if kind == "smooth" else 1.6
    x, y = surface.coordinates_mm()
    tan_dev = np.tan(surface.deflection_rad())
    in_x, in_y = np.abs(x) <= sw / 2, np.abs(y) <= sh / 2
    aperture = tuple(round(v, 9) for v in (
        2 * _fit_half_aperture(x[in_x], tan_dev[0][in_y][:, in_x], 0, sw / 2, d, z_fill),
        2 * _fit_half_aperture(y[in_y], tan_dev[1][in_y][:, in_x], 1, sh / 2, d, z_fill),
    ))
    return LenslessGeometry(surface, d, aperture, sensor, pitch_um, 20.0)


def microscope_geometry(seed: int = 0, *, sensor_shape: tuple[int, int] = (135, 240),
                        sensor_pitch_um: float = 23.2) -> LenslessGeometry:
    """The diffuser fluorescence microscope of Ch. 6 (Sec. 6.4), as
    ``examples/bench-microscope.toml`` describes it.

    Random microlens diffuser (:meth:`DiffuserSurface.random_microlens`: 250 um
    lenslets, f = 1.5 mm) ``d = 3.8`` mm in front of a backside-illuminated sensor
    with a Gaussian angular fall-off of sigma 13 deg; the aperture is the whole
    sensor-sized diffuser. Default sensor: the IMX290 (1080 x 1920 at 2.9 um)
    binned 8 x 8, 135 x 240 at 23.2 um (3.1 x 5.6 mm). Objects sit 1.7-3 mm in
    front of the diffuser (the lenslets image 2.5 mm onto the sensor).

    Parameters
    ----------
    seed : int
        Seed of the lenslet layout.
    sensor_shape : (rows, cols)
    sensor_pitch_um : float

    Returns
    -------
    LenslessGeometry
    """
    rows, cols = sensor_shape
    sw, sh = cols * sensor_pitch_um * 1e-3, rows * sensor_pitch_um * 1e-3
    surface = diffuser_for_sensor("microlens", (sw, sh), seed)
    return LenslessGeometry(surface, 3.8, (round(sw, 9), round(sh, 9)), (rows, cols),
                            sensor_pitch_um, 13.0)

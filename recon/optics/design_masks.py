"""The four mask designs of the diffuser microscope's design study (Kuo 2020, Sec. 6.3).

Sec. 6.3 compares, on a small patch of the field of view (one PSF per depth), a
traditional microscope objective with three flat transparent masks placed
``d`` in front of the sensor: a smooth diffuser, a regular microlens array and the
random microlens diffuser (Fig. 6.2, 6.3). :class:`MaskDesign` builds each of them
with the microscope's numbers (``examples/bench-microscope.toml``: lenslets about
250 um, focal length about 1.5 mm, ``d = 3.8`` mm, 520 nm, backside-illuminated
sensor with a Gaussian fall-off of sigma 13 deg) and renders their PSFs:

* ``"random"``: :meth:`DiffuserSurface.random_microlens` (Poisson-disc lenslets);
* ``"regular"``: :meth:`DiffuserSurface.regular_microlens` (the same lenslets on a
  square lattice of period ``lenslet_um``);
* ``"smooth"``: :meth:`DiffuserSurface.smooth_random`, a random smooth surface of
  the lenslets' feature size whose mean slope is chosen so that its bumps have the
  lenslets' focal power (mean slope ``arctan(lenslet_um / (4 (n - 1) f))``: a
  Gaussian bump of 1/e radius ``a`` and height ``A`` has apex curvature
  ``2 A / a^2`` and mean slope about ``A / a``), so its caustics form near the
  sensor for objects in the lenslets' focal range (the fair comparison: same
  working distance);
* ``"objective"``: an ideal thin lens of focal length ``1 / (1/z_focus + 1/d)``
  ``d`` in front of the sensor, imaging the plane ``z_focus`` (default: the plane
  the lenslets image, ``1 / (1/f - 1/d)``) with the same magnification ``d / z``
  as the lenslets, its aperture set by an object-side numerical aperture (0.15,
  the 5x objective of Fig. 6.6).

The flat masks are ray traced by :class:`recon.optics.lensless.LenslessModel`
(refraction by the surface, inverse square law, obliquity, the pixel fall-off);
the objective by the paraxial thin-lens ray map ``t_out = t_in - a / f``. Both are
geometric; diffraction is added as a Gaussian blur of standard deviation
``0.42 lambda N`` (the Airy core), ``N = d / D`` with ``D`` the lenslet (or the
smooth surface's feature, or the objective's aperture) diameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import ReconInputError
from .diffuser import DiffuserSurface
from .lensless import LenslessModel
from .lensless_geometry import (
    LenslessGeometry,
    oversample_factor,
    positive_number,
    source_position,
)

__all__ = ["DESIGNS", "MaskDesign", "bin_fine"]

#: The designs of Sec. 6.3, in the order of Fig. 6.2.
DESIGNS = ("objective", "smooth", "regular", "random")

#: Rays per axis across the objective's aperture disk.
_LENS_RAYS = 401


@dataclass(frozen=True)
class MaskDesign:
    """One mask design of Sec. 6.3 in front of a sensor patch, and its PSFs.

    Parameters
    ----------
    kind : {"objective", "smooth", "regular", "random"}
    sensor_shape : (rows, cols)
        Sensor patch, pixels (>= 8 each).
    pitch_um : float
        Sensor pixel pitch, um (default 23.2: the IMX290 binned 8 x 8, as the
        microscope bench).
    d_mm : float
        Mask-to-sensor distance, mm.
    lenslet_um, focal_mm : float
        Lenslet size (the lattice period, or the mean nearest-neighbour spacing of
        the random lenslets) and focal length; the smooth diffuser takes its feature
        size and focal power from them.
    wavelength_nm : float
        For the diffraction blur.
    falloff_sigma_deg : float or None
        Pixel angular response of the flat masks (Eq. 5.1); None: off.
    objective_na : float
        Object-side numerical aperture of the objective, in (0, 1).
    z_focus_mm : float, optional
        Plane the objective images; default the lenslets' conjugate plane
        ``1 / (1/f - 1/d)``.
    seed : int
        Seed of the random surfaces.

    Raises
    ------
    ReconInputError
        An unknown kind, non-positive sizes, lenslets that cannot focus before the
        sensor (``f >= d``), a numerical aperture outside (0, 1).
    """

    kind: str
    sensor_shape: tuple[int, int] = (128, 128)
    pitch_um: float = 23.2
    d_mm: float = 3.8
    lenslet_um: float = 250.0
    focal_mm: float = 1.5
    wavelength_nm: float = 520.0
    falloff_sigma_deg: float | None = 13.0
    objective_na: float = 0.15
    z_focus_mm: float | None = None
    seed: int = 0

    def __post_init__(self):
        if self.kind not in DESIGNS:
            raise ReconInputError(f"unknown mask design {self.kind!r}; use one of "
                                  f"{', '.join(DESIGNS)}")
        rows, cols = (int(v) for v in self.sensor_shape)
        if rows < 8 or cols < 8:
            raise ReconInputError(f"sensor patch {self.sensor_shape} is too small; give at "
                                  "least 8 x 8 pixels, e.g. (128, 128)")
        object.__setattr__(self, "sensor_shape", (rows, cols))
        for name, example in (("pitch_um", "23.2"), ("d_mm", "3.8"), ("lenslet_um", "250"),
                              ("focal_mm", "1.5"), ("wavelength_nm", "520")):
            object.__setattr__(self, name, positive_number(getattr(self, name), name, example))
        if self.focal_mm >= self.d_mm:
            raise ReconInputError(
                f"lenslet focal length {self.focal_mm:g} mm >= mask-to-sensor distance "
                f"{self.d_mm:g} mm: no object plane is imaged onto the sensor; use f < d "
                "(e.g. f = 1.5 mm, d = 3.8 mm)")
        if not 0.0 < float(self.objective_na) < 1.0:
            raise ReconInputError(f"objective_na {self.objective_na!r} must be in (0, 1); "
                                  "e.g. 0.15")
        if self.z_focus_mm is not None:
            object.__setattr__(self, "z_focus_mm",
                               positive_number(self.z_focus_mm, "z_focus_mm", "2.5"))

    # ------------------------------------------------------------------ geometry
    @property
    def conjugate_z_mm(self) -> float:
        """Object distance the lenslets image onto the sensor, ``1 / (1/f - 1/d)``, mm."""
        return 1.0 / (1.0 / self.focal_mm - 1.0 / self.d_mm)

    @property
    def focus_z_mm(self) -> float:
        """Plane the objective images (``z_focus_mm`` or :attr:`conjugate_z_mm`), mm."""
        return self.conjugate_z_mm if self.z_focus_mm is None else self.z_focus_mm

    @property
    def sensor_size_mm(self) -> tuple[float, float]:
        """(width_mm, height_mm) of the sensor patch."""
        rows, cols = self.sensor_shape
        return cols * self.pitch_um * 1e-3, rows * self.pitch_um * 1e-3

    @property
    def objective_diameter_mm(self) -> float:
        """Aperture diameter of the objective: ``2 z_focus tan(asin NA)``, mm."""
        return 2.0 * self.focus_z_mm * math.tan(math.asin(float(self.objective_na)))

    @property
    def sub_aperture_um(self) -> float:
        """Diameter that sets the diffraction blur (module docstring), um."""
        return self.objective_diameter_mm * 1e3 if self.kind == "objective" else self.lenslet_um

    def surface(self) -> DiffuserSurface:
        """The flat mask's surface, covering the sensor patch plus one lenslet.

        Raises
        ------
        ReconInputError
            For the objective (it is no flat mask).
        """
        w, h = self.sensor_size_mm
        size = (w + 2 * self.lenslet_um * 1e-3, h + 2 * self.lenslet_um * 1e-3)
        pitch = min(2.5, self.lenslet_um / 20)
        if self.kind == "random":
            return DiffuserSurface.random_microlens(size, pitch, self.lenslet_um,
                                                    self.focal_mm, seed=self.seed)
        if self.kind == "regular":
            return DiffuserSurface.regular_microlens(size, pitch, self.lenslet_um,
                                                     self.focal_mm)
        if self.kind == "smooth":
            n = 1.5
            slope = math.degrees(math.atan(self.lenslet_um * 1e-3 / (4 * (n - 1)
                                                                      * self.focal_mm)))
            return DiffuserSurface.smooth_random(size, pitch_um=min(5.0, self.lenslet_um / 10),
                                                 feature_um=self.lenslet_um, slope_deg=slope,
                                                 refractive_index=n, seed=self.seed)
        raise ReconInputError("the objective is a lens, not a flat mask; it has no surface")

    @cached_property
    def _surface(self) -> DiffuserSurface:
        return self.surface()

    def geometry(self, oversample: int = 1) -> LenslessGeometry:
        """The flat mask's :class:`LenslessGeometry` (aperture: the sensor patch), on a
        sensor ``oversample`` times finer (same size, smaller pixels)."""
        ov = oversample_factor(oversample)
        w, h = self.sensor_size_mm
        rows, cols = self.sensor_shape
        return LenslessGeometry(self._surface, self.d_mm, (round(w, 9), round(h, 9)),
                                (rows * ov, cols * ov), self.pitch_um / ov,
                                self.falloff_sigma_deg)

    # ------------------------------------------------------------------ PSFs
    def psf(self, source_xyz_mm, oversample: int = 1, *, registered: bool = True
            ) -> np.ndarray:
        """PSF of a point source on a grid ``oversample`` times finer than the sensor.

        Parameters
        ----------
        source_xyz_mm : (x, y, z)
            Source position, mm (z > 0 in front of the mask or lens).
        oversample : int
            Fine-grid factor; the result is NOT binned (:func:`bin_fine` sums it to
            sensor pixels).
        registered : bool
            Centre the pattern as for an on-axis source (Eq. 5.2, the paraxial shift
            ``-(x, y) d / z``), see :meth:`LenslessModel.psf`.

        Returns
        -------
        ndarray, float64, shape (rows * oversample, cols * oversample)
            Fraction of the source's power detected per fine pixel (geometric optics
            plus the diffraction blur of the module docstring). The mask's surface is
            built on the first call and kept.

        Raises
        ------
        ReconInputError
            A bad source position or oversample factor.
        """
        from scipy.ndimage import gaussian_filter

        src = source_position(source_xyz_mm)
        ov = oversample_factor(oversample)
        if self.kind == "objective":
            fine = self._lens_psf(src, ov, registered)
        else:
            fine = LenslessModel(self.geometry(ov)).psf(src, 1, registered=registered)
        sigma_um = 0.42 * self.wavelength_nm * 1e-3 * self.d_mm * 1e3 / self.sub_aperture_um
        return gaussian_filter(fine, sigma_um / (self.pitch_um / ov), mode="constant")

    def psf_stack(self, depths_mm, oversample: int = 1) -> np.ndarray:
        """PSFs of the convolution model at ``depths_mm`` (fine grid, not binned).

        The source sits half a sensor pixel off the axis in x and y, so that its
        pattern is centred on sensor pixel ``(rows // 2, cols // 2)``, the pixel
        :class:`recon.volume.VolumeConvolutionOperator` takes as zero shift (not on
        the corner between four pixels, where an in-focus spot would be split over
        2 x 2 sensor pixels).

        Returns
        -------
        ndarray, float64, shape (n_z, rows * oversample, cols * oversample)
        """
        out = []
        for z in np.atleast_1d(np.asarray(depths_mm, np.float64)):
            off = -0.5 * self.pitch_um * 1e-3 * float(z) / self.d_mm
            out.append(self.psf((off, off, float(z)), oversample, registered=False))
        return np.stack(out)

    def _lens_psf(self, src, ov: int, registered: bool) -> np.ndarray:
        """Ideal thin lens by the paraxial ray map (module docstring), fine grid."""
        xs, ys, zs = src
        d = self.d_mm
        f = 1.0 / (1.0 / self.focus_z_mm + 1.0 / d)
        rad = self.objective_diameter_mm / 2
        t = (np.arange(_LENS_RAYS) + 0.5) / _LENS_RAYS * 2 - 1
        ax, ay = (g.ravel() * rad for g in np.meshgrid(t, t))
        keep = ax * ax + ay * ay <= rad * rad
        ax, ay = ax[keep], ay[keep]
        r2 = (ax - xs) ** 2 + (ay - ys) ** 2 + zs * zs
        weight = (2 * rad / _LENS_RAYS) ** 2 * zs / (4 * math.pi * r2 * np.sqrt(r2))
        ux = ax + d * ((ax - xs) / zs - ax / f)
        uy = ay + d * ((ay - ys) / zs - ay / f)
        if registered:
            ux, uy = ux + xs * d / zs, uy + ys * d / zs
        rows, cols = self.sensor_shape
        shape = (rows * ov, cols * ov)
        fine_pitch = self.pitch_um * 1e-3 / ov
        fx = ux / fine_pitch + (shape[1] - 1) / 2
        fy = uy / fine_pitch + (shape[0] - 1) / 2
        x0, y0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
        bx, by = fx - x0, fy - y0
        out = np.zeros(shape[0] * shape[1], np.float64)
        for dy, dx, w in ((0, 0, (1 - by) * (1 - bx)), (0, 1, (1 - by) * bx),
                          (1, 0, by * (1 - bx)), (1, 1, by * bx)):
            r, c = y0 + dy, x0 + dx
            ok = (r >= 0) & (r < shape[0]) & (c >= 0) & (c < shape[1])
            out += np.bincount(r[ok] * shape[1] + c[ok], weights=(weight * w)[ok],
                               minlength=out.size)
        return out.reshape(shape)


def bin_fine(fine: np.ndarray, oversample: int) -> np.ndarray:
    """Sum ``oversample x oversample`` blocks of the last two axes, float64.

    Parameters
    ----------
    fine : ndarray, shape (..., R * oversample, C * oversample)
    oversample : int

    Returns
    -------
    ndarray, float64, shape (..., R, C)
    """
    ov = oversample_factor(oversample)
    a = np.asarray(fine, np.float64)
    r, c = a.shape[-2] // ov, a.shape[-1] // ov
    a = a[..., :r * ov, :c * ov]
    return a.reshape(*a.shape[:-2], r, ov, c, ov).sum(axis=(-3, -1))

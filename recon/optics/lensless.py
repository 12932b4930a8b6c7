"""Ray-traced lensless (DiffuserCam) PSFs and sensor images (Kuo 2020, Ch. 3-6).

Geometry (all lengths in mm unless a name says ``_um``)::

    source (x, y, -z)        diffuser (Z = 0)          sensor (Z = d)
         *  ---- z ---->  |flat | textured|  ---- d ---->  |
                          aperture w x h, centred on the axis

The optical axis passes through the centres of the aperture and the sensor. The
diffuser (:class:`recon.optics.diffuser.DiffuserSurface`) has its flat face towards
the scene and its textured face towards the sensor (Sec. 4.3); it is treated as a
thin element. ``x`` runs along sensor columns and ``y`` along sensor rows
(increasing index); pixel ``(r, c)`` of a ``(rows, cols)`` sensor of pitch ``p`` is
centred at ``u = ((c - (cols - 1)/2) p, (r - (rows - 1)/2) p)``. No image flip is
applied: a source displaced by ``+dx`` moves its PSF by ``-dx d / z`` (Eq. 3.1,
``m = d / z``).

Physical PSF (:meth:`LenslessModel.psf`). The aperture is sampled by a regular
grid of rays (at least as fine as the diffuser samples and fine enough that
neighbouring rays land at most ``1 / rays_per_pixel`` of a fine pixel apart). Each
ray starts at the source with the exact (non-paraxial) direction towards its
aperture point and carries the photon fraction it subtends,
``dA cos(theta_s) / (4 pi r^2)`` of an isotropic source of unit power (inverse
square law and obliquity). It is refracted by the flat face and by the local slope
of the textured face (vector Snell's law, index ``n`` inside, air outside; Fresnel
losses are neglected), propagates to the sensor plane, is weighted by the pixel
angular response ``f(theta) = exp(-theta^2 / (2 sigma^2))`` (Eq. 5.1; ``theta`` is
the angle of incidence on the sensor) and is splatted bilinearly onto a grid
``oversample`` times finer than the sensor, which is then box-binned
(:func:`recon.preprocess.box_bin`) to sensor pixels. PSF values are the fraction of
the source's emitted power detected per pixel: the sum over the sensor is at most the
aperture's solid angle over ``4 pi``, and it falls off physically (about
``cos^3`` of the field angle, times ``f``) for oblique sources.

Scenes (:meth:`LenslessModel.render`). The local convolution model of Ch. 5
(Eq. 5.4-5.5): the scene is split into ``patches x patches`` regions, each region
(weighted by bilinear partition-of-unity weights) is convolved with the registered
PSF of its centre with :class:`recon.operators.ConvolutionOperator` on the fine
grid, and the sum is binned. Scene values are radiances of a Lambertian object
plane facing the camera; the output is the photon rate per pixel per unit radiance.

The geometry (:class:`LenslessGeometry`, :func:`default_geometry`,
:func:`diffuser_for_sensor`) lives in :mod:`recon.optics.lensless_geometry` and is
re-exported here; test charts and scene resampling are in :mod:`recon.scenes`.
"""

from __future__ import annotations

import logging
import math
import numbers

import numpy as np

from ..errors import ReconInputError
from ..fft import fast_padded_shape
from ..operators import ConvolutionOperator
from ..preprocess import box_bin
from ..scenes import cell_overlap, tent_weights, usaf_target
from ..validate import as_int, float_array
from .lensless_geometry import (
    LenslessGeometry,
    default_geometry,
    diffuser_for_sensor,
    microscope_geometry,
    oversample_factor,
    positive_number,
    size_pair_mm,
    source_position,
)

logger = logging.getLogger(__name__)

__all__ = [
    "LenslessGeometry",
    "LenslessModel",
    "plane_on_object_grid",
    "default_geometry",
    "diffuser_for_sensor",
    "microscope_geometry",
]

_MAX_RAYS = 60_000_000


# ----------------------------------------------------------------------------- model
class LenslessModel:
    """Physical PSFs and sensor images of a :class:`LenslessGeometry`.

    Parameters
    ----------
    geometry : LenslessGeometry
    rays_per_pixel : float
        Ray density: neighbouring rays land at most ``1 / rays_per_pixel`` fine
        pixels apart (paraxially), i.e. at least ``rays_per_pixel^2`` rays per fine
        pixel under uniform illumination. Default 2.

    Notes
    -----
    Ray tracing is deterministic (a regular ray grid, a fixed split of the work
    into chunks). The numba kernel compiles on first use (cached on disk).
    """

    def __init__(self, geometry: LenslessGeometry, rays_per_pixel: float = 2.0):
        if not isinstance(geometry, LenslessGeometry):
            raise ReconInputError("geometry must be a LenslessGeometry (see default_geometry)")
        self.geometry = geometry
        self.rays_per_pixel = positive_number(rays_per_pixel, "rays_per_pixel", "2.0")
        g = geometry.surface.slopes()
        self._gx = np.ascontiguousarray(g[0])
        self._gy = np.ascontiguousarray(g[1])

    # ------------------------------------------------------------------ geometry helpers
    def magnification(self, z_mm: float) -> float:
        """Paraxial magnification ``m = d / z`` (Eq. 3.1)."""
        z = positive_number(z_mm, "z_mm", "30.0")
        return self.geometry.d_mm / z

    def sensor_shift_mm(self, source_xyz_mm) -> tuple[float, float]:
        """Lateral PSF shift ``-(x, y) d / z`` (mm) of a source, relative to on-axis."""
        x, y, z = source_position(source_xyz_mm)
        m = self.geometry.d_mm / z
        return -x * m, -y * m

    def min_z_mm(self) -> float:
        """See :meth:`LenslessGeometry.min_z_mm`."""
        return self.geometry.min_z_mm()

    def ray_grid(self, z_mm: float, oversample: int = 2) -> tuple[int, int]:
        """Rays (nx, ny) across the aperture for sources at depth ``z_mm``."""
        geo = self.geometry
        z = positive_number(z_mm, "z_mm", "30.0")
        ov = oversample_factor(oversample)
        fine_pitch = geo.sensor_pitch_um * 1e-3 / ov
        pitch = min(geo.surface.pitch_um * 1e-3,
                    fine_pitch / (self.rays_per_pixel * (1.0 + geo.d_mm / z)))
        aw, ah = geo.aperture_mm
        nx, ny = int(math.ceil(aw / pitch - 1e-9)), int(math.ceil(ah / pitch - 1e-9))
        if nx * ny > _MAX_RAYS:
            raise ReconInputError(
                f"{nx} x {ny} rays are too many; lower oversample or rays_per_pixel, or use a "
                "coarser diffuser pitch"
            )
        return nx, ny

    # ------------------------------------------------------------------ tracing
    def _trace(self, sources, powers, ov: int, offset_mm=(0.0, 0.0)) -> np.ndarray:
        """Fine-grid image (rows * ov, cols * ov) float64 of point sources."""
        from . import _raytrace

        geo = self.geometry
        rows, cols = geo.sensor_shape
        fine_pitch = geo.sensor_pitch_um * 1e-3 / ov
        out = np.zeros((_raytrace.CHUNKS, rows * ov, cols * ov), np.float64)
        if geo.falloff_sigma_deg is None:
            inv2s2 = 0.0
        else:
            inv2s2 = 1.0 / (2.0 * math.radians(geo.falloff_sigma_deg) ** 2)
        aw, ah = geo.aperture_mm
        for (x, y, z), p in zip(sources, powers, strict=True):
            if p == 0.0:
                continue
            nx, ny = self.ray_grid(z, ov)
            _raytrace.trace(self._gx, self._gy, geo.surface.pitch_um * 1e-3,
                            geo.surface.refractive_index, x, y, z, float(p), geo.d_mm,
                            aw / 2, ah / 2, nx, ny, inv2s2, fine_pitch,
                            float(offset_mm[0]), float(offset_mm[1]), out)
        return out.sum(axis=0)

    @staticmethod
    def _bin(fine: np.ndarray, ov: int) -> np.ndarray:
        """Sum ``ov x ov`` blocks (box_bin averages, times ov^2), float64."""
        if ov == 1:
            return np.asarray(fine, np.float64)
        return box_bin(fine, ov).astype(np.float64) * float(ov * ov)

    def psf(self, source_xyz_mm, oversample: int = 2, *, registered: bool = False
            ) -> np.ndarray:
        """Physical PSF of a point source by ray tracing (see the module docstring).

        Parameters
        ----------
        source_xyz_mm : (x, y, z)
            Source position, mm: ``z`` > 0 is the distance in front of the diffuser
            along the axis, ``x`` (along sensor columns) and ``y`` (rows) lateral.
        oversample : int
            Render on a grid this many times finer than the sensor, then box-bin.
        registered : bool
            If True, render on a sensor grid translated by the paraxial shift
            ``-(x, y) d / z`` (Eq. 5.2 with ``s = 1``), so the pattern stays centred as
            for an on-axis source: the registered PSF of the local convolution model
            (nothing is clipped by the real sensor edge).

        Returns
        -------
        ndarray, float64, shape (rows, cols)
            Fraction of the source's emitted power (isotropic, unit power) detected
            in each pixel, including the pixel fall-off ``f`` (dimensionless;
            float32 rounding from the binning, relative 6e-8).

        Raises
        ------
        ReconInputError
            A source not in front of the diffuser (z <= 0), non-finite coordinates,
            a bad oversample.
        """
        src = source_position(source_xyz_mm)
        ov = oversample_factor(oversample)
        off = self.sensor_shift_mm(src) if registered else (0.0, 0.0)
        return self._bin(self._trace([src], [1.0], ov, off), ov)

    def render_points(self, points_xyz_mm, intensities, oversample: int = 2) -> np.ndarray:
        """Sensor image of incoherent point sources (beads) in 3D: ``sum_k P_k h_k``.

        Parameters
        ----------
        points_xyz_mm : array_like, shape (N, 3)
            Source positions (x, y, z) in mm, each with z > 0.
        intensities : array_like, shape (N,)
            Emitted power of each source (any unit, >= 0); the image is in that unit
            per pixel (see :meth:`psf`).
        oversample : int

        Returns
        -------
        ndarray, float64, shape (rows, cols)
        """
        pts = float_array(points_xyz_mm, "points", ndims=None, finite=False)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ReconInputError(
                f"points must have shape (N, 3) of (x, y, z) in mm, got {pts.shape}")
        power = float_array(intensities, "intensities", ndims=None, finite=False).reshape(-1)
        if power.shape[0] != pts.shape[0]:
            raise ReconInputError(
                f"{power.shape[0]} intensities for {pts.shape[0]} points; give one per point")
        if not np.all(np.isfinite(power)) or np.any(power < 0):
            raise ReconInputError("intensities must be finite and non-negative")
        sources = [source_position(p) for p in pts]
        ov = oversample_factor(oversample)
        return self._bin(self._trace(sources, power, ov), ov)

    # ------------------------------------------------------------------ brightness
    def brightness(self, x_mm, y_mm, z_mm: float, samples: int = 48) -> np.ndarray:
        """Detected power fraction of point sources, ignoring the diffuser's deflection.

        ``b(x, y, z) = 1/(4 pi) int_aperture f(theta) z / r^3 dA`` with ``r`` the
        distance from the source to the aperture point and ``theta`` the angle of
        that undeflected ray to the axis (midpoint rule on ``samples^2`` points):
        the total of the registered PSF up to the small redistribution of the
        fall-off by the deflections, i.e. the two-part model's brightness term
        (Eq. 5.1, ``cos^3``-like times ``f``).

        Parameters
        ----------
        x_mm, y_mm : array_like, same shape
            Lateral source positions, mm.
        z_mm : float
            Source depth, mm (> 0).
        samples : int
            Aperture samples per axis (>= 1).

        Returns
        -------
        ndarray, float64, shape of ``x_mm``

        Raises
        ------
        ReconInputError
            Positions that are not finite real numbers of one shape, ``z_mm`` not a
            positive number, ``samples`` not an integer >= 1.
        """
        geo = self.geometry
        z = positive_number(z_mm, "z_mm", "30.0")
        samples = as_int(samples, "samples", 1)
        x = float_array(x_mm, "x_mm", ndims=None)
        y = float_array(y_mm, "y_mm", ndims=None)
        if x.shape != y.shape:
            raise ReconInputError(f"x_mm and y_mm must have one shape, got {x.shape} and "
                                  f"{y.shape}")
        aw, ah = geo.aperture_mm
        ax = ((np.arange(samples) + 0.5) / samples - 0.5) * aw
        ay = ((np.arange(samples) + 0.5) / samples - 0.5) * ah
        da = aw * ah / samples**2
        out = np.empty(x.shape, np.float64)
        xf, yf, of = x.reshape(-1), y.reshape(-1), out.reshape(-1)
        step = max(1, 2_000_000 // samples**2)
        for k in range(0, xf.size, step):
            dx = ax[None, None, :] - xf[k:k + step, None, None]
            dy = ay[None, :, None] - yf[k:k + step, None, None]
            r2 = dx * dx + dy * dy + z * z
            w = z / (r2 * np.sqrt(r2))
            if geo.falloff_sigma_deg is not None:
                th = np.arccos(z / np.sqrt(r2))
                w = w * np.exp(-th * th / (2.0 * math.radians(geo.falloff_sigma_deg) ** 2))
            of[k:k + step] = w.sum(axis=(1, 2)) * da / (4.0 * math.pi)
        return out

    def _brightness_map(self, pos_x, pos_y, fov, z, nodes: int = 33) -> np.ndarray:
        """:meth:`brightness` on the object grid: exact on a ``nodes x nodes`` grid over
        the field of view, bilinear in between, constant beyond it (zero scene)."""
        from scipy.ndimage import map_coordinates

        gx = np.linspace(-fov[0] / 2, fov[0] / 2, nodes)
        gy = np.linspace(-fov[1] / 2, fov[1] / 2, nodes)
        xx, yy = np.meshgrid(gx, gy)
        coarse = self.brightness(xx, yy, z)
        fx = np.clip((pos_x + fov[0] / 2) / fov[0] * (nodes - 1), 0, nodes - 1)
        fy = np.clip((pos_y + fov[1] / 2) / fov[1] * (nodes - 1), 0, nodes - 1)
        yy, xx = np.meshgrid(fy, fx, indexing="ij")
        return map_coordinates(coarse, [yy, xx], order=1, mode="nearest")

    # ------------------------------------------------------------------ scenes
    def render(self, scene, z_mm: float, field_of_view_mm, oversample: int = 2,
               patches: int = 3) -> np.ndarray:
        """Sensor image of a planar scene with spatial variance (local convolution).

        The scene is a Lambertian object plane at depth ``z_mm`` facing the camera,
        centred on the axis, pixel ``(i, j)`` covering a rectangle of the lateral
        extent (rows along y, columns along x; constant radiance over the pixel). An
        element of area ``A`` and radiance ``L`` sends intensity ``L A cos(theta)``
        towards the diffuser, the same as an isotropic point source of power
        ``4 pi L A cos(theta)`` (``theta``: its field angle), so the image is

            b = bin( sum_i C F^-1 diag(F P h~_i / B_i) F diag(alpha_i B) y ),  (Eq. 5.5)

        where ``y`` is the scene resampled (exact area overlap) onto the fine object
        grid of spacing ``fine_pitch z / d`` (Eq. 3.3, flipped: ``u = -m x``) times
        ``4 pi cos(theta)``, ``alpha_i`` are bilinear partition-of-unity weights of
        the ``patches x patches`` region centres (tents in each axis, constant
        beyond the outer centres), ``h~_i`` is the registered ray-traced PSF of
        region centre ``i`` (``psf(..., registered=True)`` on the fine grid), and
        ``B`` is the smooth brightness term of the two-part model (Eq. 5.1,
        :meth:`brightness`: inverse square, obliquity and pixel fall-off) evaluated
        per object point (``B_i`` at the region centres). Only the normalised caustic
        pattern is interpolated between regions, so brightness is right everywhere
        and a point at a region centre images exactly to its ray-traced PSF. The
        convolutions are :class:`recon.operators.ConvolutionOperator` forward passes
        on the fine grid (padded twice the fine sensor, so nothing wraps and every
        object point whose PSF can reach the sensor is represented); the operator
        is built per region because each region has its own PSF.

        Parameters
        ----------
        scene : ndarray, shape (rows_s, cols_s)
            Non-negative radiance (any unit, e.g. photons / s / mm^2 / sr).
        z_mm : float
            Depth of the scene plane in front of the diffuser, mm (> 0).
        field_of_view_mm : float or (width_mm, height_mm)
            Lateral extent covered by the scene; a scalar is the width, the height
            following from square scene pixels.
        oversample : int
            Fine grid factor (render finer, then bin).
        patches : int
            Regions per axis of the local convolution model; 1 is the shift-invariant
            convolution model (Eq. 3.3) with the on-axis PSF.

        Returns
        -------
        ndarray, float64, shape (rows, cols)
            Photon rate per pixel per unit scene radiance (scene unit times mm^2 sr).
        """
        geo = self.geometry
        y = float_array(scene, "scene", finite=False)
        if y.ndim != 2 or min(y.shape) < 1:
            raise ReconInputError(f"scene must be a 2D image (rows, cols), got shape {y.shape}")
        if not np.all(np.isfinite(y)) or np.any(y < 0):
            raise ReconInputError("scene radiance must be finite and non-negative")
        z = positive_number(z_mm, "scene depth z_mm", "30.0")
        if isinstance(field_of_view_mm, numbers.Real) and not isinstance(field_of_view_mm,
                                                                          bool):
            fw = positive_number(field_of_view_mm, "field of view", "10.0")
            fov = (fw, fw * y.shape[0] / y.shape[1])
        else:
            fov = size_pair_mm(field_of_view_mm, "field of view", "(12.0, 10.0)")
        ov = oversample_factor(oversample)
        if isinstance(patches, bool) or not isinstance(patches, numbers.Integral) or patches < 1:
            raise ReconInputError(f"patches must be an integer >= 1, got {patches!r}; e.g. 3")
        patches = int(patches)
        rows, cols = geo.sensor_shape
        fine_shape = (rows * ov, cols * ov)
        padded = fast_padded_shape(fine_shape)
        q = geo.sensor_pitch_um * 1e-3 / ov * z / geo.d_mm  # object cell, mm
        pos_y = -(np.arange(padded[0]) - padded[0] // 2) * q
        pos_x = -(np.arange(padded[1]) - padded[1] // 2) * q
        ry = cell_overlap(np.linspace(-fov[1] / 2, fov[1] / 2, y.shape[0] + 1), pos_y, q)
        rx = cell_overlap(np.linspace(-fov[0] / 2, fov[0] / 2, y.shape[1] + 1), pos_x, q)
        obj = ry @ y @ rx.T  # radiance x area, mm^2
        cos_t = z / np.sqrt(pos_y[:, None] ** 2 + pos_x[None, :] ** 2 + z * z)
        obj *= 4.0 * math.pi * cos_t
        if not np.any(obj):
            return np.zeros(geo.sensor_shape, np.float64)
        cx = (np.arange(patches) + 0.5) / patches * fov[0] - fov[0] / 2
        cy = (np.arange(patches) + 0.5) / patches * fov[1] - fov[1] / 2
        # the slowly varying brightness (1/r^2, obliquity, pixel fall-off) is applied
        # per object point; only the normalised caustic pattern is interpolated
        obj *= self._brightness_map(pos_x, pos_y, fov, z)
        wx, wy = tent_weights(pos_x, cx), tent_weights(pos_y, cy)
        out = np.zeros(fine_shape, np.float64)
        for a in range(patches):
            if not np.any(wy[a][:, None] * obj):
                continue
            for b in range(patches):
                part = (wy[a][:, None] * wx[b][None, :]) * obj
                if not np.any(part):
                    continue
                src = (float(cx[b]), float(cy[a]), z)
                kernel = self._trace([src], [1.0], ov, self.sensor_shift_mm(src))
                norm = float(self.brightness(np.array([cx[b]]), np.array([cy[a]]), z)[0])
                if not np.any(kernel) or norm <= 0:
                    continue
                scale = float(kernel.max())
                op = ConvolutionOperator((kernel / scale).astype(np.float32),
                                         padded_shape=padded)
                out += (scale / norm) * op.forward(part.astype(np.float32)).astype(np.float64)
        np.maximum(out, 0.0, out=out)  # FFT round-off below zero
        return self._bin(out, ov)

    def scene_truth(self, scene, z_mm: float, width_mm: float,
                    sensor_shape: tuple[int, int] | None = None) -> np.ndarray:
        """A planar scene as a reconstruction on the object grid of Eq. 3.3 should show it.

        The object grid samples the plane at ``pitch z / d`` with the image inverted
        (u = -m x); the scene is area-resampled onto it (anti-aliased), flipped and
        centred in the sensor's field of view: what :meth:`render`'s scene is scored
        against.

        Parameters
        ----------
        scene : ndarray, (rows_s, cols_s)
            Radiance (any unit), as given to :meth:`render`.
        z_mm : float
            Depth of the scene plane, mm.
        width_mm : float
            Lateral width the scene covers, mm (its height from square pixels).
        sensor_shape : (rows, cols), optional
            Default the geometry's.

        Returns
        -------
        ndarray, float64, ``sensor_shape``
        """
        geo = self.geometry
        return plane_on_object_grid(scene, z_mm, width_mm, geo.d_mm, geo.sensor_pitch_um,
                                    sensor_shape or geo.sensor_shape)

    def render_tilted_target(self, z_near_mm: float, z_far_mm: float, field_of_view_mm,
                             target: np.ndarray | None = None, slices: int = 4,
                             oversample: int = 2, patches: int = 1) -> np.ndarray:
        """Sensor image of a resolution target tilted in depth about the x axis.

        The target's top row (row 0) is at ``z_near_mm`` and its bottom row at
        ``z_far_mm``, depth varying linearly with the row; ``field_of_view_mm`` is the
        lateral (projected) extent. It is rendered as ``slices`` depth slices at
        equally spaced depths: each row is shared between its two nearest slice
        depths with linear weights (a partition of unity), and each slice is
        :meth:`render`-ed at its depth.

        Parameters
        ----------
        z_near_mm, z_far_mm : float
            Depths (mm, > 0) of the top and bottom rows.
        field_of_view_mm : float or (width_mm, height_mm)
        target : ndarray (rows_t, cols_t), optional
            Radiance pattern; default :func:`recon.scenes.usaf_target` ``((256, 256))``.
        slices : int
            Depth slices (>= 1; 1 renders everything at the mean depth).
        oversample, patches : int
            As in :meth:`render`.

        Returns
        -------
        ndarray, float64, shape (rows, cols)
        """
        z0 = positive_number(z_near_mm, "z_near_mm", "25.0")
        z1 = positive_number(z_far_mm, "z_far_mm", "40.0")
        if isinstance(slices, bool) or not isinstance(slices, numbers.Integral) or slices < 1:
            raise ReconInputError(f"slices must be an integer >= 1, got {slices!r}; e.g. 4")
        t = usaf_target((256, 256)) if target is None else np.asarray(target, np.float64)
        if t.ndim != 2:
            raise ReconInputError(f"target must be 2D, got shape {t.shape}")
        depth = z0 + (z1 - z0) * (np.arange(t.shape[0]) + 0.5) / t.shape[0]
        if slices == 1:
            zs = np.array([(z0 + z1) / 2])
        else:
            zs = np.linspace(min(z0, z1), max(z0, z1), int(slices))
        weights = tent_weights(depth, zs)
        out = np.zeros(self.geometry.sensor_shape, np.float64)
        for k, zk in enumerate(zs):
            part = t * weights[k][:, None]
            if np.any(part):
                out += self.render(part, float(zk), field_of_view_mm, oversample, patches)
        return out


def plane_on_object_grid(scene, z_mm: float, width_mm: float, d_mm: float,
                         sensor_pitch_um: float, sensor_shape: tuple[int, int]) -> np.ndarray:
    """A planar scene on the object grid of Eq. 3.3, cropped to the sensor's shape.

    The object grid samples the plane at ``pitch z / d`` with the image inverted
    (u = -m x): cell ``(i, j)`` is centred on the lateral position
    ``-((i - rows // 2), (j - cols // 2)) pitch z / d``, so the axis is the centre of
    cell ``(rows // 2, cols // 2)``, the point that images to the on-axis PSF as the
    convolution model centres it. Each cell holds the scene's mean radiance over it
    (exact area overlap of the scene's pixels, as :meth:`LenslessModel.render` resamples
    the scene onto its finer grid; no rounding of the scene's extent to whole cells):
    the object a reconstruction with the on-axis PSF shows, and the known scene of a
    PSF calibrated from displayed images (:mod:`recon.analysis.psf_from_scenes`).

    Parameters
    ----------
    scene : ndarray, (rows_s, cols_s)
        Radiance (any unit).
    z_mm : float
        Depth of the scene plane in front of the diffuser, mm.
    width_mm : float
        Lateral width the scene covers, mm (its height from square pixels).
    d_mm : float
        Diffuser-sensor distance, mm.
    sensor_pitch_um : float
        Sensor pixel pitch, um.
    sensor_shape : (rows, cols)

    Returns
    -------
    ndarray, float64, ``sensor_shape``
        Zero outside the scene, partial at its edges.

    Raises
    ------
    ReconInputError
        A depth, width, distance or pitch that is not a finite number > 0, or a
        scene that is not a 2D image.
    """
    rows, cols = sensor_shape
    z = positive_number(z_mm, "scene depth z_mm", "30.0")
    width = positive_number(width_mm, "scene width_mm", "10.0")
    d = positive_number(d_mm, "diffuser-sensor distance d_mm", "8.9")
    q = positive_number(sensor_pitch_um, "sensor pitch", "13.0") * 1e-3 * z / d
    img = np.asarray(scene, float)
    if img.ndim != 2 or min(img.shape) < 1:
        raise ReconInputError(f"scene must be a 2D image (rows, cols), got shape {img.shape}")
    height = width * img.shape[0] / img.shape[1]
    # cell centres, inverted (u = -m x); the axis at the centre of (rows // 2, cols // 2)
    pos_y = -(np.arange(rows) - rows // 2) * q
    pos_x = -(np.arange(cols) - cols // 2) * q
    ry = cell_overlap(np.linspace(-height / 2, height / 2, img.shape[0] + 1), pos_y, q)
    rx = cell_overlap(np.linspace(-width / 2, width / 2, img.shape[1] + 1), pos_x, q)
    return ry @ img @ rx.T / (q * q)

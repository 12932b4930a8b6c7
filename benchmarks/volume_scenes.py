"""3D test scenes on the virtual bench's diffuser, rendered with model mismatch.

The volume accuracy benchmark (:mod:`benchmarks.volume_accuracy`) reconstructs
with the 3D model of Eq. 4.4 (on-axis PSFs at the reconstruction planes, shifted
laterally) but renders its measurements with the ray-traced optics of
:mod:`recon.optics.lensless`, never with the reconstruction operator itself:

* the camera is :func:`recon.optics.lensless.default_geometry` ("smooth": the
  virtual bench's diffuser kind, 8.9 mm from a 256 x 320 sensor of 13 um pixels,
  aperture 2.67 x 2.11 mm, the built-in bench's geometry);
* the PSF stack is what a calibration sweep measures: on-axis pinhole PSFs at the
  plane depths (uniform in 1/z, Eq. 4.7), with shot and read noise of an averaged
  capture, binned to the reconstruction grid;
* beads are point sources at arbitrary 3D positions (between planes, at sub-pixel
  lateral positions), each ray-traced where it is (:meth:`LenslessModel.render_points`:
  off-axis obliquity, fall-off and non-paraxial shifts);
* the tilted target is :meth:`LenslessModel.render_tilted_target` with the local
  convolution model of Ch. 5 (3 x 3 registered ray-traced PSFs, Eq. 5.5) over many
  depth slices on a grid twice as fine as the sensor;
* both get Poisson and read noise at the sensor, then software binning.

The reconstruction grid is the sensor binned by ``bin_factor`` (pitch ``13 um *
bin``). Positions in voxel units are ``(plane, row, col)`` on the sensor field of
view of that grid (``x[:, op.crop[0], op.crop[1]]``); a source at object ``(x, y, z)``
(mm) sits at ``row = r0 - y d / (z p)``, ``col = c0 - x d / (z p)`` (Eq. 3.1, image
flipped), ``(r0, c0)`` the voxel whose PSF is the on-axis PSF.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from recon.errors import ReconInputError
from recon.optics.lensless import LenslessModel, default_geometry
from recon.preprocess import box_bin
from recon.scenes import cell_overlap, usaf_target
from recon.simulate import add_camera_noise
from recon.volume import VolumeConvolutionOperator, bin_stack, normalize_psf_stack

#: Peak photo-electrons of an averaged calibration PSF (about 8 frames at 60 % of a
#: 4000 e- well) and of a scene measurement; read noise in electrons.
PSF_PHOTONS = 2.0e4
SCENE_PHOTONS = 5000.0
READ_NOISE_E = 2.0


@dataclass(frozen=True, eq=False)
class VolumeBench:
    """The reconstruction side of the 3D benchmark: grid, PSF stack and operator.

    Attributes
    ----------
    model : LenslessModel
        The ray-traced camera (renders the scenes).
    bin_factor : int
        Lateral binning of the reconstruction grid.
    depths_mm : ndarray, float64, shape (n_z,)
        Plane depths, ascending, uniform in 1/z.
    op : VolumeConvolutionOperator
        Eq. 4.4 with the normalised measured stack (``normalize_psf_stack``).
    pitch_mm : float
        Pixel pitch of the reconstruction grid on the sensor, mm.
    psf_snr_db : float
        SNR of the noisiest calibration PSF.
    """

    model: LenslessModel
    bin_factor: int
    depths_mm: np.ndarray
    op: VolumeConvolutionOperator
    pitch_mm: float
    psf_snr_db: float

    @property
    def d_mm(self) -> float:
        """Diffuser-to-sensor distance, mm."""
        return self.model.geometry.d_mm

    @property
    def centre(self) -> tuple[int, int]:
        """``(r0, c0)``: the sensor-grid voxel of an on-axis source (padded P // 2)."""
        p0, p1 = self.op.padded_shape
        top, left = self.op.offset
        return p0 // 2 - top, p1 // 2 - left

    def plane_of(self, z_mm) -> np.ndarray:
        """Fractional plane index of depths, linear in 1/z between planes.

        Raises
        ------
        ReconInputError
            A depth outside the planes' range.
        """
        z = np.asarray(z_mm, np.float64)
        lo, hi = self.depths_mm[0], self.depths_mm[-1]
        if np.any(z < lo - 1e-9) or np.any(z > hi + 1e-9):
            raise ReconInputError(f"depths must lie within the planes, {lo:g}-{hi:g} mm")
        inv = 1.0 / self.depths_mm  # descending
        return np.interp(-1.0 / z, -inv, np.arange(inv.size, dtype=np.float64))

    def depth_of(self, plane) -> np.ndarray:
        """Depth (mm) of fractional plane indices (linear in 1/z; ends extrapolated)."""
        p = np.asarray(plane, np.float64)
        inv = 1.0 / self.depths_mm
        k = np.clip(np.floor(p).astype(int), 0, max(inv.size - 2, 0))
        step = inv[np.minimum(k + 1, inv.size - 1)] - inv[k]
        return 1.0 / (inv[k] + (p - k) * step)

    def voxel_of(self, xyz_mm) -> np.ndarray:
        """``(plane, row, col)`` voxel positions, shape (n, 3), of sources (n, 3) in mm."""
        pts = np.asarray(xyz_mm, np.float64).reshape(-1, 3)
        m = self.d_mm / (pts[:, 2] * self.pitch_mm)
        r0, c0 = self.centre
        return np.stack([self.plane_of(pts[:, 2]), r0 - pts[:, 1] * m, c0 - pts[:, 0] * m],
                        axis=1)

    def voxel_size_mm(self, z_mm) -> np.ndarray:
        """Object-space lateral voxel size ``p z / d`` at depth ``z_mm``, mm."""
        return self.pitch_mm * np.asarray(z_mm, np.float64) / self.d_mm


@dataclass(frozen=True)
class VolumeScene:
    """A rendered measurement and its truth.

    Attributes
    ----------
    b : ndarray, float32, shape (rows, cols)
        Measurement on the reconstruction grid, scaled by its largest magnitude
        (the scaled problem of :func:`recon.api.scaled_problem`).
    snr_db : float
        SNR at the sensor (before binning).
    truth_xyz_mm : ndarray (n, 3) or None
        Bead positions (beads).
    truth_voxels : ndarray (n, 3) or None
        Bead positions in voxel units (beads).
    truth_volume : ndarray (n_z, rows, cols) or None
        Ground truth on the sensor field of view of the grid (tilted target):
        isotropic-equivalent source power per voxel (Lambertian radiance times
        voxel area times ``4 pi cos(theta)``), the quantity the reconstruction
        estimates up to one gain.
    info : dict
    """

    b: np.ndarray
    snr_db: float
    truth_xyz_mm: np.ndarray | None = None
    truth_voxels: np.ndarray | None = None
    truth_volume: np.ndarray | None = None
    info: dict = field(default_factory=dict)


def _int_at_least(value, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ReconInputError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def make_bench(*, bin_factor: int = 2, z_min_mm: float = 24.0, z_max_mm: float = 48.0,
               n_planes: int = 16, seed: int = 0, psf_photons: float = PSF_PHOTONS,
               read_noise_e: float = READ_NOISE_E) -> VolumeBench:
    """The 3D reconstruction set-up on the virtual bench's smooth diffuser.

    Parameters
    ----------
    bin_factor : int
        Lateral binning of the 256 x 320 sensor for the reconstruction (1, 2, 4).
    z_min_mm, z_max_mm : float
        Nearest and farthest plane, mm (``z_min_mm`` at least the geometry's
        :meth:`~recon.optics.lensless.LenslessGeometry.min_z_mm`, about 20 mm).
    n_planes : int
        Planes, uniform in 1/z (Eq. 4.7), >= 2.
    seed : int
        Seed of the diffuser surface and of the calibration noise.
    psf_photons, read_noise_e : float
        Noise of the calibration PSFs (peak electrons, read noise electrons).

    Returns
    -------
    VolumeBench

    Raises
    ------
    ReconInputError
        Bad sizes or depths (e.g. planes closer than the PSF fits on the sensor).
    """
    bf = _int_at_least(bin_factor, "bin_factor", 1)
    n = _int_at_least(n_planes, "n_planes", 2)
    model = LenslessModel(default_geometry("smooth", seed))
    z_fit = model.min_z_mm()
    if not (math.isfinite(z_min_mm) and math.isfinite(z_max_mm)
            and z_fit - 1e-6 <= z_min_mm < z_max_mm):
        raise ReconInputError(f"need {z_fit:.3g} mm <= z_min_mm < z_max_mm (the PSF must fit "
                              f"on the sensor), got {z_min_mm}, {z_max_mm}")
    depths = 1.0 / np.linspace(1.0 / z_min_mm, 1.0 / z_max_mm, n)
    rng = np.random.default_rng(seed)
    stack, snrs = [], []
    for z in depths:
        noisy, _, _, snr = add_camera_noise(model.psf((0.0, 0.0, float(z))), psf_photons,
                                            read_noise_e, rng)
        stack.append(np.clip(noisy, 0.0, None))  # preprocessing clips at zero
        snrs.append(snr)
    h, _ = normalize_psf_stack(bin_stack(np.asarray(stack, np.float32), bf))
    op = VolumeConvolutionOperator(h, depths=depths)
    pitch = model.geometry.sensor_pitch_um * 1e-3 * bf
    return VolumeBench(model, bf, depths, op, pitch, float(min(snrs)))


def _measure(bench: VolumeBench, clean: np.ndarray, photons: float, read_noise_e: float,
             rng: np.random.Generator) -> tuple[np.ndarray, float]:
    noisy, _, _, snr = add_camera_noise(clean, photons, read_noise_e, rng)
    b = box_bin(noisy.astype(np.float32), bench.bin_factor).astype(np.float32)
    return (b / np.float32(np.abs(b).max())).astype(np.float32), snr


def bead_scene(bench: VolumeBench, n_beads: int, *, seed: int = 0,
               field_fraction: float = 0.6, min_separation_px: float = 8.0,
               photons: float = SCENE_PHOTONS, read_noise_e: float = READ_NOISE_E
               ) -> VolumeScene:
    """Beads at random 3D positions, each ray-traced where it is, with camera noise.

    Depths are uniform in plane index between the second and the second-to-last
    plane (so "within one plane" is never decided by the volume's end); lateral
    positions uniform within ``field_fraction`` of the sensor's half field at that
    depth; pairs at least ``min_separation_px`` apart laterally on the grid
    (rejection sampling); powers uniform in [0.6, 1] (relative).

    Parameters
    ----------
    bench : VolumeBench
    n_beads : int
        >= 1.
    seed : int
    field_fraction : float
        In (0, 1].
    min_separation_px : float
        >= 0, on the reconstruction grid.
    photons, read_noise_e : float
        Peak electrons of the brightest sensor pixel; read noise, electrons.

    Returns
    -------
    VolumeScene
        With ``truth_xyz_mm`` and ``truth_voxels``.

    Raises
    ------
    ReconInputError
        Bad parameters, or the beads do not fit at that separation.
    """
    n = _int_at_least(n_beads, "n_beads", 1)
    if not (0 < field_fraction <= 1 and min_separation_px >= 0):
        raise ReconInputError("field_fraction must be in (0, 1] and min_separation_px >= 0")
    rng = np.random.default_rng(seed)
    rows, cols = bench.op.sensor_shape
    n_z = bench.depths_mm.size
    lo, hi = (1.0, n_z - 2.0) if n_z >= 4 else (0.0, n_z - 1.0)
    vox, pts = [], []
    for _ in range(200 * n):
        z = float(bench.depth_of(rng.uniform(lo, hi)))
        half = np.array([cols, rows]) * 0.5 * bench.pitch_mm * z / bench.d_mm * field_fraction
        x, y = rng.uniform(-half, half)
        v = bench.voxel_of((x, y, z))[0]
        if all(math.hypot(*(v[1:] - w[1:])) >= min_separation_px for w in vox):
            vox.append(v)
            pts.append((x, y, z))
            if len(pts) == n:
                break
    else:
        raise ReconInputError(f"{n} beads do not fit {min_separation_px:g} px apart; use fewer")
    pts = np.asarray(pts, np.float64)
    powers = rng.uniform(0.6, 1.0, n)
    clean = bench.model.render_points(pts, powers)
    b, snr = _measure(bench, clean, photons, read_noise_e, rng)
    info = {"n_beads": n, "seed": seed, "powers": powers, "photons": photons,
            "read_noise_e": read_noise_e, "field_fraction": field_fraction,
            "min_separation_px": min_separation_px,
            "rendering": "ray-traced point sources at their 3D positions (render_points, "
                         "oversample 2), noise at the sensor, then binned"}
    return VolumeScene(b, snr, truth_xyz_mm=pts, truth_voxels=np.asarray(vox), info=info)


def target_truth(bench: VolumeBench, target: np.ndarray, z_near_mm: float, z_far_mm: float,
                 width_mm: float) -> np.ndarray:
    """Ground-truth volume of a tilted target on the reconstruction grid.

    Target row ``r`` (of ``R``) sits at depth ``z_near + (z_far - z_near) (r + 0.5) /
    R`` and covers ``y`` in ``[-H/2 + r H / R, -H/2 + (r + 1) H / R]``, ``H = width
    R / C`` (as :meth:`LenslessModel.render_tilted_target`). Each row is shared
    between its two nearest planes with linear weights in plane index (1/z), then
    resampled onto the plane's voxels by exact area overlap (voxel size ``p z_k /
    d``) and multiplied by ``4 pi cos(theta)``: isotropic-equivalent power per voxel
    for unit radiance.

    Parameters
    ----------
    bench : VolumeBench
    target : ndarray, shape (R, C)
        Radiance pattern, non-negative.
    z_near_mm, z_far_mm : float
        Depths of the first and last row, within the planes.
    width_mm : float
        Lateral extent of the target along x, mm.

    Returns
    -------
    ndarray, float32, shape (n_z, rows, cols)
    """
    t = np.asarray(target, np.float64)
    if t.ndim != 2 or np.any(t < 0) or not np.all(np.isfinite(t)):
        raise ReconInputError("target must be a finite, non-negative 2D image")
    n_t, m_t = t.shape
    height = width_mm * n_t / m_t
    z_rows = z_near_mm + (z_far_mm - z_near_mm) * (np.arange(n_t) + 0.5) / n_t
    frac = bench.plane_of(z_rows)
    rows, cols = bench.op.sensor_shape
    r0, c0 = bench.centre
    out = np.zeros((bench.depths_mm.size, rows, cols), np.float64)
    for k, zk in enumerate(bench.depths_mm):
        w = np.clip(1.0 - np.abs(frac - k), 0.0, None)
        if not np.any(w):
            continue
        q = float(bench.voxel_size_mm(zk))
        y = -(np.arange(rows) - r0) * q
        x = -(np.arange(cols) - c0) * q
        ry = cell_overlap(np.linspace(-height / 2, height / 2, n_t + 1), y, q)
        rx = cell_overlap(np.linspace(-width_mm / 2, width_mm / 2, m_t + 1), x, q)
        cos_t = zk / np.sqrt(y[:, None] ** 2 + x[None, :] ** 2 + zk * zk)
        out[k] = (ry @ (t * w[:, None]) @ rx.T) * 4.0 * math.pi * cos_t
    return out.astype(np.float32)


def tilted_target_scene(bench: VolumeBench, *, z_near_mm: float, z_far_mm: float,
                        width_mm: float, target: np.ndarray | None = None, slices: int = 24,
                        patches: int = 3, seed: int = 0, photons: float = SCENE_PHOTONS,
                        read_noise_e: float = READ_NOISE_E) -> VolumeScene:
    """A resolution target tilted in depth, rendered with spatial variance and noise.

    :meth:`LenslessModel.render_tilted_target` (``slices`` depth slices, the local
    convolution model with ``patches x patches`` ray-traced PSFs, twice-finer grid),
    Poisson and read noise at the sensor, binned; truth from :func:`target_truth`.

    Parameters
    ----------
    bench : VolumeBench
    z_near_mm, z_far_mm : float
        Depths of the target's first and last row (within the planes), mm.
    width_mm : float
        Lateral extent, mm.
    target : ndarray, optional
        Radiance pattern; default :func:`recon.scenes.usaf_target` 128 x 128.
    slices, patches : int
        Rendering depth slices and local-convolution regions per axis.
    seed : int
        Noise seed.
    photons, read_noise_e : float

    Returns
    -------
    VolumeScene
        With ``truth_volume``.
    """
    t = usaf_target((128, 128)) if target is None else np.asarray(target, np.float64)
    truth = target_truth(bench, t, z_near_mm, z_far_mm, width_mm)
    clean = bench.model.render_tilted_target(z_near_mm, z_far_mm, width_mm, target=t,
                                             slices=slices, oversample=2, patches=patches)
    b, snr = _measure(bench, clean, photons, read_noise_e, np.random.default_rng(seed))
    info = {"z_near_mm": z_near_mm, "z_far_mm": z_far_mm, "width_mm": width_mm,
            "target_shape": list(t.shape), "slices": slices, "patches": patches,
            "seed": seed, "photons": photons, "read_noise_e": read_noise_e,
            "rendering": f"render_tilted_target: {slices} depth slices, local convolution "
                         f"with {patches}x{patches} ray-traced PSFs (Eq. 5.5), oversample 2, "
                         "noise at the sensor, then binned"}
    return VolumeScene(b, snr, truth_volume=truth, info=info)

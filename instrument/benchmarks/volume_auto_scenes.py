"""3D scenes through the real tutorial PSF scaled per depth, with dim far planes.

The 3D automatic choices (:func:`recon.auto.volume.auto_volume`) are tested and
benchmarked on volumes whose planes differ in brightness, as a fluorescent sample's
or a scene's far planes do. The PSF stack is the real DiffuserCam tutorial PSF
(:func:`recon.sample.load_sample`) as the nearest plane, shrunk about its centre for
the farther ones by the ratio of the magnifications ``(1 + d/z) / (1 + d/z_near)``
(the caustic scales with depth, Sec. 4.2, Fig. 4.2), each plane's light scaled by
the solid angle the aperture collects, ``(z_near / z)^2``: a farther plane collects
less light. Depths are uniform in 1/z (Eq. 4.7).

Model mismatch (never the inverse crime): the measurement is rendered on a grid
twice as fine as the reconstruction's (the tutorial PSF preprocessed at half the
bin, shrunk there; objects at sub-voxel positions), box-binned, with Poisson and
Gaussian read noise at ``photons`` peak photo-electrons; the reconstruction stack
is the tutorial PSF preprocessed at the coarse bin and shrunk there (its own
interpolation), normalised by :func:`recon.volume.normalize_psf_stack`.

Scene kinds (one object per plane, at a different lateral place per plane, each
plane's source brightness falling geometrically from 1 at the nearest plane to
``1 / dim`` at the farthest):

* ``beads`` - a Gaussian spot of 0.7 fine pixels per plane;
* ``extended`` - a textured disc (a patch of a scikit-image photograph shipped in
  the package, :func:`recon.scenes.load_scene`) of radius ``0.09`` of the field per
  plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from recon.errors import ReconInputError
from recon.preprocess import box_bin
from recon.sample import load_sample
from recon.scenes import load_scene
from recon.simulate import add_camera_noise
from recon.volume import VolumeConvolutionOperator, normalize_psf_stack

__all__ = ["KINDS", "VolumeCase", "depth_plane", "depth_stack", "render_volume_case"]

#: Scene kinds of :func:`render_volume_case`.
KINDS = ("beads", "extended")
#: Diffuser-to-sensor distance (mm) and the nearest and farthest depths (mm) of the
#: magnification and light model.
D_MM, Z_NEAR_MM, Z_FAR_MM = 8.9, 20.0, 60.0


def depths_mm(n_planes: int) -> np.ndarray:
    """``n_planes`` depths uniform in 1/z from :data:`Z_NEAR_MM` to :data:`Z_FAR_MM`."""
    return 1.0 / np.linspace(1.0 / Z_NEAR_MM, 1.0 / Z_FAR_MM, n_planes)


def depth_stack(bin_factor: int, n_planes: int) -> np.ndarray:
    """The tutorial PSF at ``bin_factor``, shrunk and dimmed per depth.

    Parameters
    ----------
    bin_factor : int
        Binning of the 1200 x 1600 tutorial frames (4: 300 x 400, 8: 150 x 200).
    n_planes : int
        Planes (>= 2), nearest first (:func:`depths_mm`).

    Returns
    -------
    ndarray, float32, (n_planes, rows, cols)
        Plane ``k``: the PSF shrunk about the array centre by
        ``(1 + d/z_k) / (1 + d/z_0)`` (linear interpolation, light conserved), its sum
        ``(z_0 / z_k)^2`` of the nearest plane's.
    """
    if n_planes < 2:
        raise ReconInputError(f"n_planes must be >= 2, got {n_planes}")
    psf = np.asarray(load_sample(bin_factor).psf, np.float64)
    z = depths_mm(n_planes)
    return np.asarray([depth_plane(psf, zk, z[0]) for zk in z], np.float32)


def depth_plane(psf: np.ndarray, z_mm: float, z_near_mm: float) -> np.ndarray:
    """The nearest plane's PSF as seen from depth ``z_mm``: shrunk about the array
    centre by ``(1 + d/z) / (1 + d/z_near)`` (the caustic's magnification, Eq. 4.7;
    linear interpolation) and its sum scaled to ``(z_near / z)^2`` of ``psf``'s.

    Parameters
    ----------
    psf : ndarray, float64, 2D
        The nearest plane's PSF.
    z_mm, z_near_mm : float
        Depth of the plane and of the nearest plane, mm (``d`` is :data:`D_MM`).

    Returns
    -------
    ndarray, float64, ``psf.shape``
    """
    centre = (np.array(psf.shape, np.float64) - 1) / 2
    s = (1 + D_MM / z_mm) / (1 + D_MM / z_near_mm)  # <= 1: farther planes are smaller
    h = np.clip(ndimage.affine_transform(psf, np.eye(2) / s, centre - centre / s, order=1),
                0, None)
    return h * (psf.sum() * (z_near_mm / z_mm) ** 2 / h.sum())


@dataclass
class VolumeCase:
    """A rendered 3D case: the reconstruction model, the measurement and the truth.

    Attributes
    ----------
    op : VolumeConvolutionOperator
        Reconstruction model (coarse stack, normalised).
    b : ndarray, float32, ``op.shape_out``
        Measurement divided by its maximum (the scaled problem).
    raw_e : ndarray, float32, ``op.shape_out``
        The measurement in photo-electrons (for the noise model).
    truth : ndarray, float32, (n_z, rows, cols)
        Source power per voxel on the sensor field of view (box-binned fine scene).
    objects : list of dict
        Per object (nearest first): ``plane``, ``centre`` (row, col on the coarse field of view),
        ``radius_px`` (coarse), ``brightness`` (source brightness relative to the
        nearest plane's object).
    depths_mm : ndarray
    info : dict
        ``kind``, ``photons``, ``dim``, ``snr_db``.
    """

    op: VolumeConvolutionOperator
    b: np.ndarray
    raw_e: np.ndarray
    truth: np.ndarray
    objects: list
    depths_mm: np.ndarray
    info: dict


def _positions(n: int, shape: tuple[int, int], rng) -> list[tuple[float, float]]:
    """``n`` lateral places on a jittered grid over the central 60 % of the field."""
    cols = int(np.ceil(np.sqrt(n * shape[1] / shape[0])))
    rows = int(np.ceil(n / cols))
    out = []
    for k in range(n):
        i, j = divmod(k, cols)
        fr = 0.2 + 0.6 * (i + 0.5 + rng.uniform(-0.15, 0.15)) / rows
        fc = 0.2 + 0.6 * (j + 0.5 + rng.uniform(-0.15, 0.15)) / cols
        out.append((fr * shape[0], fc * shape[1]))
    return out


def render_volume_case(kind: str, photons: float, *, n_planes: int = 6, dim: float = 1.0,
                       coarse_bin: int = 8, read_noise_e: float = 3.0, seed: int = 0,
                       occupied=None) -> VolumeCase:
    """Render one object per plane through the depth stack, with mismatch and noise.

    Parameters
    ----------
    kind : {"beads", "extended"}
    photons : float
        Peak photo-electrons of the noise-free measurement.
    n_planes : int
        Planes (>= 2).
    dim : float
        Source brightness of the farthest plane's object is ``1 / dim`` of the
        nearest's (geometric in between; >= 1). The PSF's light model dims the far
        planes further in the measurement.
    coarse_bin : int
        Even reconstruction binning (8: 150 x 200); rendered at ``coarse_bin // 2``.
    read_noise_e : float
    seed : int
        Lateral jitter, sub-voxel positions, photo patches and noise.
    occupied : sequence of int, optional
        The planes that hold an object (default all); the others are empty.

    Returns
    -------
    VolumeCase

    Raises
    ------
    ReconInputError
        Unknown kind, odd ``coarse_bin`` or ``dim < 1``.
    """
    if kind not in KINDS:
        raise ReconInputError(f"unknown 3D scene kind {kind!r}; use one of {', '.join(KINDS)}")
    if coarse_bin < 2 or coarse_bin % 2:
        raise ReconInputError(f"coarse_bin {coarse_bin} must be even (rendered at half)")
    if not dim >= 1:
        raise ReconInputError(f"dim must be >= 1, got {dim}")
    rng = np.random.default_rng(seed)
    fine_stack = depth_stack(coarse_bin // 2, n_planes)
    coarse_stack, _ = normalize_psf_stack(depth_stack(coarse_bin, n_planes))
    op = VolumeConvolutionOperator(coarse_stack, depths=depths_mm(n_planes))
    rows, cols = op.sensor_shape
    fine_op = VolumeConvolutionOperator(
        fine_stack[:, :2 * rows, :2 * cols] / np.float32(fine_stack.sum()),
        padded_shape=tuple(2 * p for p in op.padded_shape))
    brightness = dim ** (-np.arange(n_planes) / max(n_planes - 1, 1))
    fine = np.zeros((n_planes, 2 * rows, 2 * cols), np.float64)
    yy, xx = np.mgrid[0:2 * rows, 0:2 * cols].astype(np.float64)
    objects = []
    radius = 0.09 * min(rows, cols)  # coarse pixels
    occupied = set(range(n_planes) if occupied is None else occupied)
    for k, (r, c) in enumerate(_positions(n_planes, (rows, cols), rng)):
        r, c = r + rng.uniform(-0.5, 0.5), c + rng.uniform(-0.5, 0.5)
        if k not in occupied:
            continue
        fr, fc = 2 * r + 0.5, 2 * c + 0.5  # fine coordinates of the coarse position
        if kind == "beads":
            spot = np.exp(-((yy - fr) ** 2 + (xx - fc) ** 2) / (2 * 0.7 ** 2))
            obj, rad = spot / spot.sum(), 1.5
        else:
            disc = np.hypot(yy - fr, xx - fc) <= 2 * radius
            patch = load_scene(("camera", "astronaut", "coffee", "chelsea")[k % 4],
                               (2 * rows, 2 * cols)).astype(np.float64)
            obj = disc * (0.3 + 0.7 * patch)
            rad = radius
        fine[k] += brightness[k] * obj
        objects.append({"plane": k, "centre": [float(r), float(c)], "radius_px": float(rad),
                        "brightness": float(brightness[k])})
    x_fine = np.zeros(fine_op.shape_in, np.float32)
    x_fine[(slice(None), *fine_op.crop)] = fine
    clean = np.clip(fine_op.forward(x_fine).astype(np.float64), 0, None)
    noisy, _, _, snr = add_camera_noise(clean, photons, read_noise_e, rng)
    raw_e = box_bin(noisy.astype(np.float32), 2).astype(np.float32)
    truth = np.stack([box_bin(p.astype(np.float32), 2) for p in fine]).astype(np.float32)
    b = (raw_e / np.float32(np.abs(raw_e).max())).astype(np.float32)
    return VolumeCase(op, b, raw_e, truth, objects, depths_mm(n_planes),
                      {"kind": kind, "photons": float(photons), "dim": float(dim),
                       "snr_db": float(snr), "coarse_bin": coarse_bin})

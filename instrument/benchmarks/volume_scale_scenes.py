"""The seed-size 3D problem, generated on the fly (Kuo 2020, Ch. 4: 2048 x 2048 x 128).

:func:`write_psf_store` turns the tutorial's measured on-axis PSF
(``diffusercam-tutorial/psf_sample.tif``) into a depth-scaled stack -- the caustic
pattern shrunk and dimmed per plane as a point moves away (planes uniform in 1/z,
about one axial resolution apart, :func:`stack_depths_mm`; the 3D auto benchmark's
model, :func:`instrument.benchmarks.volume_auto_scenes.depth_plane`)
-- written plane by plane to a Zarr store chunked by
plane (never whole in memory, never in the repository). :func:`scene_objects`
places beads and extended objects (discs and textured squares) across the depths;
:func:`render_measurement` images them through the same model the solvers use
(:class:`recon.volume.slab.VolumeSlab`, a few planes at a time) with Poisson and
read noise, the objects rendered at sub-pixel positions (model mismatch: the solver's
grid is the sensor's). :func:`objects_at_depth` says which objects a reconstruction
puts at their plane (within one).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates, shift

from recon.preprocess import dark_level
from recon.simulate import add_camera_noise
from recon.validate import positive
from recon.volume.slab import VolumeSlab

from .volume_auto_scenes import D_MM, depth_plane

__all__ = ["SceneObject", "axial_resolution_planes", "bead_light", "objects_at_depth",
           "render_measurement", "scene_objects", "stack_depths_mm", "window_energies",
           "write_psf_store"]


def _base_psf(psf: np.ndarray, n: int) -> np.ndarray:
    """The tutorial PSF dark-subtracted, cropped square about its centre of light and
    resampled to ``n`` x ``n`` (float64, max 1)."""
    p = np.clip(np.asarray(psf, np.float64) - dark_level(psf), 0.0, None)
    side = min(p.shape)
    r0, c0 = (p.shape[0] - side) // 2, (p.shape[1] - side) // 2
    p = p[r0:r0 + side, c0:c0 + side]
    ii = np.linspace(0, side - 1, n)
    grid = np.meshgrid(ii, ii, indexing="ij")
    out = map_coordinates(p, grid, order=1)
    return out / out.max()


#: Nearest depth of the generated stack, mm (8.9 mm behind the diffuser, :data:`D_MM`).
Z_NEAR_MM = 5.0
#: Lateral shift, pixels, of the PSF's rim between neighbouring planes: the planes are
#: spaced about one axial resolution apart (Sec. 4.4), so "at its depth within one
#: plane" means something.
RIM_SHIFT_PX = 3.0
#: A bead's light relative to one pixel of an extended object on a 512-pixel sensor
#: (fluorescent beads are bright: about as much light as a disc of radius 4 px there).
BEAD_LIGHT_512 = 50.0


def bead_light(n: int) -> float:
    """A bead's light on an ``n``-pixel sensor, relative to one pixel of an extended object.

    The scene is the same at every sensor size, sampled more or less finely: the discs'
    radii grow with ``n`` (:func:`scene_objects`), so their light grows as ``n^2``, and a
    bead -- a point, one pixel at any sampling -- carries :data:`BEAD_LIGHT_512`
    ``(n / 512)^2`` to keep its share of the scene's light (800 at 2048: about a disc of radius
    16 px there, 4 px at 512). A fixed bead light would make the beads 16 times fainter
    beside the discs at 2048 than at 512 (measured at 512 x 512 x 32, 80 iterations:
    beads at their plane 20 of 24 at light 50, 4 of 24 at 50/16).

    Parameters
    ----------
    n : int
        Sensor side, pixels.

    Returns
    -------
    float
    """
    return BEAD_LIGHT_512 * (n / 512.0) ** 2


def stack_depths_mm(n: int, n_z: int) -> np.ndarray:
    """Depths (mm, nearest first, uniform in 1/z) whose PSFs, of rim radius ``0.45 n``,
    differ in magnification by :data:`RIM_SHIFT_PX` at the rim between neighbouring
    planes (the farthest at least 0.4 of the nearest's size)."""
    m0 = 1 + D_MM / Z_NEAR_MM
    s = np.maximum(1.0 - np.arange(n_z) * RIM_SHIFT_PX / (0.45 * n), 0.4)
    return D_MM / (s * m0 - 1)


def write_psf_store(path: str, psf: np.ndarray, n: int, n_z: int) -> tuple[float, list[float]]:
    """Write a depth-scaled PSF stack (n_z, n, n) float32 to a Zarr store, plane by plane.

    The tutorial PSF resampled to ``n`` x ``n`` is the nearest plane; plane ``k`` at
    depth :func:`stack_depths_mm` is it shrunk and dimmed by
    :func:`~instrument.benchmarks.volume_auto_scenes.depth_plane` (the 3D auto benchmark's
    model: magnification ``1 + d/z``, light ``1/z^2``).

    Parameters
    ----------
    path : str
        New Zarr v3 store (chunks of one plane).
    psf : ndarray, 2D
        A measured on-axis PSF (the tutorial's, raw counts).
    n : int
        Sensor side, pixels.
    n_z : int
        Planes, nearest first.

    Returns
    -------
    psf_scale : float
        ``sqrt(sum_z (sum h_z)^2)`` (:func:`recon.volume.normalize_psf_stack`'s divisor).
    depths_mm : list of float
    """
    from instrument.writer.files import write_planes_zarr

    base = _base_psf(psf, n)
    z = stack_depths_mm(n, n_z)
    sums = []

    def planes():
        for zk in z:
            plane = depth_plane(base, zk, z[0]).astype(np.float32)
            sums.append(float(plane.sum(dtype=np.float64)))
            yield plane

    write_planes_zarr(path, planes(), (n_z, n, n))
    return float(np.sqrt(np.sum(np.square(sums)))), [float(v) for v in z]


def axial_resolution_planes(store, depths_mm, samples: int = 3,
                            threshold: float = 0.8) -> dict:
    """How many of the stack's planes one axial resolution spans, plane by plane.

    The resolvable 1/z step ``c`` (Eq. 4.7 with the inner-product predictor of Sec.
    6.4: :func:`recon.analysis.sampling.inverse_depth_step_per_mm`) is measured on
    ``samples`` planes spread over the stack, interpolated over the planes, and divided
    by the stack's local 1/z spacing. The generated stack spaces its planes by a fixed
    rim shift (:data:`RIM_SHIFT_PX`) whatever the sensor size, while the caustic's
    lines widen with it (the same tutorial PSF resampled), so at 2048 x 2048 x 128 one
    resolution spans several planes (3.4 at the far end, 5.7 at the near end; about
    one at 512 x 512 x 32): "at its plane within one" is then finer than the system
    resolves.

    Parameters
    ----------
    store : array-like, (n_z, n, n)
        The PSF stack (a Zarr array: only the sampled planes are read).
    depths_mm : sequence of float
        Each plane's depth, mm, nearest first (:func:`stack_depths_mm`).
    samples : int
        Planes measured (>= 2; nearest and farthest included).
    threshold : float
        Inner product at which two depths count as distinguishable.

    Returns
    -------
    dict
        ``planes`` (float list, per plane: planes per resolvable step; inf for the
        planes of a small sensor's stack that repeat one depth, where
        :func:`stack_depths_mm` reaches its 0.4 size floor), ``measured``
        (the sampled planes' index, depth in mm and ``c`` in 1/mm), ``threshold``.
    """
    from recon.analysis.sampling import inverse_depth_step_per_mm

    z = np.asarray(depths_mm, np.float64)
    idx = np.unique(np.linspace(0, z.size - 1, max(2, samples)).round().astype(int))
    c = np.array([inverse_depth_step_per_mm(np.asarray(store[k], np.float64), D_MM,
                                            float(z[k]), threshold) for k in idx])
    spacing = np.abs(np.gradient(1.0 / z)) if z.size > 1 else np.ones(1)
    with np.errstate(divide="ignore"):  # planes at one depth: inf (the clamped stack)
        per_plane = np.interp(np.arange(z.size), idx, c) / spacing
    return {"planes": [float(v) for v in per_plane], "threshold": threshold,
            "measured": [{"plane": int(k), "depth_mm": float(z[k]), "step_per_mm": float(v)}
                         for k, v in zip(idx, c, strict=True)]}


@dataclass
class SceneObject:
    """One object of the scene: ``kind`` (bead, disc or texture), its plane, centre
    (row, col; sub-pixel), radius (pixels) and a bead's light (relative to one pixel of
    an extended object; :func:`bead_light`)."""

    kind: str
    plane: int
    row: float
    col: float
    radius: float
    light: float = BEAD_LIGHT_512

    def patch(self, rng: np.random.Generator) -> tuple[np.ndarray, int, int]:
        """The object's brightness on a small patch and the patch's top-left pixel."""
        r = int(np.ceil(self.radius)) + 2
        i0, j0 = int(np.floor(self.row)) - r, int(np.floor(self.col)) - r
        ii, jj = np.mgrid[0:2 * r + 1, 0:2 * r + 1].astype(np.float64)
        di, dj = ii + i0 - self.row, jj + j0 - self.col
        if self.kind == "bead":  # a point at a sub-pixel position: bilinear weights
            p = np.zeros_like(ii)
            p[r, r] = 1.0
            p = shift(p, (self.row - np.floor(self.row), self.col - np.floor(self.col)),
                      order=1)
            return self.light * p, i0, j0
        inside = np.hypot(di, dj) < self.radius
        if self.kind == "disc":
            return inside.astype(np.float64), i0, j0
        return inside * (0.5 + 0.5 * rng.random(ii.shape)), i0, j0  # texture


def scene_objects(n: int, n_z: int, *, beads: int = 24, extended: int = 12,
                  seed: int = 0, light: float | None = None) -> list[SceneObject]:
    """Beads and extended objects (discs, textured discs of radius 6-24 px at 2048)
    at random planes and positions inside the central 80 % of the field of view.

    ``light`` is each bead's light (default :func:`bead_light` of ``n``: the same scene
    at every sensor size); the positions and planes do not depend on it.

    Raises
    ------
    ReconInputError
        ``light`` not a finite number > 0.
    """
    rng = np.random.default_rng(seed)
    light = bead_light(n) if light is None else positive(light, "light")
    out = []
    for k in range(beads + extended):
        kind = "bead" if k < beads else ("disc" if k % 2 else "texture")
        radius = 0.0 if kind == "bead" else float(rng.uniform(6, 24) * n / 2048 + 1)
        out.append(SceneObject(kind, int(rng.integers(0, n_z)),
                               float(rng.uniform(0.1, 0.9) * n), float(rng.uniform(0.1, 0.9) * n),
                               radius, light))
    return out


def render_measurement(store, psf_scale: float, objects: list[SceneObject], *,
                       photons: float = 5000.0, read_noise: float = 2.0, seed: int = 1
                       ) -> np.ndarray:
    """The measurement of ``objects``: the volume model (Eq. 4.4) applied by
    :class:`~recon.volume.slab.VolumeSlab` one plane at a time (only planes that hold
    objects), then Poisson noise at ``photons`` for the brightest pixel and Gaussian
    read noise (:func:`recon.simulate.add_camera_noise`, electrons).

    Returns
    -------
    ndarray, float32, (n, n)
        In electrons (not scaled).
    """
    rng = np.random.default_rng(seed)
    n = store.shape[1]
    image = np.zeros((n, n), np.float64)
    for z in sorted({o.plane for o in objects}):
        slab = VolumeSlab(store, z, z + 1, psf_scale)
        for o in objects:
            if o.plane == z:
                p, i0, j0 = o.patch(rng)
                slab.y[0, i0:i0 + p.shape[0], j0:j0 + p.shape[1]] += p.astype(np.float32)
        image += slab.forward("y")
        del slab
    return add_camera_noise(np.clip(image, 0, None), photons, read_noise, rng)[0].astype(
        np.float32)


def window_energies(volume: np.ndarray, objects: list[SceneObject]) -> np.ndarray:
    """Per object and plane, the light of ``volume`` in a window of the object's size
    about its centre (float64, (objects, n_z)); a slab of planes gives its columns."""
    out = np.zeros((len(objects), volume.shape[0]))
    for k, o in enumerate(objects):
        r = int(np.ceil(o.radius)) + 3
        i, j = int(round(o.row)), int(round(o.col))
        window = volume[:, max(0, i - r):i + r + 1, max(0, j - r):j + r + 1]
        out[k] = window.reshape(volume.shape[0], -1).sum(axis=1, dtype=np.float64)
    return out


def objects_at_depth(volume, objects: list[SceneObject], tolerance: int = 1,
                     resolution_planes=None) -> dict:
    """Which objects a volume puts at their plane: per object, the plane of most energy
    in a window of its size about its centre (:func:`window_energies`).

    Parameters
    ----------
    volume : ndarray, (n_z, n, n), or the (objects, n_z) energies themselves
        On the sensor grid.
    objects : list of SceneObject
    tolerance : int
        Planes of slack.
    resolution_planes : sequence of float, optional
        Planes per axial resolution at each plane (:func:`axial_resolution_planes`):
        also counts the objects found within one resolution of their plane.

    Returns
    -------
    dict
        ``found`` / ``total`` per kind and overall, and per object its true and found
        plane (JSON-ready); with ``resolution_planes`` also ``found_within_resolution``
        and ``by_kind_within_resolution``.
    """
    energy = (volume if volume.ndim == 2 and volume.shape[0] == len(objects)
              else window_energies(volume, objects))
    rows = []
    for o, e in zip(objects, energy, strict=True):
        found = int(np.argmax(e))
        rows.append({"kind": o.kind, "plane": o.plane, "found_plane": found,
                     "ok": abs(found - o.plane) <= tolerance})
        if resolution_planes is not None:
            rows[-1]["within_resolution"] = bool(
                abs(found - o.plane) <= max(tolerance, resolution_planes[o.plane]))
    kinds = sorted({r["kind"] for r in rows})

    def tally(key: str) -> dict:
        return {k: [sum(r[key] for r in rows if r["kind"] == k),
                    sum(1 for r in rows if r["kind"] == k)] for k in kinds}

    out = {"found": sum(r["ok"] for r in rows), "total": len(rows), "by_kind": tally("ok"),
           "tolerance_planes": tolerance, "objects": rows}
    if resolution_planes is not None:
        out["found_within_resolution"] = sum(r["within_resolution"] for r in rows)
        out["by_kind_within_resolution"] = tally("within_resolution")
    return out

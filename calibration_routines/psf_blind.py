"""Compressive calibration: PSFs from images of a bead slide (Sec. 5.4, Eq. 5.11-5.13).

A slide of fluorescent beads at unknown positions sits on the source stage at depth
``z_mm``; the stage moves it to ``N`` random lateral offsets and the camera images
it at each (excitation on, fixed exposure). One first point takes the darks with
the camera capped. :meth:`PsfBlindPlan.reduce` averages and dark-subtracts each
image, removes the background (lowest DCT coefficients, Sec. 6.4) and recovers a
``ny x nx`` grid of registered PSFs by blind deconvolution
(:func:`recon.spatial.blind_calibration`), more PSFs than images. The product is
``psf_grid_registered`` with the node positions, shifts and depth, the same as a
``psf-grid`` run's, so ``recon --psf-grid`` and ``recon3d --psf-grid`` take it.
"""

from __future__ import annotations

import numpy as np

from instrument.acquisition.plan import (
    Capture,
    Expose,
    Move,
    Plan,
    PlanError,
    PlanPoint,
    Prompt,
    register_plan,
)
from recon.analysis import remove_background_dct
from recon.preprocess import box_bin
from recon.spatial import blind_calibration

from ._common import sensor_geometry

__all__ = ["PsfBlindPlan"]


@register_plan
class PsfBlindPlan(Plan):
    """Bead-slide images at random stage offsets and the PSFs they hold (module docstring).

    Parameters
    ----------
    offsets_mm : list of (x, y)
        Lateral stage positions of the images, mm.
    z_mm : float
        Depth of the slide, mm.
    grid_shape : (ny, nx)
        Nodes of the recovered PSFs.
    node_spacing_mm : float
        Node spacing in the object plane, mm.
    exposure_s : float
        Exposure of every image and dark, s.
    d_mm, pitch_mm : float
        Geometry.
    frames_per_point : int
    rounds : int
        Blind deconvolution rounds (rank bound 1..rounds).
    bin_factor : int
        Lateral binning before the blind deconvolution.
    l1 : float
    dct_n_low : int
    """

    name = "psf-blind"

    def __init__(self, *, offsets_mm, z_mm: float, grid_shape, node_spacing_mm: float,
                 exposure_s: float, d_mm: float, pitch_mm: float, frames_per_point: int = 4,
                 rounds: int = 6, bin_factor: int = 1, l1: float = 1e-3,
                 dct_n_low: int = 5) -> None:
        off = np.asarray(offsets_mm, float).reshape(-1, 2)
        if len(off) < 1:
            raise PlanError("a bead-slide calibration needs at least one image (--images)")
        if not (exposure_s > 0 and z_mm > 0 and node_spacing_mm > 0):
            raise PlanError("exposure_s, z_mm and node_spacing_mm must be > 0")
        super().__init__(offsets_mm=off.tolist(), z_mm=float(z_mm),
                         grid_shape=[int(v) for v in grid_shape],
                         node_spacing_mm=float(node_spacing_mm), exposure_s=float(exposure_s),
                         d_mm=float(d_mm), pitch_mm=float(pitch_mm),
                         frames_per_point=int(frames_per_point), rounds=int(rounds),
                         bin_factor=int(bin_factor), l1=float(l1), dct_n_low=int(dct_n_low))

    @classmethod
    def for_bench(cls, bench, *, n_images: int = 4, z_mm: float, grid: int = 3,
                  node_spacing_mm: float, exposure_s: float, travel_mm: float | None = None,
                  seed: int = 0, **params) -> PsfBlindPlan:
        """``n_images`` random slide offsets within ``+-travel_mm`` (default half the
        node grid's width), a ``grid x grid`` node grid.

        Raises
        ------
        PlanError
            Fewer than one image, a grid below 2 or a bad number.
        """
        if not isinstance(n_images, int) or n_images < 1:
            raise PlanError(f"--images {n_images!r}: give a whole number >= 1")
        if not isinstance(grid, int) or grid < 2:
            raise PlanError(f"--grid {grid!r}: give a whole number >= 2 of nodes a side")
        d_mm, pitch_mm, _ = sensor_geometry(bench.config)
        reach = node_spacing_mm * (grid - 1) / 2 if travel_mm is None else float(travel_mm)
        rng = np.random.default_rng(seed)
        offsets = rng.uniform(-reach, reach, (n_images, 2))
        params.setdefault("frames_per_point", bench.config.calibration.frames_per_point)
        return cls(offsets_mm=offsets, z_mm=z_mm, grid_shape=(grid, grid),
                   node_spacing_mm=node_spacing_mm, exposure_s=exposure_s, d_mm=d_mm,
                   pitch_mm=pitch_mm, **params)

    # ------------------------------------------------------------------ plan
    def points(self) -> list[PlanPoint]:
        n, z = self.params["frames_per_point"], self.params["z_mm"]
        darks = [PlanPoint({"x_mm": 0.0, "y_mm": 0.0, "z_mm": z}, ("dark",) * n)]
        return darks + [PlanPoint({"x_mm": x, "y_mm": y, "z_mm": z}, ("beads",) * n)
                        for x, y in self.params["offsets_mm"]]

    def steps(self, index, point):
        c, p = point.coords, self.params
        yield Move("source_stage", {"x": c["x_mm"], "y": c["y_mm"], "z": c["z_mm"]})
        yield Expose(exposure_s=p["exposure_s"])
        if index == 0:
            yield Prompt("cap_camera", "Cap the camera for the dark frames")
            yield Capture(p["frames_per_point"], "dark")
            yield Prompt("uncap_camera", "Uncap the camera: the bead slide is imaged next")
        else:
            yield Capture(p["frames_per_point"], "beads")

    # ------------------------------------------------------------------ products
    def reduce(self, store) -> dict:
        """Recover the PSFs; write ``psf_grid_registered`` (and the bead images as
        ``bead_images``); return the grid and the blind deconvolution's history."""
        p = self.params
        dark = store.point_frames(0, "dark")[0].astype(np.float64).mean(axis=0)
        images = np.stack([store.point_frames(i, "beads")[0].astype(np.float64).mean(axis=0)
                           - dark for i in range(1, store.n_points)])
        images = remove_background_dct(images, p["dct_n_low"]) / p["exposure_s"]
        f = p["bin_factor"]
        if f > 1:
            images = np.moveaxis(box_bin(np.moveaxis(images, 0, -1), f), -1, 0)
        m = p["d_mm"] / p["z_mm"]
        spacing_px = p["node_spacing_mm"] * m / (p["pitch_mm"] * f)
        result = blind_calibration(images, tuple(p["grid_shape"]), spacing_px,
                                   rounds=p["rounds"], l1=p["l1"], z_mm=p["z_mm"],
                                   d_mm=p["d_mm"])
        g = result.grid
        shifts = g.shifts_px * f  # sensor pixels of the unbinned camera
        positions = [(-dx * p["pitch_mm"] / m, -dy * p["pitch_mm"] / m) for dy, dx in shifts]
        attrs = {"positions_mm": positions, "z_mm": p["z_mm"], "units": "DN/s",
                 "shifts_px": shifts.tolist(), "bin_factor": f}
        psfs = g.psfs
        if f > 1:  # back on the camera's grid (nearest neighbour, DN/s per pixel kept)
            psfs = np.repeat(np.repeat(psfs, f, axis=1), f, axis=2) / (f * f)
            rows, cols = store.frame_shape
            psfs = np.pad(psfs[:, :rows, :cols], ((0, 0), (0, rows - min(rows, psfs.shape[1])),
                                                  (0, cols - min(cols, psfs.shape[2]))))
        store.write_product("psf_grid_registered", psfs.astype(np.float32), **attrs)
        store.write_product("bead_images", images.astype(np.float32), bin_factor=f)
        return {"grid_shape": p["grid_shape"], "positions_mm": positions, "z_mm": p["z_mm"],
                "images": len(images), "psfs": int(g.n), **result.history}

"""Reconstruction from PSF-grid runs: ``recon --psf-grid`` and ``recon3d --psf-grid``.

A ``calibrate psf-grid`` run (:class:`calibration_routines.PsfGridPlan`; or a
``calibrate psf-blind`` run, :class:`calibration_routines.PsfBlindPlan`) stores the
registered PSFs of one depth (``products/psf_grid_registered``) with the source
positions, the registered shifts and the depth; :func:`load_psf_grid` turns one
into a :class:`recon.spatial.PsfGrid`. :func:`run_recon_grid` reconstructs one frame
with one grid (an image) or several (a volume, one grid per depth; depths between
them synthesised) through :func:`recon.reconstruct` and writes the
outputs the way ``recon`` and ``recon3d`` do. It logs, it never prints.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from diffuserlab.jsonio import jsonable

__all__ = ["GRID_PRODUCT", "background_output", "load_psf_grid", "run_recon_grid"]

log = logging.getLogger(__name__)

#: The product of a psf-grid run that holds the registered PSFs.
GRID_PRODUCT = "psf_grid_registered"


def load_psf_grid(path: str | Path):
    """The registered PSF grid of a ``calibrate psf-grid`` run.

    Parameters
    ----------
    path : str or Path
        ``RUN.zarr`` of a finished psf-grid run.

    Returns
    -------
    recon.spatial.PsfGrid
        With the run's depth ``z_mm`` and diffuser distance ``d_mm``.

    Raises
    ------
    recon.errors.ReconInputError
        Not a run store, not a psf-grid run, or a run without its products (resume it).
    """
    from recon.errors import ReconInputError
    from recon.spatial import PsfGrid

    from ..runs.runstore import RunStore, RunStoreError

    try:
        store = RunStore.open(path)
        plan = store.attrs["plan"]
        if plan.get("name") not in ("psf-grid", "psf-blind"):
            raise ReconInputError(f"{path} is a {plan.get('name')!r} run, not a psf-grid run; "
                                  "calibrate one with `diffuserlab calibrate psf-grid` (or "
                                  "psf-blind)")
        psfs, attrs = store.product(GRID_PRODUCT)
    except RunStoreError as exc:
        raise ReconInputError(f"{exc}; finish the run with `diffuserlab calibrate resume "
                              f"{path}`") from exc
    params = plan.get("params", {})
    return PsfGrid.from_positions(np.asarray(psfs, np.float32), attrs["positions_mm"],
                                  z_mm=float(attrs["z_mm"]), d_mm=params.get("d_mm"),
                                  registered=True, shifts_px=attrs["shifts_px"])


def run_recon_grid(grid_paths: list[str], raw_path: str, options, *, out: str,
                   metrics_json: str | None = None, depths_mm=None,
                   volume: bool = False, overwrite: bool = True) -> dict:
    """Load grids and a frame, reconstruct, write outputs; return the metrics.

    Parameters
    ----------
    grid_paths : list of str
        psf-grid runs: one (2D, unless ``volume``) or one per depth.
    raw_path : str
        The frame (TIFF, PNG or ``.npy``).
    options : recon.options.ReconOptions
        The reconstruction's parameters; its PSF-grid keywords go to
        :func:`recon.reconstruct` (``dark`` a level, "auto" or "none": a grid takes no
        dark frame).
    depths_mm : sequence of float, optional
        Depths to synthesise between the grids' (a volume).
    out : str
        2D: the stem of ``OUT.png`` / ``OUT.tif`` (:func:`output_paths`); 3D: the
        volume ``OUT.tif`` / ``OUT.zarr`` with its projections.
    metrics_json : str, optional
    volume : bool
        Reconstruct a volume (``recon3d``) even from one grid.
    overwrite : bool
        Replace existing outputs; False: an output another process wrote meanwhile
        is kept and this call refused (:func:`instrument.atomic.output_group`).

    Returns
    -------
    dict
        :meth:`recon.Reconstruction.metrics` plus the inputs and the
        output paths; with a background estimate also ``OUT_background.tif``.
    """
    from recon import reconstruct
    from recon.io import DATA_ORIENTATION, load_image

    from ..atomic import output_group, write_json
    from ..writer.files import save_image
    from ..writer.products import (
        output_paths,
        volume_output_paths,
        write_image_products,
        write_volume_products,
    )

    grids = [load_psf_grid(p) for p in grid_paths]
    raw = load_image(raw_path)
    rec = reconstruct(grids if (volume or len(grids) > 1) else grids[0], raw, options,
                      depths_mm=depths_mm)
    metrics = rec.metrics()
    metrics.update(psf_grid=[str(p) for p in grid_paths], raw=str(raw_path),
                   grid_depths_mm=[g.z_mm for g in grids])
    with output_group(replace=overwrite):  # every output of the reconstruction, or none
        if rec.operator.volume:
            vol_path, mips = volume_output_paths(out)
            write_volume_products(rec.image, vol_path, mips,
                                  {"depths_mm": metrics["depths_mm"],
                                   "model": rec.choice.label(),
                                   "orientation": DATA_ORIENTATION})
            metrics.update(output_volume=str(vol_path),
                           output_mips={k: str(v) for k, v in mips.items()})
        else:
            png, tif = output_paths(out)
            write_image_products(rec.image, png, tif)
            metrics.update(output_png=str(png), output_tiff=str(tif))
        if rec.background is not None:
            bg = background_output(out, rec.operator.volume)
            save_image(bg, rec.background)
            metrics["output_background"] = str(bg)
        metrics["orientation"] = {"png": "scene, upright", "data": DATA_ORIENTATION}
        metrics = jsonable(metrics, nonfinite_to_none=True)
        if metrics_json:
            write_json(metrics_json, metrics)
    log.debug("recon --psf-grid: model %s", rec.choice.label())
    return metrics


def background_output(out: str, volume: bool) -> Path:
    """Where :func:`run_recon_grid` writes the estimated background for ``--out``."""
    from ..writer.products import output_paths, volume_output_paths

    path = volume_output_paths(out)[0] if volume else output_paths(out)[1]
    stem = path.with_name(path.stem)  # the known suffix only (take.2.tif -> take.2)
    return stem.parent / f"{stem.name}_background.tif"

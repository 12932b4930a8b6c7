"""Calibration of the diffuser fluorescence microscope (Kuo 2020, Sec. 5.3, 6.4).

The microscope's local convolution model needs registered PSF grids over its
volume: laterally at the Nyquist spacing of the sensor fall-off (Eq. 5.9,
:func:`recon.analysis.lateral_calibration_spacing_mm`) and axially at 1/z steps of
at most ``4 lambda / p^2`` (Eq. 5.10, :func:`recon.analysis.axial_step_eq510_per_mm`).
:func:`microscope_grid_plans` makes one :class:`~calibration_routines.PsfGridPlan`
(stage mode: the bead on the xyz stage, lit by the LED array) per depth;
:func:`calibrate_microscope` runs them, one run store per depth, ready for
``diffuserlab recon3d --psf-grid`` (one ``--psf-grid`` per run).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from instrument.acquisition.plan import PlanError
from instrument.acquisition.runner import Runner
from instrument.writer.guards import check_outputs
from recon.analysis import (
    axial_step_eq510_per_mm,
    inverse_depths,
    lateral_calibration_spacing_mm,
)

from ._common import sensor_geometry
from .psf_grid import PsfGridPlan

__all__ = ["calibrate_microscope", "microscope_depths", "microscope_grid_plans"]

log = logging.getLogger(__name__)


def microscope_depths(z_min_mm: float, z_max_mm: float, *, wavelength_nm: float,
                      lenslet_um: float = 250.0) -> np.ndarray:
    """Calibration depths uniform in 1/z at the Eq. 5.10 step (mm, ascending).

    Sec. 6.4's numbers (520 nm, 250 um lenslets): step 0.0333 1/mm, 9 depths over
    1.7-3 mm.
    """
    step = axial_step_eq510_per_mm(wavelength_nm, lenslet_um)
    return inverse_depths(z_min_mm, z_max_mm, c_per_mm=step)


def microscope_grid_plans(bench, *, z_min_mm: float | None = None,
                          z_max_mm: float | None = None, n: int = 4,
                          lenslet_um: float = 250.0, falloff_sigma_deg: float | None = None,
                          depths_mm=None, **params) -> list[PsfGridPlan]:
    """One stage-mode PSF grid per calibration depth, at the Eq. 5.9 spacing.

    Parameters
    ----------
    bench : Bench
        The microscope (its ``geometry``: wavelength, fall-off sigma; its
        ``calibration.z_range_mm`` when no range is given).
    z_min_mm, z_max_mm : float, optional
    n : int
        Positions a side of each grid; fewer where the outer positions would shift
        the PSF off the sensor (never below 2).
    lenslet_um : float
        Lenslet diameter ``p`` of Eq. 5.10.
    falloff_sigma_deg : float, optional
        Measured fall-off sigma; default the bench file's
        ``geometry.sensor_falloff_sigma_deg``.
    depths_mm : array_like, optional
        Calibration depths instead of the Eq. 5.10 grid.
    **params
        Passed to :meth:`PsfGridPlan.for_bench` (``frames_per_point``, ...).

    Returns
    -------
    list of PsfGridPlan

    Raises
    ------
    PlanError
        No fall-off sigma known, or a depth where even a 2 x 2 grid leaves the sensor.
    """
    geo = bench.config.geometry
    sigma = falloff_sigma_deg if falloff_sigma_deg is not None else geo.sensor_falloff_sigma_deg
    if sigma is None:
        raise PlanError("the Eq. 5.9 spacing needs the sensor fall-off: pass "
                        "falloff_sigma_deg (from an angular-response run) or set "
                        "geometry.sensor_falloff_sigma_deg in the bench file")
    lo, hi = bench.config.calibration.z_range_mm
    z_min = lo if z_min_mm is None else z_min_mm
    z_max = hi if z_max_mm is None else z_max_mm
    depths = (microscope_depths(z_min, z_max, wavelength_nm=geo.wavelength_nm,
                                lenslet_um=lenslet_um)
              if depths_mm is None else np.asarray(depths_mm, float))
    plans = []
    for z in depths:
        spacing = lateral_calibration_spacing_mm(sigma, float(z))
        for side in range(n, 1, -1):
            try:
                plans.append(PsfGridPlan.for_bench(
                    bench, mode="stage", n=side, spacing_mm=spacing, z_mm=float(z),
                    falloff_sigma_deg=sigma, **params))
                break
            except PlanError as exc:
                if "leave the sensor" not in str(exc) or side == 2:
                    raise
    return plans


def calibrate_microscope(bench, out_dir: str | Path, *, on_event=None,
                         resolution_check: bool = False, **options) -> list[Path]:
    """Run :func:`microscope_grid_plans` on a bench: one ``grid-<z>mm.zarr`` per depth.

    With ``resolution_check`` the two-point resolution of each depth's local model
    at five field positions follows (Fig. 6.4a,
    :func:`calibration_routines.microscope_resolution.microscope_resolution`),
    written to ``resolution.json`` in ``out_dir`` and logged.

    Parameters
    ----------
    bench : Bench
        An opened bench (real, or :class:`instrument.devices.virtual_bench.VirtualBench`).
    out_dir : str or Path
        Folder for the run stores (created).
    on_event : callable, optional
        The runner's progress callback.
    resolution_check : bool
        Also measure the two-point resolution (ray traced on a virtual bench).
    **options
        Passed to :func:`microscope_grid_plans`.

    Returns
    -------
    list of Path
        The run stores, by ascending depth.
    """
    sensor_geometry(bench.config)  # a clear error for a bench without geometry
    out = Path(out_dir)
    if resolution_check:
        check_outputs([out / "resolution.json"], None, False, option="out_dir")
    out.mkdir(parents=True, exist_ok=True)
    runs = []
    for plan in microscope_grid_plans(bench, **options):
        path = out / f"grid-{plan.params['z_mm']:.4f}mm.zarr"
        log.info("microscope: PSF grid at z = %.4f mm", plan.params["z_mm"])
        Runner(bench, on_event=on_event).run(plan, path)
        runs.append(path)
    if resolution_check:
        from .microscope_resolution import microscope_resolution, resolution_table

        found = microscope_resolution(runs, bench=bench, out_json=out / "resolution.json")
        log.info("microscope two-point resolution (Fig. 6.4a):\n%s", resolution_table(found))
    return runs

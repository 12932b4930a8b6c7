"""Two-point resolution of a calibrated microscope across its field (Sec. 6.4, Fig. 6.4a).

For each psf-grid run (one depth) the local convolution model of its registered
PSFs (Eq. 5.3-5.5) reconstructs pairs of points at several field positions and
separations (:func:`recon.spatial.two_point_resolution`: l1 FISTA, resolved at a
20 % dip). On the virtual microscope the pairs are ray traced through the twin's
optics (:func:`recon.spatial.ray_traced_pair`: the exact, spatially varying image,
no model, sub-pixel positions); on real hardware, where no such truth exists, the
model images the pairs itself (the model's own resolution, an optimistic bound).
Separations and resolutions are in the object plane, um (``pixel pitch * z / d``
per object-grid pixel).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from instrument.atomic import write_json
from instrument.processing.reconstruct_grid import GRID_PRODUCT, load_psf_grid
from instrument.runs.runstore import RunStore
from instrument.writer.guards import check_outputs
from recon.spatial import local_convolution_operator, ray_traced_pair, two_point_resolution

__all__ = ["microscope_resolution", "resolution_table"]

log = logging.getLogger(__name__)

#: Default separations, object-grid pixels.
SEPARATIONS_PX = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0)


def microscope_resolution(runs, *, bench=None, field_mm=None, separations_px=SEPARATIONS_PX,
                          axis: str = "x", iterations: int = 150, l1: float = 1e-4,
                          noise_std: float = 0.01, seed: int = 0,
                          out_json: str | Path | None = None) -> list[dict]:
    """Two-point resolution at field positions for each calibrated depth (module docstring).

    Parameters
    ----------
    runs : list of str or Path
        Finished psf-grid runs (e.g. what :func:`calibrate_microscope` returned).
    bench : Bench, optional
        The bench; a :class:`instrument.devices.virtual_bench.VirtualBench` supplies its ray
        tracer (``bench.model``) for the measurements, otherwise the model images
        the pairs.
    field_mm : array_like, (M, 2), optional
        Source positions ``(x, y)``, mm. Default: the grid's reference node and the
        four diagonal positions at 0.7 of the outermost node's offset.
    separations_px : sequence of float
        Separations, object-grid pixels.
    axis : {"x", "y"}
    iterations, l1, noise_std, seed
        As :func:`recon.spatial.two_point_resolution` (noise: a fraction of the peak).
    out_json : str or Path, optional
        Also write the results here (checked before any work: never an existing file).

    Returns
    -------
    list of dict
        Per run: ``run``, ``z_mm``, ``pixel_um`` (object plane), ``truth``
        (``"ray-traced"`` or ``"model"``), ``positions``: per field position its
        ``field_mm``, ``resolution_um`` (None when even the largest separation is not
        resolved) and ``dips`` (separation in um -> dip).

    Raises
    ------
    instrument.writer.guards.OutputError
        ``out_json`` exists or lies inside a run store.
    recon.errors.ReconInputError
        A run that is not a finished psf-grid run, or positions off the object grid.
    """
    if out_json is not None:
        check_outputs([out_json], None, False, option="resolution JSON")
    model = getattr(bench, "model", None)
    results = []
    for run in runs:
        grid = load_psf_grid(run)
        store = RunStore.open(run)
        _, attrs = store.product(GRID_PRODUCT)
        params = store.attrs["plan"]["params"]
        z, d, pitch = float(grid.z_mm), float(params["d_mm"]), float(params["pitch_mm"])
        m = d / z
        positions = np.asarray(attrs["positions_mm"], float)
        ref = positions[int(np.argmin(np.hypot(*np.asarray(attrs["shifts_px"], float).T)))]
        if field_mm is None:
            reach = np.abs(positions - ref).max(axis=0) * 0.7
            field = np.array([[0, 0], [1, 1], [1, -1], [-1, 1], [-1, -1]]) * reach + ref
        else:
            field = np.asarray(field_mm, float).reshape(-1, 2)
        op = local_convolution_operator(grid)
        # source (x, y) -> object-grid offset (row, col) from the grid's centre (u = -m x)
        field_px = np.column_stack([(ref[1] - field[:, 1]) * m / pitch,
                                    (ref[0] - field[:, 0]) * m / pitch])
        truth = None
        if model is not None and tuple(model.geometry.sensor_shape) == grid.sensor_shape:
            truth = ray_traced_pair(model, z, op.shape_in, reference_mm=ref)
        rows = two_point_resolution(op, field_px, separations_px, truth_images=truth, axis=axis,
                                    iterations=iterations, l1=l1, noise_std=noise_std,
                                    seed=seed)
        um = pitch / m * 1e3
        entry = {"run": str(run), "z_mm": z, "pixel_um": um,
                 "truth": "model" if truth is None else "ray-traced",
                 "positions": [{"field_mm": f.tolist(),
                                "resolution_um": None if r["resolution_px"] is None
                                else r["resolution_px"] * um,
                                "dips": {f"{s * um:.1f}": v for s, v in r["dips"].items()}}
                               for f, r in zip(field, rows, strict=True)]}
        log.info("two-point resolution at z = %.3f mm: %s", z,
                 [p["resolution_um"] for p in entry["positions"]])
        results.append(entry)
    if out_json is not None:
        write_json(out_json, results)  # never half a file under the final name
    return results


def resolution_table(results: list[dict]) -> str:
    """One line per depth: the resolution (um) at each field position."""
    lines = []
    for r in results:
        cells = ", ".join(
            f"({p['field_mm'][0]:+.2f}, {p['field_mm'][1]:+.2f}) mm: "
            + ("not resolved" if p["resolution_um"] is None else f"{p['resolution_um']:.0f} um")
            for p in r["positions"])
        lines.append(f"z = {r['z_mm']:.3f} mm (pixel {r['pixel_um']:.1f} um, truth "
                     f"{r['truth']}): {cells}")
    return "\n".join(lines)

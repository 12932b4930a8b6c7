"""``diffuserlab recon3d``: a volume from one DiffuserCam image and a PSF stack (Kuo 2020, Ch. 4).

Loads a PSF stack (a run store ``RUN.zarr``, a TIFF stack with depths in its
metadata, or a TIFF / ``.npy`` stack with ``--depths``) and one raw measurement,
subtracts the dark level, bins laterally, scales the problem like the 2D API
(:func:`recon.api.scaled_problem`: stack normalised by
:func:`recon.volume.normalize_psf_stack`, measurement divided by its largest
magnitude), builds the 3D forward model of Eq. 4.4
(:class:`recon.volume.VolumeConvolutionOperator`) and solves it with 3D FISTA or
3D ADMM. Writes the sensor field of view of every plane as a float32 volume (TIFF
or Zarr v3, depths attached), the three maximum-intensity projections as PNG and,
if asked, the metrics JSON (the 2D record plus depths and the 3D FFT floor).

Bad input exits with status 2 and one line; a diverging solver with status 3.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

from drivers.base import jsonable

__all__ = ["METHODS", "add_subcommands", "run", "run_recon3d", "summary_line"]

log = logging.getLogger(__name__)

#: Solvers of ``--method``.
METHODS = ("admm", "fista")

#: Saturated fraction of the raw image above which a warning is logged.
SATURATION_WARN = 0.001

_VOLUME_SUFFIXES = (".tif", ".tiff", ".zarr")


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``recon3d`` to the ``diffuserlab`` subparsers.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subparsers of the ``diffuserlab`` parser. The new parser's defaults
        carry ``handler=run``, so :func:`instrument.cli.main` dispatches to
        :func:`run` without naming the command.
    """
    p = sub.add_parser("recon3d", help="reconstruct a volume from one image and a PSF stack")
    p.add_argument("--psf-stack", required=True,
                   help="PSF stack: a run store (RUN.zarr from `calibrate psf-sweep` or "
                   "`runs import-psf`), a TIFF stack (depths in its metadata or --depths) or "
                   "a .npy stack (n_z, rows, cols) with --depths")
    p.add_argument("--psf-product", default="psf_stack",
                   help="which stack of a run store (default psf_stack)")
    p.add_argument("--depths", default=None,
                   help="comma-separated depths in mm, one per plane (unless recorded)")
    p.add_argument("--raw", required=True, help="raw measurement, same size as the PSFs")
    p.add_argument("--method", default="admm", help="admm or fista (default admm)")
    p.add_argument("--iterations", type=int, default=100)
    from recon.volume import DEFAULT_TV

    p.add_argument("--tv", type=float, default=DEFAULT_TV,
                   help="3D TV weight in the scaled problem (0 disables; default "
                   f"{DEFAULT_TV:g}, chosen by the 3D accuracy benchmark)")
    p.add_argument("--l1", type=float, default=0.0,
                   help="l1 (native sparsity) weight in the scaled problem (default 0)")
    p.add_argument("--bin", type=int, default=1, dest="bin_factor",
                   help="lateral box binning of every plane and of the raw image")
    p.add_argument("--dark", default="auto",
                   help="dark level: auto (median of the planes' dark corners psf[5:15, "
                   "5:15], subtracted from the stack and the raw image; default), none, or "
                   "a number in input units")
    p.add_argument("--out", default="out/volume.tif",
                   help="volume to write: OUT.tif (float32 TIFF, depths in its metadata) or "
                   "OUT.zarr (Zarr v3 array, depths attribute); projections go to "
                   "OUT_mip_{xy,xz,yz}.png")
    p.add_argument("--metrics-json", default=None, help="write the metrics JSON here")
    p.set_defaults(handler=run)


def _parse_depths(text: str | None) -> list[float] | None:
    if text is None:
        return None
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise ValueError(f"--depths {text!r} is not a comma-separated list of numbers (mm)") \
            from exc


def _parse_dark(text: str) -> str | float:
    key = str(text).strip().lower()
    if key in ("auto", "none"):
        return key
    try:
        value = float(key)
    except ValueError as exc:
        raise ValueError(f"--dark {text!r}: use auto, none or a number") from exc
    if not math.isfinite(value):
        raise ValueError(f"--dark {text!r} must be finite")
    return value


def _out_paths(out: str) -> tuple[Path, dict[str, Path]]:
    """The volume path and the three projection PNG paths of ``--out``."""
    path = Path(out)
    if path.suffix.lower() not in _VOLUME_SUFFIXES:
        raise ValueError(f"--out {out}: use a .tif/.tiff or .zarr name for the volume")
    stem = path.with_suffix("")
    return path, {v: stem.parent / f"{stem.name}_mip_{v}.png" for v in ("xy", "xz", "yz")}


def _prepare(stack: np.ndarray, raw: np.ndarray, dark: str | float,
             bin_factor: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """Dark subtraction, binning and clipping with the :mod:`recon.preprocess` steps.

    Returns the stack (n_z, r, c) and raw (r, c), float32, and what was done.

    Raises
    ------
    recon.errors.ReconInputError
        Invalid images, shapes that differ, or a plane without signal.
    """
    from recon.errors import ReconInputError
    from recon.preprocess import (
        box_bin,
        dark_level,
        saturation_fraction,
        subtract_dark,
        validate_measurement,
        validate_psf,
    )
    from recon.volume import bin_stack

    if raw.ndim != 2:
        raise ReconInputError(f"the raw image has shape {raw.shape}; recon3d needs one "
                              "grayscale image (rows, cols)")
    if raw.shape != stack.shape[1:]:
        raise ReconInputError(f"raw image {raw.shape[0]}x{raw.shape[1]} and PSF planes "
                              f"{stack.shape[1]}x{stack.shape[2]} differ in size; capture or "
                              "crop both to the same sensor region")
    for k in range(stack.shape[0]):
        validate_psf(stack[k])
    validate_measurement(raw)
    saturated = saturation_fraction(raw)
    if saturated > SATURATION_WARN:
        log.warning("%.2g%% of the raw image is saturated: the linear model does not hold "
                    "there", 100 * saturated)
    if dark == "none":
        level = None
    elif dark == "auto":
        level = float(np.median([dark_level(stack[k]) for k in range(stack.shape[0])]))
    else:
        level = float(dark)
    if level is not None:
        stack = subtract_dark(stack, level)  # a scalar: any (n_z, r, c) layout is fine
        raw = subtract_dark(raw, level)
    stack = bin_stack(stack, bin_factor)
    raw = box_bin(raw, bin_factor)
    clipped = float(np.count_nonzero(stack < 0)) / stack.size
    np.clip(stack, 0.0, None, out=stack)
    empty = [k for k in range(stack.shape[0]) if not stack[k].sum(dtype=np.float64) > 0]
    if empty:
        raise ReconInputError(f"PSF planes {empty} have no signal above the dark level "
                              f"{level}; try --dark none or a smaller value")
    info = {"dark_mode": dark if isinstance(dark, str) else "value", "dark_level": level,
            "bin_factor": int(bin_factor), "saturated_fraction_raw": saturated,
            "psf_clipped_fraction": clipped}
    return stack, raw, info


def _solver(method: str):
    """The 3D solver of ``method``: fista3d, or admm3d imported lazily (it may be missing).

    Raises
    ------
    recon.errors.ReconInputError
        admm3d is not available in this recon.volume.
    """
    from recon.errors import ReconInputError

    if method == "fista":
        from recon.volume import fista3d

        return fista3d
    try:
        from recon.volume import admm3d
    except ImportError as exc:
        raise ReconInputError(
            "admm3d not available in this recon.volume; use --method fista") from exc
    return admm3d


def _projections(volume: np.ndarray) -> dict[str, np.ndarray]:
    """Maximum-intensity projections, each plane repeated so z is visible.

    ``xy`` is the maximum over z (rows, cols); ``xz`` over y (z, cols); ``yz`` over
    x (rows, z). Along z every plane is repeated ``max(1, min(rows, cols) // (2 n_z))``
    times (nearest neighbour, for viewing only).
    """
    n_z, rows, cols = volume.shape
    rep = max(1, min(rows, cols) // (2 * n_z))
    return {"xy": volume.max(axis=0),
            "xz": np.repeat(volume.max(axis=1), rep, axis=0),
            "yz": np.repeat(volume.max(axis=2).T, rep, axis=1)}


def _write_volume(path: Path, volume: np.ndarray, attrs: dict) -> None:
    """A float32 TIFF (JSON metadata) or a Zarr v3 array (attributes) of the volume."""
    import tifffile
    import zarr

    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() != ".zarr":
        tifffile.imwrite(path, volume.astype(np.float32), photometric="minisblack",
                         metadata={**attrs, "axes": "ZYX"})
        return
    node = path / "zarr.json"
    if path.exists():
        kind = json.loads(node.read_text()).get("node_type") if node.is_file() else None
        if kind != "array":
            raise ValueError(f"--out {path} exists and is not a volume written by recon3d "
                             "(a run store?); choose another name")
    arr = zarr.create_array(str(path), shape=volume.shape, dtype="float32",
                            chunks=(1, *volume.shape[1:]), overwrite=True, zarr_format=3)
    arr[:] = volume
    arr.attrs.update(attrs)


def run_recon3d(psf_stack: str, raw_path: str, *, method: str, iterations: int, tv: float,
                l1: float, out: str, depths_mm: list[float] | None = None,
                bin_factor: int = 1, dark: str | float = "auto",
                psf_product: str = "psf_stack", metrics_json: str | None = None) -> dict:
    """Load, preprocess, reconstruct a volume, write it with its projections and metrics.

    Parameters
    ----------
    psf_stack : str
        Run store, TIFF or ``.npy`` stack (see
        :func:`instrument.stacks.load_psf_stack`).
    raw_path : str
        Raw measurement (TIFF, PNG or ``.npy``), the size of one PSF plane.
    method : {"admm", "fista"}
    iterations : int
        Solver iterations (>= 1).
    tv, l1 : float
        3D TV and l1 weights in the scaled problem (>= 0; 0 disables).
    out : str
        ``OUT.tif``/``OUT.tiff`` or ``OUT.zarr``; projections go to
        ``OUT_mip_xy.png``, ``OUT_mip_xz.png`` and ``OUT_mip_yz.png``.
    depths_mm : list of float, optional
        One depth per plane when the stack does not record them.
    bin_factor : int
        Lateral box binning of the stack and the raw image.
    dark : "auto", "none" or float
        Dark level handling (see :func:`_prepare`).
    psf_product : str
        Product of a run store to read.
    metrics_json : str, optional
        Where to write the metrics.

    Returns
    -------
    dict
        The metrics: method, iterations, weights, shapes, depths, preprocessing,
        scales, times (total, median per iteration), the FFT floor
        (:func:`recon.volume.operator.fft_floor_seconds`, measured after the solve in
        this process) and the ratio to it, final relative residual and objective,
        the objective and residual histories, solver parameters and output paths.

    Raises
    ------
    recon.errors.ReconInputError
        Bad files, shapes or parameters, or admm3d not available.
    instrument.runstore.RunStoreError
        Unreadable stack, missing or mismatched depths.
    ValueError
        Bad ``--out`` name.
    recon.errors.DivergenceError
        The solver diverged.
    """
    from recon.errors import ReconInputError
    from recon.io import load_image, save_image
    from recon.volume import VolumeConvolutionOperator, normalize_psf_stack
    from recon.volume.operator import fft_floor_seconds

    from .stacks import load_psf_stack

    if method not in METHODS:
        raise ReconInputError(f"unknown method {method!r}; choose admm or fista")
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
        raise ReconInputError(f"--iterations must be an integer >= 1, got {iterations!r}")
    for name, w in (("tv", tv), ("l1", l1)):
        if not (math.isfinite(w) and w >= 0):
            raise ReconInputError(f"--{name} must be a finite number >= 0, got {w}")
    vol_path, mip_paths = _out_paths(out)
    solver = _solver(method)
    t_start = time.perf_counter()
    stack, depths, _ = load_psf_stack(psf_stack, depths_mm, product=psf_product)
    stack_shape_in = list(stack.shape)
    raw = load_image(raw_path)
    raw_shape_in = list(raw.shape)
    order = np.argsort(depths, kind="stable")
    stack, depths = stack[order], [float(depths[i]) for i in order]
    stack, raw, info = _prepare(stack, raw, dark, bin_factor)

    h, psf_scale = normalize_psf_stack(stack)
    del stack
    raw_scale = float(np.max(np.abs(raw)))
    if not raw_scale > 0:
        raise ReconInputError("the measurement is zero after dark subtraction; check the "
                              "exposure and --dark")
    b = (raw / raw_scale).astype(np.float32)
    op = VolumeConvolutionOperator(h, depths=depths)
    log.info("recon3d: %s, %d planes of %dx%d (padded %s), %d iterations", method, op.n_z,
             *op.sensor_shape, op.padded_shape, iterations)
    result = solver(op, b, iterations=iterations, tv=tv, l1=l1, nonneg=True)
    volume = np.ascontiguousarray(result.x[(slice(None), *op.crop)] * raw_scale,
                                  dtype=np.float32)
    seconds_total = time.perf_counter() - t_start

    floor = fft_floor_seconds(op.padded_shape, op.n_z)
    per_iter = float(np.median(result.history.seconds))
    attrs = {"depths_mm": depths, "units": "measurement counts per unit of the normalised "
             "PSF stack (sum_z (sum h_z)^2 = 1)", "method": method, "psf_stack": str(psf_stack),
             "raw": str(raw_path), "bin_factor": int(bin_factor)}
    _write_volume(vol_path, volume, attrs)
    for view, image in _projections(volume).items():
        save_image(mip_paths[view], image)
    metrics = {
        "method": method,
        "iterations": iterations,
        "tv": tv,
        "l1": l1,
        "shape": list(volume.shape),
        "sensor_shape": list(op.sensor_shape),
        "padded_shape": list(op.padded_shape),
        "n_planes": op.n_z,
        "depths_mm": depths,
        "psf_stack": str(psf_stack),
        "psf_product": psf_product,
        "stack_shape_in": stack_shape_in,
        "raw": str(raw_path),
        "raw_shape_in": raw_shape_in,
        **info,
        "psf_scale": psf_scale,
        "raw_scale": raw_scale,
        "seconds_total": seconds_total,
        "seconds_per_iteration": per_iter,
        "fft_floor_seconds": floor,
        "fft_floor_transforms": f"{op.n_z + 1} rfft2 + {op.n_z + 1} irfft2 at "
                                f"{op.padded_shape[0]}x{op.padded_shape[1]}",
        "ratio_to_fft_floor": per_iter / floor,
        "final_relative_residual": result.final_relative_residual,
        "final_objective": result.final_objective,
        "objective": list(result.history.objective),
        "data_residual": list(result.history.data_residual),
        "params": dict(result.params),
        "output_volume": str(vol_path),
        "output_mips": {k: str(v) for k, v in mip_paths.items()},
    }
    metrics = jsonable(metrics, nonfinite_to_none=True)
    if metrics_json:
        Path(metrics_json).parent.mkdir(parents=True, exist_ok=True)
        Path(metrics_json).write_text(json.dumps(metrics, indent=1))
    return metrics


def summary_line(m: dict) -> str:
    """One line of a recon3d metrics record for the terminal."""
    return (f"{m['method']}: {m['iterations']} it, {m['n_planes']} planes of "
            f"{m['shape'][1]}x{m['shape'][2]} (padded {m['padded_shape']}), "
            f"{m['seconds_total']:.2f} s total, {m['seconds_per_iteration'] * 1e3:.1f} ms/it = "
            f"{m['ratio_to_fft_floor']:.2f}x FFT floor ({m['fft_floor_seconds'] * 1e3:.1f} ms), "
            f"final relative residual {m['final_relative_residual']:.4f} -> "
            f"{m['output_volume']}")


def run(args: argparse.Namespace) -> int:
    """Run ``recon3d``; 0 on success, 2 on bad input (one line), 3 on divergence.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed by the parser of :func:`add_subcommands`.

    Returns
    -------
    int
        The exit status.
    """
    from recon.errors import DivergenceError, ReconInputError

    from .runstore import RunStoreError

    try:
        m = run_recon3d(args.psf_stack, args.raw, method=args.method,
                        iterations=args.iterations, tv=args.tv, l1=args.l1, out=args.out,
                        depths_mm=_parse_depths(args.depths), bin_factor=args.bin_factor,
                        dark=_parse_dark(args.dark), psf_product=args.psf_product,
                        metrics_json=args.metrics_json)
    except DivergenceError as exc:
        print(f"diffuserlab: diverged: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 3
    except (ReconInputError, RunStoreError, ValueError, OSError) as exc:
        text = " ".join(str(exc).split())
        print(f"diffuserlab: error: {text}", file=sys.stderr)
        return 2
    print(summary_line(m))
    return 0

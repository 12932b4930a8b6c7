"""Benchmarks of the reconstruction layer: speed, accuracy, stability, erasures.

Each benchmark is a plain function returning a JSON-ready dict and printing a small
table; :mod:`recon.benchmarks.run` runs them all (``python -m
recon.benchmarks.run --quick``) and writes JSON/PNG files under ``--out``.

This module holds what they share: locating and preprocessing the real DiffuserCam
tutorial sample, the scaled problem the solvers expect (PSF normalised to unit sum,
measurement divided by its maximum), a uniform way to call every solver, and output
helpers.
"""

from __future__ import annotations

import functools
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

import recon

from ..errors import ReconInputError
from ..operators import ConvolutionOperator
from ..preprocess import Prepared, prepare_pair
from ..solvers import SolveResult, admm, fista, gradient_descent, wiener

__all__ = [
    "DATA_ENV",
    "DEFAULT_WEIGHTS",
    "METHODS",
    "data_dir",
    "format_table",
    "jsonable",
    "load_sample",
    "save_figure",
    "scaled_problem",
    "solve",
    "write_json",
]

#: Environment variable overriding the directory of the tutorial sample.
DATA_ENV = "DIFFUSERLAB_DATA"
PSF_FILE = "psf_sample.tif"
RAW_FILE = "rawdata_hand_sample.tif"

#: Methods in the order they are reported.
METHODS: tuple[str, ...] = ("wiener", "gd", "fista", "admm")

#: Per-method regularisation used when no sweep result is passed in: the Tikhonov
#: weight lambda for Wiener, the TV weight tau for the others (scaled problem:
#: unit-sum PSF, measurement / max). These are the weights the accuracy sweep chose
#: on the full run (camera scene, real PSF at bin 4, ~35 dB SNR).
DEFAULT_WEIGHTS: dict[str, float] = {"wiener": 10.0, "gd": 3e-4, "fista": 3e-4, "admm": 1e-3}


def data_dir() -> Path:
    """Directory holding the DiffuserCam tutorial sample.

    ``$DIFFUSERLAB_DATA`` if set, else ``shared/data/diffusercam-tutorial`` next to
    the repository (``Path(recon.__file__).resolve().parents[1].parent``).

    Raises
    ------
    ReconInputError
        If the directory or either TIFF is missing.
    """
    env = os.environ.get(DATA_ENV)
    base = (Path(env) if env else
            Path(recon.__file__).resolve().parents[1].parent / "shared/data/diffusercam-tutorial")
    missing = [f for f in (PSF_FILE, RAW_FILE) if not (base / f).is_file()]
    if missing:
        raise ReconInputError(
            f"DiffuserCam tutorial sample not found: {', '.join(missing)} missing in {base}; "
            f"set {DATA_ENV} to the directory holding {PSF_FILE} and {RAW_FILE}"
        )
    return base


@functools.lru_cache(maxsize=1)
def _raw_pair() -> tuple[np.ndarray, np.ndarray]:
    from ..io import load_image

    base = data_dir()
    psf, raw = load_image(base / PSF_FILE), load_image(base / RAW_FILE)
    psf.setflags(write=False)
    raw.setflags(write=False)
    return psf, raw


@functools.lru_cache(maxsize=4)
def load_sample(bin_factor: int) -> Prepared:
    """The real PSF and hand measurement preprocessed by
    :func:`recon.preprocess.prepare_pair` (dark from the PSF corner, box binning).

    Parameters
    ----------
    bin_factor : int
        4 gives 300 x 400 (padded 600 x 800), 2 gives 600 x 800.

    Returns
    -------
    Prepared
        Cached; do not modify the arrays.
    """
    psf, raw = _raw_pair()
    return prepare_pair(psf, raw, bin_factor=bin_factor)


def scaled_problem(psf: np.ndarray, b: np.ndarray,
                   weights: np.ndarray | None = None) -> tuple[ConvolutionOperator, np.ndarray]:
    """Operator and measurement in the solvers' scaling convention.

    Parameters
    ----------
    psf : ndarray (rows, cols)
        Non-negative PSF; normalised here to unit sum (so |H| <= 1).
    b : ndarray (rows, cols)
        Measurement; multiplied by ``weights`` if given, then divided by its max.
    weights : ndarray (rows, cols), optional
        Sensor weights / erasure mask (Eq. 3.10).

    Returns
    -------
    op : ConvolutionOperator
    b_scaled : ndarray, float32
    """
    h = np.asarray(psf, np.float64)
    op = ConvolutionOperator((h / h.sum()).astype(np.float32), sensor_weights=weights)
    bb = np.asarray(b, np.float64)
    if weights is not None:
        bb = bb * weights
    peak = float(np.max(bb))
    if not peak > 0:
        raise ReconInputError("measurement has no positive value after weighting")
    return op, (bb / peak).astype(np.float32)


def solve(method: str, op: ConvolutionOperator, b: np.ndarray, iterations: int,
          weight: float, lipschitz: float | None = None) -> SolveResult:
    """Run one of :data:`METHODS` with its single regularisation weight.

    Parameters
    ----------
    method : {"wiener", "gd", "fista", "admm"}
    op, b
        Scaled problem (see :func:`scaled_problem`).
    iterations : int
        Ignored by Wiener (one shot).
    weight : float
        Wiener: Tikhonov lambda; others: TV weight tau.
    lipschitz : float, optional
        Known Lipschitz constant for GD/FISTA (skips the power iteration).

    Returns
    -------
    SolveResult

    Raises
    ------
    DivergenceError
        Passed through from the solver.
    """
    if method == "wiener":
        return wiener(op, b, weight)
    if method == "gd":
        return gradient_descent(op, b, iterations, tv=weight, lipschitz=lipschitz)
    if method == "fista":
        return fista(op, b, iterations, tv=weight, lipschitz=lipschitz)
    if method == "admm":
        return admm(op, b, iterations, tv=weight)
    raise ReconInputError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")


def jsonable(obj: Any) -> Any:
    """Recursively convert numpy scalars/arrays and tuples; non-finite floats -> None."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.integer | bool):
        return obj if isinstance(obj, bool) else int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, float | np.floating):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


def write_json(path: Path, data: dict) -> Path:
    """Write ``data`` (made JSON-safe by :func:`jsonable`) with indentation."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(jsonable(data), indent=1, allow_nan=False) + "\n")
    return path


def save_figure(fig, path: Path) -> Path:
    """Save a :class:`matplotlib.figure.Figure` (no pyplot state involved)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    return path


def format_table(headers: list[str], rows: list[list[Any]]) -> str:
    """Plain-text table with left-aligned first column and right-aligned others."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = []
    for k, r in enumerate(cells):
        parts = [r[0].ljust(widths[0])] + [c.rjust(w) for c, w in zip(r[1:], widths[1:],
                                                                       strict=True)]
        lines.append("  ".join(parts))
        if k == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)


def fmt(value: float | None, spec: str = ".2f") -> str:
    """Format a number, or '-' for None/non-finite."""
    if value is None or not isinstance(value, int | float) or not math.isfinite(value):
        return "-"
    return format(value, spec)

"""Benchmarks of the reconstruction layer: speed, accuracy, stability, erasures.

Each benchmark is a plain function returning a JSON-ready dict, with a function
formatting its small table; :func:`instrument.benchmarks.run.run_benchmarks` runs them
all and writes JSON/PNG files under ``out`` (``diffuserlab benchmark recon
[--quick]`` runs it and prints the tables).

This module holds what they share: locating and preprocessing the real DiffuserCam
tutorial sample, the scaled problem the solvers expect (PSF normalised to unit sum,
measurement divided by its maximum), a uniform way to call every solver, and output
helpers.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from diffuserlab.jsonio import jsonable
from recon.api import DEFAULT_TV, scaled_problem
from recon.api import solve as api_solve
from recon.operators import ConvolutionOperator
from recon.sample import DATA_ENV, data_dir, load_sample
from recon.solvers import METHODS, SOLVERS, SolveResult

from ..atomic import write_json

__all__ = [
    "DATA_ENV",
    "DEFAULT_WEIGHTS",
    "METHODS",
    "data_dir",
    "format_table",
    "jsonable",
    "load_sample",
    "log_x_axis",
    "save_figure",
    "scaled_problem",
    "solve",
    "write_json",
]


#: Per-method regularisation used when no sweep result is passed in: the TV weight
#: tau of :data:`recon.api.DEFAULT_TV` (scaled problem: unit-sum PSF, measurement /
#: max) and, for Wiener, the Tikhonov lambda the accuracy sweep chose on whole-FoV
#: scenes (the crop the Wiener filter ignores dominates its error there).
DEFAULT_WEIGHTS: dict[str, float] = {**DEFAULT_TV, "wiener": 10.0}


def solve(method: str, op: ConvolutionOperator, b: np.ndarray, iterations: int,
          weight: float, lipschitz: float | None = None) -> SolveResult:
    """Run one of :data:`METHODS` with its single regularisation weight.

    A thin adapter over :func:`recon.api.solve`: ``weight`` is the Tikhonov lambda
    for Wiener and the TV weight tau for the others; ``lipschitz`` (GD/FISTA) skips
    the power iteration.

    Raises
    ------
    DivergenceError
        Passed through from the solver.
    """
    if not SOLVERS[method].iterative:
        return api_solve(op, b, method, iterations=1, tv=0.0, regularization=weight)
    extra = {"lipschitz": lipschitz} if method in ("gd", "fista") else {}
    return api_solve(op, b, method, iterations=iterations, tv=weight, **extra)


def machine_record() -> dict:
    """Where and when a benchmark ran: UTC date, platform, CPU count, Python and NumPy
    versions and the 1-minute load average (the machine may be shared).

    Returns
    -------
    dict
        ``date_utc`` (ISO 8601 str), ``platform``, ``cpu_count`` (int), ``python``,
        ``numpy`` (str) and ``load_average_start`` (three floats, or None where the
        system has none).
    """
    import datetime
    import os
    import platform

    try:
        load = list(os.getloadavg())
    except OSError:
        load = None
    return {"date_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M"),
            "platform": platform.platform(terse=True), "cpu_count": os.cpu_count(),
            "python": platform.python_version(), "numpy": np.__version__,
            "load_average_start": load}


def save_figure(fig, path: Path) -> Path:
    """Save a :class:`matplotlib.figure.Figure` (no pyplot state involved)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from ..writer.figures import save_figure as write_figure

    FigureCanvasAgg(fig)
    return write_figure(fig, path, dpi=110, bbox_inches="tight")


def log_x_axis(ax) -> None:
    """Log-scaled x axis of a matplotlib ``Axes``, labelled on the decades only (the
    default minor-tick labels overlap on short ranges)."""
    from matplotlib.ticker import NullFormatter

    ax.set_xscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())


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

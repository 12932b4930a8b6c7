"""Shared solver plumbing: the result/history record, divergence detection and the
iterative solvers' declared iteration default."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import DivergenceError, ReconInputError
from ..options import ReconOptions

#: Default iterations of every iterative solver (:func:`recon.solvers.admm`,
#: :func:`recon.solvers.fista`, :func:`recon.solvers.gradient_descent`,
#: :func:`recon.volume.admm3d`, :func:`recon.volume.fista3d`,
#: :func:`recon.spatial.spatial_admm`, :func:`recon.spatial.fista_background`): the
#: declared ``iterations`` of :class:`recon.options.ReconOptions`, what
#: :func:`recon.reconstruct` and the commands default to (stated there, once).
DEFAULT_ITERATIONS: int = ReconOptions.defaults()["iterations"]


@dataclass
class History:
    """Per-iteration record of a solve.

    Attributes
    ----------
    objective : list of float
        Objective 1/2 ||A x - b||^2 + tau TV(x) (or the method's own cost), one entry
        per iteration, evaluated where the method makes it free (see each solver).
    data_residual : list of float
        Relative data residual ||A x - b|| / ||b|| per iteration.
    seconds : list of float
        Wall time of each iteration, s.
    extra : dict
        Method-specific traces (penalties, restarts, ...).
    """

    objective: list[float] = field(default_factory=list)
    data_residual: list[float] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)
    extra: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        """JSON-ready copy."""
        return {"objective": list(self.objective), "data_residual": list(self.data_residual),
                "seconds": list(self.seconds), **{k: list(v) if isinstance(v, list) else v
                                                   for k, v in self.extra.items()}}


@dataclass
class SolveResult:
    """An estimate and how it was obtained.

    Attributes
    ----------
    x : ndarray, float32
        The estimate on the operator's input grid (the padded object domain).
    history : History
    final_objective : float
    final_relative_residual : float
        ||A x - b|| / ||b|| of the returned estimate.
    params : dict
        The parameters actually used (steps, penalties, weights).
    """

    x: np.ndarray
    history: History
    final_objective: float
    final_relative_residual: float
    params: dict


def check_measurement(b, shape: tuple[int, ...]) -> np.ndarray:
    """Validate a (scaled) measurement for a solver; returns it as C-contiguous float32.

    Raises
    ------
    ReconInputError
        Wrong shape, NaN/inf values, or all zero.
    """
    b = np.ascontiguousarray(b, dtype=np.float32)
    if b.shape != tuple(shape):
        raise ReconInputError(
            f"measurement has shape {b.shape}, the forward model expects {tuple(shape)}; "
            "bin or crop the raw image like the PSF"
        )
    bad = b.size - int(np.count_nonzero(np.isfinite(b)))
    if bad:
        raise ReconInputError(
            f"measurement contains {bad} NaN/inf values; fix or mask those pixels "
            "(erasure mask) before reconstructing"
        )
    if not np.any(b):
        raise ReconInputError(
            "measurement is all zero after preprocessing; check the exposure and the dark level"
        )
    return b


def anisotropic_tv(x: np.ndarray) -> float:
    """Anisotropic TV: sum of |circular forward differences| over all axes.

    The TV term of Eq. 2.5 with Psi the finite-difference operator (Sec. 2.2),
    circular as in the padded domain of Eq. 3.4. float64 accumulation.
    """
    return float(sum(np.abs(np.roll(x, -1, axis=a) - x).sum(dtype=np.float64)
                     for a in range(x.ndim)))


class Monitor:
    """Times iterations, records the history and stops a diverging run.

    A run diverges when the objective is NaN/inf or exceeds ``growth_limit`` times
    the objective of the zero image, 1/2 ||b||^2, which any sane iterate of a
    non-negative least-squares problem starting from zero stays well below.

    Parameters
    ----------
    b_norm_sq : float
        ||b||^2 of the (scaled) measurement.
    method : str
        Name used in error messages.
    growth_limit : float
        Divergence threshold, in units of the zero-image objective.
    """

    snapshot_every = 10

    def __init__(self, b_norm_sq: float, method: str, growth_limit: float = 100.0):
        if not b_norm_sq > 0 or not math.isfinite(b_norm_sq):
            raise ReconInputError(
                "measurement is all zero (or not finite) after preprocessing; check the "
                "exposure and the dark level"
            )
        self.b_norm = math.sqrt(b_norm_sq)
        self.limit = growth_limit * 0.5 * b_norm_sq
        self.method = method
        self.history = History()
        self._t0 = time.perf_counter()
        self._last_good = None

    def start(self) -> None:
        """Mark the start of an iteration."""
        self._t0 = time.perf_counter()

    def record(self, objective: float, data_sq: float, x=None, hint: str = "") -> None:
        """Close an iteration: store its figures and raise on divergence.

        Every ``snapshot_every`` healthy iterations a copy of ``x`` is kept, so a
        divergence error carries the last good estimate (amortised cost: one copy
        per ten iterations).

        Raises
        ------
        DivergenceError
            With the history so far and the last good estimate attached.
        """
        self.history.seconds.append(time.perf_counter() - self._t0)
        self.history.objective.append(float(objective))
        self.history.data_residual.append(math.sqrt(max(data_sq, 0.0)) / self.b_norm)
        k = len(self.history.objective)
        if not math.isfinite(objective) or objective > self.limit:
            raise DivergenceError(
                f"{self.method} diverged at iteration {k}: objective {objective:.3g} "
                f"(zero image gives {self.limit / 100:.3g}). {hint}".strip(),
                history=self.history.as_dict(),
                last_good=None if self._last_good is None else self._last_good.copy(),
            )
        if x is not None and (k - 1) % self.snapshot_every == 0:
            if self._last_good is None or self._last_good.shape != x.shape:
                self._last_good = np.array(x, copy=True)
            else:
                np.copyto(self._last_good, x)  # no allocation in the loop
            self.history.seconds[-1] = time.perf_counter() - self._t0  # copy included

"""Shared pieces of :mod:`recon.cgh`: the result record, projections, target checks."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ReconInputError
from ..solvers.common import History
from ..validate import as_array

SLM_KINDS = ("phase", "complex")


@dataclass
class HologramResult:
    """An SLM pattern and how it was computed.

    Attributes
    ----------
    field : numpy.ndarray
        complex64 ``slm_shape``: the SLM field ``s`` (unit modulus for a phase-only
        SLM, ``|s| <= 1`` for a complex one).
    phase : numpy.ndarray
        float32 ``slm_shape``: ``angle(s)`` in radians, ``(-pi, pi]``; what a
        phase-only SLM displays (through its LUT).
    loss : float
        Final loss (NaN for the one-step baseline, which has none).
    history : recon.solvers.common.History
        Per iteration: ``objective`` (loss at the accepted iterate), ``data_residual``
        (``sqrt(2 L / 2 L_0)`` with ``L_0`` the loss of a dark image), ``seconds``;
        ``extra`` holds ``step``, ``backtracks``, ``ffts`` (complex-FFT equivalents),
        ``restarts`` (iteration indices) and ``fft_seconds``.
    seconds : float
        Wall time of the computation (s), set-up included.
    iterations : int
        Iterations run.
    ffts_per_iteration : float
        Mean complex-FFT equivalents per iteration (a real FFT counts one half).
    stop_reason : str
        Why the loop ended.
    checkpoints : dict
        ``{iteration: field}`` copies requested with ``checkpoints=``; each entry also
        has its cumulative seconds in ``checkpoint_seconds``.
    checkpoint_seconds : dict
        ``{iteration: seconds since the start}``.
    params : dict
        Parameters actually used.
    """

    field: np.ndarray
    phase: np.ndarray
    loss: float
    history: History
    seconds: float
    iterations: int = 0
    ffts_per_iteration: float = 0.0
    stop_reason: str = ""
    checkpoints: dict = field(default_factory=dict)
    checkpoint_seconds: dict = field(default_factory=dict)
    params: dict = field(default_factory=dict)


def check_slm_kind(slm: str) -> str:
    """Validate the SLM kind: ``"phase"`` (phase-only, Eq. A.6) or ``"complex"`` (Fig. 7.8)."""
    if slm not in SLM_KINDS:
        raise ReconInputError(f"slm must be one of {SLM_KINDS}, got {slm!r}")
    return slm


def project(v: np.ndarray, slm: str, out: np.ndarray | None = None) -> np.ndarray:
    """Projection onto the SLM's feasible set.

    ``"phase"``: ``v / |v|`` (Eq. A.6), with ``1`` where ``v = 0``;
    ``"complex"``: ``v / max(1, |v|)`` (amplitude at most 1, Fig. 7.8).

    Parameters
    ----------
    v : numpy.ndarray
        complex64 SLM field.
    slm : {"phase", "complex"}
    out : numpy.ndarray, optional
        complex64 output buffer.

    Returns
    -------
    numpy.ndarray
        complex64, ``v.shape``.
    """
    a = np.abs(v)
    if slm == "phase":
        zero = a == 0
        a[zero] = 1.0
        res = np.divide(v, a, out=out)
        res[zero] = 1.0
        return res
    np.maximum(a, 1.0, out=a)
    return np.divide(v, a, out=out)


def check_targets(targets, display) -> np.ndarray:
    """Target intensities as float32 ``(n_planes, G_y, G_x)`` (centred frame).

    Raises
    ------
    ReconInputError
        Wrong shape, NaN/inf, negative values, or an all-zero plane.
    """
    t = given = as_array(targets, "target")
    if t.dtype.kind not in "fiu" or t.dtype == np.bool_:
        raise ReconInputError(f"target must be real intensities, got dtype {t.dtype}")
    grid = tuple(display.grid_shape)
    if t.shape == grid:
        t = t[None]
    if t.shape != (display.n_planes, *grid):
        raise ReconInputError(
            f"target has shape {given.shape}; the display needs {grid} per plane "
            f"({display.n_planes} plane(s)): resize the image to SLM shape x k")
    t = np.ascontiguousarray(t, dtype=np.float32)
    if not np.all(np.isfinite(t)):
        raise ReconInputError("target contains NaN or inf")
    if np.any(t < 0):
        raise ReconInputError("target intensities must be >= 0 (use intensity, not amplitude)")
    for p in range(t.shape[0]):
        if not np.any(t[p]):
            raise ReconInputError(f"target plane {p} is all zero; nothing to display")
    return t

"""Baseline: one-step back-propagation (Eq. 7.11-7.13).

One-step back-propagation is the algorithm of the prior work the dissertation
compares against (Popoff, Buckley, Yu, Park): assign the target a random phase,
propagate it back through the lens and the conjugate mask, integrate the field
over each SLM pixel and keep only the phase. The other reference, the no-mask
display (the same optimiser on the bare SLM), is
:func:`recon.cgh.optimize.no_mask_hologram`.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import ReconInputError
from ..operators import real32
from ..solvers.common import History
from ..validate import as_int
from .hologram import HologramResult, check_slm_kind, check_targets, project
from .scattering_display import ScatteringDisplay

__all__ = ["one_step_hologram", "random_phase_field"]


def random_phase_field(target, seed: int = 0) -> np.ndarray:
    """Target field ``sqrt(T) exp(i 2 pi theta)`` with ``theta ~ U[0, 1)`` (Eq. 7.13).

    Parameters
    ----------
    target : numpy.ndarray
        Real, non-negative intensities, any shape.
    seed : int
        Seed of :func:`numpy.random.default_rng` for ``theta`` (>= 0).

    Returns
    -------
    numpy.ndarray
        complex64, ``target.shape``.

    Raises
    ------
    ReconInputError
        Non-real, negative or non-finite target, or a seed not an integer >= 0.
    """
    t = real32(target, "target")
    if not np.all(np.isfinite(t)) or np.any(t < 0):
        raise ReconInputError("target must be finite and >= 0")
    theta = np.random.default_rng(as_int(seed, "seed", 0)).random(t.shape, dtype=np.float32)
    ang = np.float32(2.0 * math.pi) * theta
    out = np.empty(t.shape, np.complex64)
    amp = np.sqrt(t)
    out.real = amp * np.cos(ang)
    out.imag = amp * np.sin(ang)
    return out


def one_step_hologram(display: ScatteringDisplay, target, seed: int = 0,
                      slm: str = "phase") -> HologramResult:
    """One-step back-propagation with a random target phase (Eq. 7.11-7.13).

    ``p_i = arg( sum_{u in pixel i} F_c^H{ sqrt(T) e^{i phi} }(u) m*(u) )``, i.e.
    ``arg(display.adjoint(y_target))``: the per-pixel integral of Eq. 7.12 is the
    binning ``U^T``, and averaging the complex field (not the angles) is the
    L2-optimal phase-only value per pixel. With several planes the back-propagated
    fields add.

    Parameters
    ----------
    display : ScatteringDisplay
    target : numpy.ndarray
        Target intensity, ``display.grid_shape`` (or ``(n_planes, *grid_shape)``),
        centred frame, >= 0.
    seed : int
        Seed of the random target phase (>= 0).
    slm : {"phase", "complex"}
        Phase-only (keep the phase) or complex SLM (keep the field, scaled so the
        largest amplitude is 1).

    Returns
    -------
    HologramResult
        With ``loss = nan`` and an empty history (no iterations).

    Raises
    ------
    ReconInputError
        Bad display, target (``recon.cgh.hologram.check_targets``), seed or slm.
    """
    if not isinstance(display, ScatteringDisplay):
        raise ReconInputError(f"display must be a ScatteringDisplay, got {type(display).__name__}")
    check_slm_kind(slm)
    t0 = time.perf_counter()
    t = check_targets(target, display)
    y = random_phase_field(t, seed).reshape(display.shape_out)
    z = display.adjoint(y)
    if slm == "phase":
        s = project(z, "phase")
    else:
        peak = float(np.abs(z).max())
        s = (z / peak if peak > 0 else np.ones_like(z)).astype(np.complex64)
    seconds = time.perf_counter() - t0
    return HologramResult(field=s, phase=np.angle(s).astype(np.float32), loss=float("nan"),
                          history=History(), seconds=seconds, iterations=0,
                          ffts_per_iteration=0.0, stop_reason="one-step",
                          params={"method": "one-step", "seed": seed, "slm": slm})


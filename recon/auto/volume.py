"""Automatic 3D weight and planes: hold-out cross-validation over a short weight grid,
then only the planes that hold signal (Kuo 2020, Ch. 4; :mod:`recon.auto.weight` for
the criterion).

The 2D path needs a warm-startable solver; the 3D solvers are one call each, so the
candidates are the few weights the 3D accuracy benchmark found worth trying
(:data:`CANDIDATES`), each solved for a third of the iterations on 90 % of the pixels
(the fit) and scored by how well it predicts the other 10 %; the one-standard-error
rule picks the largest weight close to the best. Those fits are also the cheap first
estimate of where the signal lies: planes whose peak is below :data:`PLANE_FRACTION`
of the brightest plane's are dropped, and
the final solve (``iterations``) runs on the remaining planes only (a smaller forward
model, fewer FFTs), the dropped planes returned as zeros. Cost: the candidates
together take the iterations of one full solve, on all planes; the final solve at
most one more: at most 2x a fixed-weight run.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import DivergenceError

__all__ = ["CANDIDATES", "PLANE_FRACTION", "auto_volume"]

#: 3D weights tried per regulariser (scaled problem): the 3D accuracy benchmark's
#: best weights lie in 1e-6 .. 1e-4 for TV; l1 from 1e-4 (beads) to 1e-2.
CANDIDATES = {"tv": (1e-4, 1e-5, 1e-6), "l1": (1e-2, 1e-3, 1e-4)}
#: A plane whose first-estimate peak (its brightest voxel in the field of view, over
#: the candidates) is below this fraction of the brightest plane's holds no signal.
#: Plane sums do not separate (the far planes' broad PSFs spread a diffuse background
#: over them: sums 0.47-1.0 of the largest with beads in one plane only) and the short
#: candidate fits blur the peaks too (0.19-0.43 of the bead plane's there, against
#: 0.03-0.15 after a full solve), hence one half. A plane holding signal less than half
#: as bright as the brightest plane's is dropped with it: a limitation.
PLANE_FRACTION = 0.5
HOLDOUT = 0.1


def _planes(op, kept: list[int]):
    """The forward model of the planes ``kept`` only (sharing their spectra)."""
    depths = None if op.depths is None else [op.depths[k] for k in kept]
    return type(op)(np.ascontiguousarray(op.psf_stack[kept]), padded_shape=op.padded_shape,
                    sensor_weights=op.sensor_weights, depths=depths,
                    _spectra=np.ascontiguousarray(op.spectra[kept]))


def auto_volume(solve, op, b: np.ndarray, *, iterations: int, regulariser: str, other: float,
                seed: int = 0) -> tuple[object, dict]:
    """Choose the 3D weight and the planes, then solve.

    Parameters
    ----------
    solve : callable
        ``solve(op, b, iterations=, tv=, l1=, nonneg=True) -> SolveResult``
        (:func:`recon.volume.admm3d` or :func:`recon.volume.fista3d`).
    op : VolumeConvolutionOperator
        Scaled forward model (normalised stack).
    b : ndarray, float32, ``op.shape_out``
        Scaled measurement.
    iterations : int
        Iterations of the final solve (the candidates share as many).
    regulariser : {"tv", "l1"}
        The weight to choose; ``other`` is the fixed value of the other one.
    seed : int
        Seed of the held-out pixels.

    Returns
    -------
    result : SolveResult
        On all planes (``x`` of ``op.shape_in``; dropped planes are zero).
    record : dict
        ``weight``, ``regulariser``, ``candidates`` (weight, held-out error, standard
        error), ``planes_kept`` (indices), ``plane_energy`` (each plane's peak in the first
        estimate), ``reason``.
    """
    keep = np.random.default_rng(seed).random(op.sensor_shape) >= HOLDOUT
    held = (op.sensor_weights > 0) & ~keep
    fit_op = op.with_weights(op.sensor_weights * keep)
    b_fit = np.ascontiguousarray(b * keep, np.float32)
    per = max(1, iterations // len(CANDIDATES[regulariser]))
    cands, energy = [], None
    for w in CANDIDATES[regulariser]:
        tv, l1 = (w, other) if regulariser == "tv" else (other, w)
        try:
            r = solve(fit_op, b_fit, iterations=per, tv=tv, l1=l1, nonneg=True)
        except DivergenceError:
            continue
        e = np.square(op.forward(r.x) - b, dtype=np.float64)[held]
        cands.append({"weight": w, "holdout_error": float(e.sum()),
                      "standard_error": float(e.std() * math.sqrt(e.size))})
        plane = np.max(r.x[(slice(None), *op.crop)].reshape(op.n_z, -1), axis=1)
        energy = plane if energy is None else np.maximum(energy, plane)
    if not cands:
        raise DivergenceError("3D automatic weight: every candidate diverged; give fixed "
                              "weights (--tv, --l1)")
    best = min(cands, key=lambda c: c["holdout_error"])
    chosen = next(c for c in cands
                  if c["holdout_error"] <= best["holdout_error"] + best["standard_error"])
    kept = [k for k in range(op.n_z) if energy[k] >= PLANE_FRACTION * energy.max()]
    tv, l1 = ((chosen["weight"], other) if regulariser == "tv" else (other, chosen["weight"]))
    sub = op if len(kept) == op.n_z else _planes(op, kept)
    result = solve(sub, b, iterations=iterations, tv=tv, l1=l1, nonneg=True)
    if sub is not op:
        x = np.zeros(op.shape_in, np.float32)
        x[kept] = result.x
        result.x = x
    record = {"regulariser": regulariser, "weight": chosen["weight"], "candidates": cands,
              "planes_kept": kept, "plane_energy": [float(v) for v in energy],
              "reason": (f"hold-out cross-validation over {len(cands)} weights "
                         f"({per} iterations each on 90 % of the pixels, one-standard-error "
                         f"rule); {len(kept)} of {op.n_z} planes hold >= "
                         f"{100 * PLANE_FRACTION:g} % of the brightest plane's peak")}
    return result, record

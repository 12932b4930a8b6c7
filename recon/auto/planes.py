"""Which planes of a volume estimate show signal: a held-out regression test (Kuo 2020,
Eq. 4.4: the measurement is the sum of the planes' predictions).

A plane is tested on the pixels no fit saw (the held-out blocks of
:func:`recon.auto.holdout.holdout_split`). Its prediction there, ``p_k = w C (h_k * x_k)``,
is one regressor of the held-out data ``b_h`` beside the other planes' summed
prediction and a constant, ``b_h ~ c + g sum_{j != k} p_j + a_k p_k``, fitted by
weighted least squares (weights 1 / var from the frame's fitted Poisson-Gaussian
noise model, :mod:`recon.auto.noise`). The constant and the common gain absorb what
every plane's estimate shares: a weakly regularised estimate clipped to non-negative
values over-predicts every pixel a little. A plane shows signal when ``a_k`` is
:data:`SIGNAL_SNR` standard errors above zero (its prediction explains held-out data
the other planes do not), or when removing it makes the held-out error worse by
:data:`SIGNAL_SNR` standard errors of that change (a plane of noise worsens it as
often as it improves it, so "any worsening" would pass half of the empty planes).
Nothing is compared with the brightest plane.

Both standard errors come from the data, over tiles of the sensor (:func:`clusters`:
a 12 x 12 grid; cluster-robust, Liang & Zeger 1986), not from the noise model or
from pixels taken as independent: the forward model's mismatch on the bright planes
leaves a residual correlated over the caustic's lines, and a plane's prediction is
correlated the same way. Taken pixel by pixel the tests were overconfident: on 8
draws of a 6-plane bead scene with planes 3-5 empty (3000 e-, rendered on a 2x finer
grid), the empty planes' ``t`` spread from -20 to +11 (6 of 24 at 3 or more, their
verdicts flipping with the weight the path chose); by tiles, -3.6 to +3.4 (1 of 24),
the bead planes 2.4-243 (each above 3 in ``t`` or in the removal test).

The test can confirm signal; it cannot always confirm emptiness. Where the model's
mismatch with the brightest planes is larger than a dim plane's whole contribution,
that plane's evidence drowns: the farthest bead of a 6-plane scene, 30x dimmer than the
nearest, reconstructed at its depth, showed ``t`` 2.3 and a removal that improved the
held-out error at 3000 e- (``t`` 5.2 at 30000 e-); light a near plane's object leaks
into the next, nearly alike, plane's PSF shows there as signal. So the planes without
evidence are reported, and set to zero only when asked (:func:`planes_record`),
jointly tested first (:func:`joint_drop`).
"""

from __future__ import annotations

import math

import numpy as np

from ..fft import irfftn, rfftn

__all__ = ["CLUSTER_TILES", "SIGNAL_SNR", "clusters", "joint_drop", "plane_predictions",
           "plane_tests", "planes_record"]

#: Standard errors a plane's held-out regression coefficient, or the held-out error its
#: removal adds, must reach (one-sided: a plane of fitted noise passes either with
#: probability about 0.13 % each, and is then kept).
SIGNAL_SNR = 3.0
#: Tiles per side of the grid whose tiles are the tests' independent samples
#: (:func:`clusters`): 144 at most, 74 holding held-out pixels at 150 x 200.
CLUSTER_TILES = 12


def plane_predictions(op, x: np.ndarray) -> np.ndarray:
    """Each plane's predicted measurement ``w C (h_k * x_k)`` (Eq. 4.4, one term).

    Parameters
    ----------
    op : VolumeConvolutionOperator
    x : ndarray, float32, ``op.shape_in``

    Returns
    -------
    ndarray, float32, (n_z, rows, cols)
        Their sum is ``op.forward(x)``.
    """
    spec = rfftn(np.asarray(x, np.float32))
    spec *= op.spectra
    full = irfftn(spec, op.padded_shape)
    return (op.sensor_weights * full[(slice(None), *op.crop)]).astype(np.float32)


def clusters(shape: tuple[int, int], held: np.ndarray, tiles: int = CLUSTER_TILES
             ) -> np.ndarray:
    """The cluster of each held-out pixel: its tile of a ``tiles`` x ``tiles`` grid over
    the sensor (in ``held``'s order, int).

    Neighbouring pixels' residuals are correlated (the model's mismatch and a
    caustic's lines span several pixels), so the tests treat a tile, not a pixel, as
    an independent sample.
    """
    r = np.arange(shape[0]) * tiles // max(shape[0], 1)
    c = np.arange(shape[1]) * tiles // max(shape[1], 1)
    return (r[:, None] * tiles + c[None, :])[held]


def _dense(groups: np.ndarray) -> tuple[np.ndarray, int]:
    """Cluster labels renumbered 0 .. G-1 (the tiles holding held-out pixels) and G."""
    ids, dense = np.unique(groups, return_inverse=True)
    return dense.ravel(), int(ids.size)


def _wls(columns: list, y: np.ndarray, sw: np.ndarray, groups: tuple[np.ndarray, int]
         ) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares ``y ~ X a`` (rows weighted by ``sw``) with
    cluster-robust standard errors (the sandwich ``B M B``, ``B = (X'X)^-1``,
    ``M = sum_g (X_g' e_g)(X_g' e_g)'`` over the clusters ``groups``, scaled by
    ``G / (G - 1)``; Liang & Zeger 1986). ``groups``: :func:`_dense`'s labels and G.

    Returns the coefficients and their t statistics (NaN with fewer than 2 clusters).
    """
    X = np.stack(columns, axis=1) * sw[:, None]
    yw = y * sw
    coef, *_ = np.linalg.lstsq(X, yw, rcond=None)
    e = yw - X @ coef
    g, n = groups
    if n < 2:
        return coef, np.full_like(coef, math.nan)
    scores = np.stack([np.bincount(g, X[:, j] * e, minlength=n)
                       for j in range(X.shape[1])], axis=1)
    bread = np.linalg.pinv(X.T @ X)
    cov = bread @ (scores.T @ scores) @ bread * (n / (n - 1))
    se = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    return coef, coef / se


def _regress(y: np.ndarray, sw: np.ndarray, groups: tuple[np.ndarray, int], rest: np.ndarray,
             q: np.ndarray) -> tuple:
    """``y ~ c + g rest + a q`` by weighted least squares: ``(a, t of a)``."""
    if not np.any(q):
        return 0.0, math.nan
    coef, t = _wls([np.ones_like(y), rest, q], y, sw, groups)
    return float(coef[2]), float(t[2])


def _removal_z(rh: np.ndarray, q: np.ndarray, groups: tuple[np.ndarray, int]
               ) -> tuple[float, float]:
    """The held-out squared error added by removing the prediction ``q`` and that
    change in standard errors of its sum over the clusters (``groups``: :func:`_dense`'s
    labels and G; NaN when undefined)."""
    g, n = groups
    d = np.bincount(g, np.square(rh + q) - np.square(rh), minlength=n)
    worse = float(d.sum())
    sd = float(np.std(d, ddof=1)) if n > 1 else 0.0
    return worse, (worse / (math.sqrt(n) * sd) if sd > 0 and np.any(q) else math.nan)


def plane_tests(op, x: np.ndarray, b: np.ndarray, variance: np.ndarray,
                held: np.ndarray) -> dict:
    """Whether each plane of a volume estimate shows signal in held-out pixels.

    Parameters
    ----------
    op : VolumeConvolutionOperator
        Scaled forward model.
    x : ndarray, float32, ``op.shape_in``
        The estimate (fitted without the held-out pixels).
    b : ndarray, float32, ``op.shape_out``
        Scaled measurement.
    variance : ndarray, ``op.shape_out``
        Noise variance per pixel of ``b`` (:meth:`recon.auto.noise.NoiseModel.variance`,
        weights folded in); floored at its smallest positive value; all zero gives
        unweighted rows.
    held : ndarray of bool, ``op.shape_out``
        The held-out pixels.

    Returns
    -------
    dict
        Per plane: ``t`` (its held-out coefficient in standard errors; NaN for a
        plane that predicts nothing), ``coefficient``, ``removal_worsens_by`` (the
        held-out squared error added by removing it), ``removal_z`` (that error in
        standard errors of its sum over the tiles of :func:`clusters`; NaN for a
        plane that predicts nothing); ``t`` and ``removal_z`` are cluster-robust, ``holds_signal``;
        ``predictions`` (per plane, float32 (n_z, rows, cols)); ``residual`` (``b``
        minus their sum); ``held`` (what :func:`joint_drop` needs: the held-out
        data, weights, predictions and clusters).
    """
    p = plane_predictions(op, x)
    r = b - p.sum(axis=0)
    y = b[held].astype(np.float64)
    v = variance[held].astype(np.float64)
    sw = (1.0 / np.sqrt(np.maximum(v, v[v > 0].min())) if np.any(v > 0)
          else np.ones_like(y))
    groups = _dense(clusters(b.shape[-2:], held))  # labelled once for every test
    cols = p[:, held].astype(np.float64)
    total = cols.sum(axis=0)
    rh = r[held].astype(np.float64)
    t, coef, worse, worse_z, signal = [], [], [], [], []
    for k in range(op.n_z):
        a, tk = _regress(y, sw, groups, total - cols[k], cols[k])
        t.append(tk)
        coef.append(a)
        wk, zk = _removal_z(rh, cols[k], groups)
        worse.append(wk)
        worse_z.append(zk)
        signal.append(bool((not math.isnan(tk) and tk >= SIGNAL_SNR)
                           or (not math.isnan(zk) and zk >= SIGNAL_SNR)))
    return {"t": t, "coefficient": coef, "removal_worsens_by": worse,
            "removal_z": worse_z,
            "holds_signal": signal, "predictions": p, "residual": r,
            "held": {"y": y, "sw": sw, "columns": cols, "groups": groups}}


def joint_drop(tests: dict, empty: list) -> tuple[list, dict]:
    """The planes of ``empty`` that may go together, by the same held-out regression.

    Their summed prediction is the regressor: while it is :data:`SIGNAL_SNR` standard
    errors above zero (together they explain held-out data), the plane with the
    largest t of those left is kept instead.

    Returns
    -------
    dropped : list of int
    record : dict
        ``t`` of the last joint test (None when nothing was tested).
    """
    h = tests["held"]
    total = h["columns"].sum(axis=0)
    left = sorted(empty, key=lambda k: -(tests["t"][k] if not math.isnan(tests["t"][k])
                                          else -1e9))
    record = {"t": None}
    while left:
        q = h["columns"][left].sum(axis=0)
        _, t_joint = _regress(h["y"], h["sw"], h["groups"], total - q, q)
        record = {"t": None if math.isnan(t_joint) else t_joint}
        if math.isnan(t_joint) or t_joint < SIGNAL_SNR:
            break
        left.pop(0)
    return sorted(left), record


def planes_record(op, x: np.ndarray, b: np.ndarray, tests: dict, held: np.ndarray,
                  empty_planes: str) -> tuple[list, list, dict]:
    """Per-plane records, the planes kept, and what dropping those without evidence did.

    Parameters
    ----------
    op, x, b, held
        As :func:`plane_tests`.
    tests : dict
        :func:`plane_tests`' result.
    empty_planes : {"keep", "drop"}
        ``"keep"``: every plane stays (those without evidence are reported);
        ``"drop"``: those that show no signal, alone or together
        (:func:`joint_drop`), are set to zero.

    Returns
    -------
    planes : list of dict
        Per plane: ``plane``, ``depth_mm``, ``energy`` and ``energy_share`` (of the
        field of view), ``holdout_t``, ``holdout_coefficient``,
        ``removal_worsens_holdout_by``, ``removal_worsens_holdout_z`` (in standard
        errors), ``shows_signal``.
    kept : list of int
    drop : dict
        ``planes`` (without evidence, alone and together), ``applied`` (set to
        zero), the held-out error and relative data residual with every plane and
        without those, ``joint_t`` and ``reason``.
    """
    fov = x[(slice(None), *op.crop)]
    energy = fov.reshape(op.n_z, -1).sum(axis=1, dtype=np.float64)
    total = float(energy.sum())

    def num(v):
        return None if math.isnan(v) else v

    planes = [{"plane": k, "depth_mm": None if op.depths is None else float(op.depths[k]),
               "energy": float(energy[k]),
               "energy_share": float(energy[k] / total) if total > 0 else 0.0,
               "holdout_t": num(tests["t"][k]),
               "holdout_coefficient": tests["coefficient"][k],
               "removal_worsens_holdout_by": tests["removal_worsens_by"][k],
               "removal_worsens_holdout_z": num(tests["removal_z"][k]),
               "shows_signal": tests["holds_signal"][k]} for k in range(op.n_z)]
    candidates = [k for k in range(op.n_z) if not tests["holds_signal"][k]]
    empty, joint = joint_drop(tests, candidates) if candidates else ([], {"t": None})
    r = tests["residual"]
    without = r + tests["predictions"][empty].sum(axis=0) if empty else r
    b_norm = max(float(np.linalg.norm(b)), 1e-30)
    drop = {"planes": empty, "applied": False, "joint_t": joint["t"],
            "holdout_error_all_planes": float(np.sum(np.square(r[held], dtype=np.float64))),
            "holdout_error_without": float(np.sum(np.square(without[held],
                                                            dtype=np.float64))),
            "relative_residual_all_planes": float(np.linalg.norm(r)) / b_norm,
            "relative_residual_without": float(np.linalg.norm(without)) / b_norm}
    why = (f"a plane shows signal when its prediction of the held-out pixels, beside the "
           f"other planes', is {SIGNAL_SNR:g} standard errors above zero, or removing it "
           f"worsens their prediction by {SIGNAL_SNR:g} standard errors")
    effect = (f"held-out error {drop['holdout_error_all_planes']:.4g} -> "
              f"{drop['holdout_error_without']:.4g}, relative residual "
              f"{drop['relative_residual_all_planes']:.4f} -> "
              f"{drop['relative_residual_without']:.4f}")
    together = sorted(set(candidates) - set(empty))
    if not candidates:
        drop["reason"] = f"all {op.n_z} show signal ({why}); all kept"
    elif not empty:
        drop["reason"] = (f"planes {candidates} show no signal one by one ({why}), but "
                          "together they do: all kept")
    elif empty_planes == "keep":
        drop["reason"] = (f"planes {empty} show no signal ({why}; a dim plane's may drown "
                          "in the model's error on the bright ones); all kept (without "
                          f"them: {effect})")
    else:
        drop["applied"] = True
        drop["reason"] = (f"planes {empty} show no signal ({why}), together neither, and "
                          f"were set to zero as asked, nothing re-solved: {effect}")
    if together:
        drop["reason"] += f"; planes {together} kept: together they show signal"
    kept = [k for k in range(op.n_z) if not (drop["applied"] and k in empty)]
    return planes, kept, drop

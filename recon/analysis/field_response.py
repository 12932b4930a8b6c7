"""Fit a scene calibration's field response (:mod:`recon.field_response`) on its pairs.

Each calibration pair ``k`` has a held-out reconstruction ``r_k`` (the recipe's solve
with the PSF estimated without it) and its scene ``s_k``. After each channel's
least-squares gain (what the recipe's errors are scored after), the field response is
the least-squares gain of each point of the field over the pairs and channels,

    g(x) = [G * sum_k,c r_kc s_kc](x) / [G * sum_k,c r_kc^2](x),

with ``G`` a Gaussian of 0.8 :data:`recon.field_response.STEP_PX` (full-size pixels),
sampled on the grid. It is kept only if it pays on pairs it was not fitted on: each
pair's error with the response fitted on the other pairs against its error without
(:func:`held_out_field_gain_db`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import ReconInputError
from ..field_response import STEP_PX, apply_field_response, resample_evenly
from ..metrics import fit_gain

__all__ = ["KEEP_DB", "MAX_GAIN", "SIGMA_STEPS", "fit_field_response", "held_out_field_gain_db"]

#: The smoothing of the per-pixel gain, in grid steps (a Gaussian's sigma).
SIGMA_STEPS = 0.8
#: The least mean held-out gain (dB) for which a recipe keeps its field response: a
#: response is a strong change (near 0 where the calibration scenes were dark), kept
#: only where it clearly pays. On the five real pairs every fold's response bought
#: +0.18 to +0.44 dB; the simulated bench's bought +0.0003 dB and would black out the
#: half of the field its scenes left dark.
KEEP_DB = 0.05
#: The largest gain of the response: a ratio of two near-empty sums where the
#: reconstructions hold almost no light and the scenes some (it reached 268 in a corner
#: that a sensor response left dark, and cost that fold's held-out pair 4.4 dB); no
#: shading of the optics is that strong.
MAX_GAIN = 4.0


def _sums(images, scenes, binned_by):
    """Per-pixel sums over pairs and channels of ``r s`` and ``r^2``, the images each
    gain-fitted per channel to their scenes, smoothed."""
    from scipy.ndimage import gaussian_filter

    rs = rr = 0.0
    for r, s in zip(images, scenes, strict=True):
        r = np.atleast_3d(np.asarray(r, np.float64))
        s = np.atleast_3d(np.asarray(s, np.float64))
        if r.shape != s.shape:
            raise ReconInputError(f"reconstruction of shape {r.shape} for a scene of shape "
                                  f"{s.shape}: give each pair's image on its scene's grid")
        r = r * np.array([fit_gain(r[..., c], s[..., c]) for c in range(r.shape[-1])])
        rs = rs + (r * s).sum(-1)
        rr = rr + (r * r).sum(-1)
    sigma = SIGMA_STEPS * STEP_PX / binned_by
    return gaussian_filter(rs, sigma), gaussian_filter(rr, sigma)


def fit_field_response(images: Sequence[np.ndarray], scenes: Sequence[np.ndarray],
                       binned_by: int = 1) -> np.ndarray:
    """The field response of reconstructions ``images`` against ``scenes`` (module
    docstring).

    Parameters
    ----------
    images, scenes : sequence of ndarray, (rows, cols) or (rows, cols, channels)
        Each pair's held-out reconstruction and scene, the same shape, at least one pair.
    binned_by : int
        The pairs' binning against the PSF the response is for (the grid has one node
        per :data:`recon.field_response.STEP_PX` of its pixels).

    Returns
    -------
    ndarray, float64, (n_rows, n_cols)
        The gains at the grid's nodes (0 where no pair had light in its reconstruction).

    Raises
    ------
    ReconInputError
        No pair, or an image of another shape than its scene.
    """
    if not len(images):
        raise ReconInputError("no calibration pair to fit a field response on; give at "
                              "least one")
    rs, rr = _sums(images, scenes, binned_by)
    g = np.divide(rs, rr, out=np.zeros_like(rs), where=rr > 1e-12 * rr.max())
    g = np.minimum(g, MAX_GAIN)
    nodes = [max(1, round(side * binned_by / STEP_PX)) for side in g.shape]
    return np.maximum(resample_evenly(g, nodes), 0.0)


def held_out_field_gain_db(images: Sequence[np.ndarray], scenes: Sequence[np.ndarray],
                           scorers: Sequence, binned_by: int = 1) -> np.ndarray:
    """What a field response buys each pair when fitted on the others.

    Parameters
    ----------
    images, scenes
        As for :func:`fit_field_response`, at least two pairs.
    scorers : sequence of callable
        ``scorers[k](estimate) -> error``: pair ``k``'s error measure
        (:func:`recon.analysis.early_stop.gain_fitted_error` against scene ``k``).
    binned_by : int
        As for :func:`fit_field_response`.

    Returns
    -------
    ndarray, float64, (n_pairs,)
        ``20 log10(error without / error with)`` per pair (dB; > 0: it helped).

    Raises
    ------
    ReconInputError
        Fewer than two pairs.
    """
    n = len(images)
    if n < 2:
        raise ReconInputError(f"{n} calibration pair(s): a held-out field response needs "
                              "at least two")
    out = np.zeros(n)
    for k in range(n):
        others = [j for j in range(n) if j != k]
        grid = fit_field_response([images[j] for j in others], [scenes[j] for j in others],
                                  binned_by)
        without = scorers[k](images[k])
        with_ = scorers[k](apply_field_response(images[k], grid))
        out[k] = 20 * np.log10(max(without, 1e-12) / max(with_, 1e-12))
    return out

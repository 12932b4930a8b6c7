"""The reconstruction recipe of a scene-calibrated camera, fitted on its calibration pairs.

With a PSF calibrated from a few known scenes (:mod:`recon.analysis.psf_from_scenes`),
the model's error, not the sensor's noise, limits a reconstruction: the PSF carries
the estimation error of a few pairs and the camera departs from a shift-invariant
convolution. A non-negative FISTA without any prior (Eq. 2.5 with no TV term, Kuo 2020
Sec. 2.3) first fits the scene's structure and then, iteration after iteration, the
model error, amplified by the ill-conditioned inverse: stopping it early is the
regularisation (semi-convergence; Landweber's iteration count as the regularisation
parameter, Engl, Hanke & Neubauer 1996, Ch. 6). It has no block tiling, unlike
anisotropic TV at the weight that the held-out pixels choose on such data. Two more
numbers complete the recipe (:class:`recon.early_stop.EarlyStop`): a soft threshold
of the PSF (:func:`recon.early_stop.clean_psf`: the estimate's noise floor) and the
weight of an isotropic TV denoising of the result (:func:`recon.early_stop.denoise_tv`).

All three are fitted on calibration data only: each calibration pair ``k`` is
reconstructed with the PSF estimated *without* it
(:func:`recon.analysis.psf_from_scenes.leave_one_out`'s PSFs), thresholded at each
candidate, by one FISTA solve observed at every candidate count (the iterate at count
``n`` is what a solve of ``n`` iterations returns), each denoised at every candidate
weight, and scored against its known scene after a per-channel least-squares gain
(the scene's scale is not the reconstruction's). The triple with the least mean error
in dB over the pairs (the geometric mean of the relative errors) wins
(:func:`fit_early_stop`). The recipe ships with the PSF it was made for (SHA-256 of
its values) and :func:`reconstruct_early_stopped` refuses another PSF.

:func:`fit_held_out` makes the fit a pair may be scored with (a benchmark's
leave-one-out entry); docs/real-data.md has the recipes and scores on the five real
DiffuserCam pairs.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..early_stop import EarlyStop, clean_psf, denoise_tv, psf_identity, psf_signature
from ..errors import ReconInputError
from .psf_from_scenes import check_pairs

__all__ = ["CANDIDATES", "REFERENCE_ITERATIONS", "THRESHOLDS", "WEIGHTS", "fit_early_stop",
           "fit_held_out", "gain_fitted_error", "reconstruct_early_stopped",
           "reference_db", "solve_checkpoints"]

#: Candidate iteration counts of :func:`fit_early_stop` (checkpoints of one solve).
CANDIDATES = tuple(range(10, 201, 10))
#: Candidate PSF thresholds (fractions of the maximum, :func:`recon.early_stop.clean_psf`).
THRESHOLDS = (0.0, 0.05, 0.1)
#: Candidate weights of the final isotropic TV denoising (:func:`recon.early_stop.denoise_tv`).
WEIGHTS = (0.0, 0.05, 0.1, 0.2)
#: Iterations of the fixed reference solve that scores a PSF (:func:`reference_db`).
REFERENCE_ITERATIONS = 50


def gain_fitted_error(estimate: np.ndarray, scene: np.ndarray) -> float:
    """Relative error of ``estimate`` against ``scene`` after a per-channel
    least-squares gain, averaged over channels.

    Per channel ``min_g ||g e - s|| / ||s||``, the gain of
    :func:`recon.metrics.fit_gain` (``<e, s> / <e, e>``, 0 for an all-zero ``e``), the
    sums in float64.

    Parameters
    ----------
    estimate, scene : ndarray, (rows, cols) or (rows, cols, channels), same shape

    Returns
    -------
    float
        In [0, 1]; 1 for an all-zero estimate.

    Raises
    ------
    ReconInputError
        ``estimate`` and ``scene`` of different shapes.
    """
    return _scorer(scene)(estimate)


def _scorer(scene):
    """:func:`gain_fitted_error` against ``scene`` as a function of the estimate, the
    scene's channel planes and norms made once (the fit scores each pair's scene
    ``n_thresholds x n_candidates x n_weights`` times)."""
    # channels first and contiguous, and the sums by NumPy's own loops: BLAS (fit_gain's
    # vdot, norm) spun its threads on these 130 000-pixel planes under load, and the
    # scoring cost as much CPU as the solves that made the estimates
    s = np.ascontiguousarray(np.moveaxis(np.atleast_3d(np.asarray(scene, np.float64)), -1, 0))
    ss = np.einsum("cij,cij->c", s, s)

    def error(estimate) -> float:
        e = np.atleast_3d(np.asarray(estimate, np.float64))  # (rows, cols, channels)
        e = np.ascontiguousarray(np.moveaxis(e, -1, 0))
        if e.shape != s.shape:
            raise ReconInputError(f"estimate shape {np.shape(estimate)} differs from the "
                                  f"scene's {np.shape(scene)}")
        ee, es = np.einsum("cij,cij->c", e, e), np.einsum("cij,cij->c", e, s)
        gain = np.divide(es, ee, out=np.zeros_like(es), where=ee > 0)  # fit_gain's
        r = gain[:, None, None] * e - s
        out = np.where(ss > 0, np.sqrt(np.einsum("cij,cij->c", r, r) / np.where(ss > 0, ss, 1)),
                       1.0)
        return float(np.mean(out))
    return error


def _solve(psf, raw, iterations: int, observe=None, **options):
    """:func:`recon.planar.reconstruct_image` with the early-stop solve's options (the
    image path of :func:`recon.reconstruct`; the front door itself would close an
    import cycle: it reaches the spatial models, which use this package)."""
    from ..options import ReconOptions
    from ..planar import reconstruct_image

    unknown = sorted(set(options) - {s.dest for s in ReconOptions.specs()})
    if unknown:
        raise ReconInputError(f"no reconstruction option {', '.join(unknown)}; give "
                              "options of recon.reconstruct such as dark or bin_factor")
    chosen = ReconOptions.from_defaults(method="fista", iterations=iterations, tv=0.0, l1=0.0,
                                        **options)
    extra = {} if observe is None else {"observe": observe}
    return reconstruct_image(psf, raw, chosen, auto_stop=False, **extra)


def solve_checkpoints(psf, raw, counts: Sequence[int]) -> dict[int, np.ndarray]:
    """One prior-free non-negative FISTA solve of ``max(counts)`` iterations, observed
    at each of ``counts``: what a solve of that many iterations returns.

    Parameters
    ----------
    psf, raw : ndarray, (rows, cols) or (rows, cols, channels), float
        Dark-subtracted (``dark="none"``), as for :func:`recon.reconstruct`.
    counts : sequence of int
        Iteration counts, each >= 1.

    Returns
    -------
    dict of int to ndarray
        Per count, the sensor-grid estimate, float32, ``raw``'s shape, in the solver's
        scale (the reconstruction's image divided by ``info.raw_scale``).

    Raises
    ------
    ReconInputError
        What :func:`recon.reconstruct` refuses.
    """
    kept: dict[int, list] = {n: [] for n in counts}

    def observe(k, x):  # the channels are solved one after the other
        if k in kept:
            kept[k].append(np.array(x, np.float32))

    rec = _solve(psf, raw, max(counts), observe=observe, dark="none")
    crop = rec.operator.crop
    return {n: (xs[0][crop] if len(xs) == 1 else np.stack([x[crop] for x in xs], axis=-1))
            for n, xs in kept.items()}


def fit_early_stop(scenes, measurements, held_out_psfs: Sequence, psf, *,
                   candidates: Sequence[int] = CANDIDATES,
                   thresholds: Sequence[float] = THRESHOLDS,
                   weights: Sequence[float] = WEIGHTS, names: Sequence[str] = (),
                   on_candidate=None, on_solve=None) -> EarlyStop:
    """Fit the recipe (PSF threshold, iteration count, denoising weight) on
    calibration pairs (module docstring).

    Parameters
    ----------
    scenes, measurements
        The calibration pairs, as for
        :func:`recon.analysis.psf_from_scenes.estimate_psf_from_scenes` (measurements
        dark-subtracted), at least two.
    held_out_psfs : sequence of ndarray
        Pair ``k``'s PSF estimated without it (``leave_one_out(...).psfs``), each of
        the measurements' shape.
    psf : ndarray
        The PSF estimated from every pair: the one the recipe ships with.
    candidates : sequence of int
        Iteration counts to try (each >= 1; default :data:`CANDIDATES`); one solve of
        the largest per pair and threshold, observed at each.
    thresholds : sequence of float
        PSF thresholds to try (each in [0, 1); default :data:`THRESHOLDS`).
    weights : sequence of float
        Denoising weights to try (each >= 0, 0 for none; default :data:`WEIGHTS`).
    names : sequence of str
        The pairs' names, for the record.
    on_candidate : callable, optional
        ``on_candidate(threshold, errors)`` after each threshold (progress), with
        ``errors`` (n_candidates, n_weights, n_pairs).
    on_solve : callable, optional
        ``on_solve(done, total)`` after each observed solve (one per threshold and
        pair: ``total`` of them), for progress lines.

    Returns
    -------
    EarlyStop

    Raises
    ------
    ReconInputError
        Fewer than two pairs, one held-out PSF per pair missing, a PSF of another
        shape, a candidate count < 1, a threshold outside [0, 1) or a negative weight.
    """
    xs, bs = check_pairs(scenes, measurements)
    if len(xs) < 2 or len(held_out_psfs) != len(xs):
        raise ReconInputError(
            f"{len(xs)} calibration pairs and {len(held_out_psfs)} held-out PSFs: give at "
            "least two pairs and each one's PSF estimated without it (leave_one_out)")
    cands = sorted({int(c) for c in candidates})
    if not cands or cands[0] < 1:
        raise ReconInputError(f"candidate iteration counts {list(candidates)}: give counts >= 1")
    ts = sorted({float(t) for t in thresholds})
    ws = sorted({float(w) for w in weights})
    if not ts or not ws or not (0 <= ts[0] and ts[-1] < 1) or ws[0] < 0:
        raise ReconInputError(f"thresholds {list(thresholds)} and weights {list(weights)}: "
                              "give thresholds in [0, 1) and weights >= 0")
    for h in (*held_out_psfs, psf):
        if np.shape(h)[:2] != xs[0].shape[:2]:
            raise ReconInputError(f"PSF of shape {np.shape(h)} for pairs of shape "
                                  f"{xs[0].shape}: give PSFs of the measurements' shape")
    errors = np.zeros((len(ts), len(cands), len(ws), len(xs)))
    scorers = [_scorer(x) for x in xs]
    for i, t in enumerate(ts):
        for k, b in enumerate(bs):
            images = solve_checkpoints(clean_psf(held_out_psfs[k], t), b, cands)
            for j, n in enumerate(cands):
                for m, w in enumerate(ws):  # weight 0: denoise_tv's copy, not made
                    errors[i, j, m, k] = scorers[k](denoise_tv(images[n], w) if w > 0
                                                    else images[n])
            if on_solve is not None:
                on_solve(i * len(xs) + k + 1, len(ts) * len(xs))
        if on_candidate is not None:
            on_candidate(t, errors[i])
    score = np.log10(np.maximum(errors, 1e-12)).mean(axis=-1)  # mean error in dB / 20
    i, j, m = np.unravel_index(int(np.argmin(score)), score.shape)
    return EarlyStop(cands[j], tuple(cands), errors, psf_identity(psf), tuple(names),
                     ts[i], ws[m], tuple(ts), tuple(ws), psf_signature(psf))


def reference_db(scenes, measurements, held_out_psfs: Sequence, fit: EarlyStop | None = None
                 ) -> np.ndarray:
    """What each held-out PSF buys: a fixed reference reconstruction's error, in dB.

    Pair ``k`` is reconstructed with the PSF estimated without it by the prior-free
    non-negative FISTA of :data:`REFERENCE_ITERATIONS` iterations (the PSF as
    estimated: no threshold, no denoising) and scored against its scene:
    ``-20 log10`` of :func:`gain_fitted_error`. Higher is better; unlike the
    measurement residual it says how well the PSF reconstructs scenes (a calibration's
    quality figure, docs/real-data.md). Read from ``fit``'s errors when its grid holds
    that setting (threshold 0, the count, weight 0), else solved.

    Parameters
    ----------
    scenes, measurements, held_out_psfs
        As for :func:`fit_early_stop`.
    fit : EarlyStop, optional
        A fit on the same pairs and held-out PSFs.

    Returns
    -------
    ndarray, float64, (n_pairs,)

    Raises
    ------
    ReconInputError
        Pairs refused by :func:`recon.analysis.psf_from_scenes.check_pairs`, or not one
        PSF per pair.
    """
    xs, bs = check_pairs(scenes, measurements)
    if len(held_out_psfs) != len(xs):
        raise ReconInputError(f"{len(xs)} pairs and {len(held_out_psfs)} held-out PSFs: "
                              "give each pair's PSF estimated without it")
    n = REFERENCE_ITERATIONS
    if (fit is not None and fit.errors is not None and 0.0 in fit.thresholds
            and n in fit.candidates and 0.0 in fit.weights
            and np.shape(fit.errors)[-1] == len(xs)):
        errors = np.asarray(fit.errors)[list(fit.thresholds).index(0.0),
                                        list(fit.candidates).index(n),
                                        list(fit.weights).index(0.0)]
    else:
        errors = np.array([gain_fitted_error(solve_checkpoints(h, b, [n])[n], x)
                           for h, x, b in zip(held_out_psfs, xs, bs, strict=True)])
    return -20.0 * np.log10(np.maximum(errors, 1e-12))


def fit_held_out(scenes, measurements, k: int, *, psf=None,
                 candidates: Sequence[int] = CANDIDATES,
                 thresholds: Sequence[float] = THRESHOLDS,
                 weights: Sequence[float] = WEIGHTS, **psf_options) -> EarlyStop:
    """The early-stop fit that pair ``k`` may be scored with: fitted on the other pairs
    only (a benchmark's leave-one-out entry).

    The PSF is estimated from the other pairs (or ``psf``, that estimate, given);
    each of those pairs is reconstructed with the PSF estimated from the rest of them
    (:func:`recon.analysis.psf_from_scenes.leave_one_out` on the other pairs), so pair
    ``k`` touches neither the PSF nor the count.

    Parameters
    ----------
    scenes, measurements
        Every pair, as for :func:`fit_early_stop` (at least three).
    k : int
        The held-out pair's index.
    psf : ndarray, optional
        The PSF estimated from every pair but ``k`` (computed when not given).
    candidates, thresholds, weights
        As for :func:`fit_early_stop`.
    **psf_options
        Of :func:`recon.analysis.psf_from_scenes.estimate_psf_from_scenes`.

    Returns
    -------
    EarlyStop
        Tied to that PSF; reconstruct pair ``k`` with :func:`reconstruct_early_stopped`.

    Raises
    ------
    ReconInputError
        Fewer than three pairs, ``k`` out of range, or what :func:`fit_early_stop`
        refuses.
    """
    from .psf_from_scenes import estimate_psf_from_scenes, leave_one_out

    scenes, measurements = list(scenes), list(measurements)
    if len(scenes) < 3 or not 0 <= int(k) < len(scenes):
        raise ReconInputError(f"pair {k} of {len(scenes)}: give at least three pairs and "
                              "the index of one of them")
    xs = [x for i, x in enumerate(scenes) if i != k]
    bs = [b for i, b in enumerate(measurements) if i != k]
    if psf is None:
        psf = estimate_psf_from_scenes(xs, bs, **psf_options).psf
    return fit_early_stop(xs, bs, leave_one_out(xs, bs, **psf_options).psfs, psf,
                          candidates=candidates, thresholds=thresholds, weights=weights)


def reconstruct_early_stopped(psf, raw, fit: EarlyStop, **options):
    """Reconstruct with a fitted recipe, after checking that ``psf`` is the recipe's
    PSF: the PSF thresholded, non-negative FISTA without a prior for
    ``fit.iterations`` iterations exactly, the image denoised
    (:meth:`recon.early_stop.EarlyStop.finish`).

    Parameters
    ----------
    psf, raw
        As for :func:`recon.reconstruct` (one PSF).
    fit : EarlyStop
    **options
        Further options of :func:`recon.reconstruct` (``dark``: ``"auto"``, ``"none"``
        or a level; ``bin_factor``, ``device``, ...), not the method, iterations or
        weights.

    Returns
    -------
    recon.result.Reconstruction
        ``info.extra["calibration"]`` holds the recipe.

    Raises
    ------
    ReconInputError
        ``psf`` is not the fit's PSF, an option that the fit fixes or an unknown one,
        or what :func:`recon.reconstruct` refuses.
    """
    fixed = sorted({"method", "iterations", "tv", "l1", "auto_stop"} & set(options))
    if fixed:
        raise ReconInputError(f"{', '.join(fixed)}: fixed by the early-stop calibration; "
                              "leave them out")
    return fit.finish(_solve(fit.clean_psf(psf), raw, fit.iterations, **options))

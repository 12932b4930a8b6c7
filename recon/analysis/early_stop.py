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
(:func:`fit_early_stop`).

A held-out PSF comes from one pair fewer than the PSF the recipe ships with, so it is
noisier, and its reconstructions peak earlier: on the five real pairs the count that
scored best on each held-out scene was above the fitted one in four folds of five.
Each pair reconstructed with the shipped PSF itself (which has seen it) errs the other
way. So :func:`fit_recipe` also solves each pair with the shipped PSF (``in_sample``)
and moves the held-out errors at each count halfway (:data:`IN_SAMPLE_SHARE`) towards
those in-sample ones: the shipped PSF's error on a new scene lies between the two. The
move at each count is measured on the green channel alone and undenoised (the gap in
dB between the two solves of that channel) and applied at every weight, so an
in-sample solve costs about a third of a held-out one (on the five real pairs the green
channel's gap chose the same recipes as all three channels', and all but one as
scoring every weight). In the strictly nested leave-one-out on the five real pairs
this gained 0.12 dB (docs/real-data.md).

The pairs' held-out reconstructions with that triple then
give the recipe's field response (:mod:`recon.analysis.field_response`: a smooth gain
over the field, for the camera's falloff and the light the model spreads where the
scenes had none), kept only if it lowered the error of pairs it was not fitted on by
at least :data:`recon.analysis.field_response.KEEP_DB`.

:func:`fit_recipe` runs the whole fit: the held-out PSFs and the recipe, on the pairs
binned 2 x 2 (:data:`FIT_BIN`) where each side keeps at least :data:`FIT_MIN_PX`
pixels. Binning cuts the fit's cost about four-fold (FFTs and denoisings of a quarter
of the pixels) and does not move the recipe: on the five shared real pairs (270 x 480
RGB) the fit at bin 2 chose what the full-size fit chose (90 iterations, threshold 0,
weight 0.05; docs/real-data.md). The count is a property of the solve's spectrum,
which binning keeps below the binned grid's Nyquist frequency. The recipe is applied
at the PSF's own size. The recipe ships with the PSF it was made for (SHA-256 of
its values) and :func:`reconstruct_early_stopped` refuses another PSF.

:func:`fit_held_out` makes the fit a pair may be scored with (a benchmark's
leave-one-out entry); docs/real-data.md has the recipes and scores on the five real
DiffuserCam pairs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..early_stop import EarlyStop, clean_psf, denoise_tv, psf_identity, psf_signature
from ..errors import ReconInputError
from ..fft import map_jobs
from ..validate import as_int
from .field_response import KEEP_DB, fit_field_response, held_out_field_gain_db
from .psf_from_scenes import LeaveOneOut, PsfEstimate, check_pairs

__all__ = ["CANDIDATES", "FIT_BIN", "FIT_MIN_PX", "IN_SAMPLE_SHARE", "REFERENCE_ITERATIONS",
           "THRESHOLDS", "WEIGHTS", "RecipeFit", "fit_bin_factor", "fit_early_stop", "fit_held_out",
           "fit_recipe", "gain_fitted_error", "reconstruct_early_stopped", "reference_db",
           "solve_checkpoints"]

#: Candidate iteration counts of :func:`fit_early_stop` (checkpoints of one solve).
CANDIDATES = tuple(range(10, 201, 10))
#: Candidate PSF thresholds (fractions of the maximum, :func:`recon.early_stop.clean_psf`):
#: none by default. With the converged, channel-tied PSF estimate, 0 won every full-size
#: fit on the shared real pairs (0.1 lost on every pair, by 1.2-4.2 dB), and binning
#: changes what a threshold removes (it lowers the PSF's peak against its floor): at
#: bin 2 one fold chose 0.05 and lost 0.70 dB on its held-out pair (docs/real-data.md).
THRESHOLDS = (0.0,)
#: Candidate weights of the final isotropic TV denoising (:func:`recon.early_stop.denoise_tv`).
WEIGHTS = (0.0, 0.05, 0.1, 0.2)
#: Iterations of the fixed reference solve that scores a PSF (:func:`reference_db`).
REFERENCE_ITERATIONS = 50
#: The binning :func:`fit_recipe` fits at (module docstring).
FIT_BIN = 2
#: The fewest pixels a side keeps once binned; smaller pairs are fitted unbinned.
FIT_MIN_PX = 96
#: How far :func:`fit_early_stop` with ``in_sample`` moves the held-out errors (in dB)
#: towards the in-sample ones (each pair reconstructed with the PSF from every pair):
#: the midpoint, not tuned (module docstring).
IN_SAMPLE_SHARE = 0.5


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
                   on_candidate=None, on_solve=None, binned_by: int = 1,
                   field: bool = True, in_sample: bool = False) -> EarlyStop:
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
        The PSF estimated from every pair: the one the recipe ships with, at its own
        size (``bin_factor`` times the pairs' shape, remainders cropped by binning).
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
        pair, twice that with ``in_sample``: ``total`` of them), for progress lines.
        The solves run as
        :func:`recon.fft.map_jobs` (each on one FFT thread, as many at once as the
        caller's FFT workers).
    binned_by : int
        The binning of the pairs and held-out PSFs against ``psf`` (>= 1; recorded as
        the recipe's ``fit_bin_factor``).
    field : bool
        Fit a field response (:mod:`recon.analysis.field_response`) on the pairs'
        held-out reconstructions with the recipe chosen (their solves' checkpoints,
        kept until the choice: one image per candidate count and pair), and keep it if
        its mean held-out gain is at least
        :data:`recon.analysis.field_response.KEEP_DB` (recorded either way).
    in_sample : bool
        Also reconstruct each pair with ``psf`` itself (binned by ``binned_by``), which
        was estimated from every pair, and choose by the held-out errors moved, at each
        count, :data:`IN_SAMPLE_SHARE` of the way (in dB) towards these in-sample ones
        (module docstring). The move is measured on the lead channel
        (:data:`recon.planar.LEAD_CHANNEL`, green, of RGB pairs; every channel of
        others) without denoising, against that channel of the held-out solve; both
        are recorded as the recipe's ``lead_errors``. One more solve of that channel
        per threshold and pair. False (default): the held-out errors alone, for
        held-out PSFs as good as ``psf`` (pairs it has not seen).

    Returns
    -------
    EarlyStop

    Raises
    ------
    ReconInputError
        Fewer than two pairs, one held-out PSF per pair missing, a PSF of another
        shape, a candidate count < 1, a threshold outside [0, 1), a negative weight or
        a bin factor < 1.
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
    binning = as_int(binned_by, "binned_by", 1)
    for h, factor in [*((h, 1) for h in held_out_psfs), (psf, binning)]:
        if tuple(n // factor for n in np.shape(h)[:2]) != xs[0].shape[:2]:
            raise ReconInputError(f"PSF of shape {np.shape(h)} for pairs of shape "
                                  f"{xs[0].shape} binned {factor} x {factor}: give PSFs "
                                  "of the measurements' shape")
    errors = np.zeros((len(ts), len(cands), len(ws), len(xs)))
    # in-sample: the lead channel's undenoised errors, [0] held out, [1] with psf itself
    lead_errors = np.zeros((2, len(ts), len(cands), len(xs))) if in_sample else None
    lead = _lead_channel(xs[0])
    whole = None
    if in_sample:
        from ..preprocess.binning import box_bin

        whole = np.asarray(box_bin(np.asarray(psf), binning) if binning > 1 else psf,
                           np.float32)
        whole = whole[..., lead] if whole.ndim == 3 else whole
    scorers = [_scorer(x) for x in xs]
    lead_scorers = [_scorer(x[..., lead]) for x in xs] if in_sample else None

    def observed(job):  # one solve, scored at every count (and weight: held out)
        i, k, seen = job
        if seen:  # the lead channel with the PSF from every pair, undenoised
            images = solve_checkpoints(clean_psf(whole, ts[i]), bs[k][..., lead], cands)
            return [lead_scorers[k](images[n]) for n in cands], None, None
        images = solve_checkpoints(clean_psf(held_out_psfs[k], ts[i]), bs[k], cands)
        # weight 0: denoise_tv's copy, not made; the checkpoints kept for the field
        return ([[scorers[k](denoise_tv(images[n], w) if w > 0 else images[n])
                  for w in ws] for n in cands], images if field else None,
                [lead_scorers[k](images[n][..., lead]) for n in cands] if in_sample
                else None)

    jobs = [(i, k, seen) for seen in ((False, True) if in_sample else (False,))
            for i in range(len(ts)) for k in range(len(xs))]
    left = {i: len(jobs) // len(ts) for i in range(len(ts))}  # each threshold's to come
    checkpoints = {}  # (threshold, pair): the held-out solve's images at every count

    def done(index, result):  # in this thread, as each solve ends
        i, k, seen = jobs[index]
        if seen:
            lead_errors[1, i, :, k] = result[0]
        else:
            errors[i, :, :, k], checkpoints[i, k], plain = result
            if plain is not None:
                lead_errors[0, i, :, k] = plain
        left[i] -= 1
        if on_solve is not None:
            on_solve(len(jobs) - sum(left.values()), len(jobs))
        if left[i] == 0 and on_candidate is not None:
            on_candidate(ts[i], errors[i])

    map_jobs(observed, jobs, on_done=done)
    score = _mean_db(errors)
    if in_sample:  # each count's held-out errors moved towards the in-sample ones
        score = score + IN_SAMPLE_SHARE * (_mean_db(lead_errors[1])
                                           - _mean_db(lead_errors[0]))[:, :, None]
    i, j, m = np.unravel_index(int(np.argmin(score)), score.shape)
    grid = gain_db = None
    if field:  # each pair's held-out reconstruction with the recipe chosen
        images = [checkpoints[i, k][cands[j]] for k in range(len(xs))]
        images = [denoise_tv(x, ws[m]) if ws[m] > 0 else x for x in images]
        checkpoints.clear()
        gain_db = float(np.mean(held_out_field_gain_db(images, xs, scorers, binning)))
        grid = fit_field_response(images, xs, binning) if gain_db >= KEEP_DB else None
    return EarlyStop(cands[j], tuple(cands), errors, psf_identity(psf), tuple(names),
                     ts[i], ws[m], tuple(ts), tuple(ws), psf_signature(psf),
                     fit_bin_factor=binning, field_response=grid, field_gain_db=gain_db,
                     lead_errors=lead_errors)


def _lead_channel(scene) -> int | slice:
    """The channel index :func:`fit_early_stop` measures the in-sample move on: green
    (:data:`recon.planar.LEAD_CHANNEL`) of an RGB scene (rows, cols, 3), every channel
    (a slice) otherwise."""
    from ..planar import LEAD_CHANNEL

    return LEAD_CHANNEL if np.ndim(scene) == 3 and np.shape(scene)[2] == 3 else slice(None)


def _mean_db(errors: np.ndarray) -> np.ndarray:
    """The mean over pairs (last axis) of the errors in dB, / 20: the fit's score."""
    return np.log10(np.maximum(errors, 1e-12)).mean(axis=-1)


def fit_bin_factor(shape) -> int:
    """The binning :func:`fit_recipe` fits pairs of ``shape`` (rows, cols[, channels])
    at: :data:`FIT_BIN` when each binned side keeps :data:`FIT_MIN_PX` pixels, else 1."""
    return FIT_BIN if min(shape[:2]) // FIT_BIN >= FIT_MIN_PX else 1


@dataclass(frozen=True)
class RecipeFit:
    """What :func:`fit_recipe` made, every figure at its binning.

    Attributes
    ----------
    fit : EarlyStop
        The recipe, for the PSF from every pair.
    held_out : recon.analysis.psf_from_scenes.LeaveOneOut
        Each pair's held-out residual and PSF, of the binned pairs.
    reference_db : ndarray, float64, (n_pairs,)
        :func:`reference_db` of the held-out PSFs on the binned pairs.
    bin_factor : int
        The binning (1: none).
    estimate : recon.analysis.psf_from_scenes.PsfEstimate or None
        The PSF from every pair, full size, when :func:`fit_recipe` estimated it.
    sensor_response : ndarray, float64, (n_rows, n_cols), or None
        The sensor response that PSF was estimated with
        (:func:`recon.analysis.sensor_response.fit_sensor_response`), or None.
    """

    fit: EarlyStop
    held_out: LeaveOneOut
    reference_db: np.ndarray
    bin_factor: int
    estimate: PsfEstimate | None = None
    sensor_response: np.ndarray | None = None


def fit_recipe(scenes, measurements, psf=None, *, bin_factor: int | None = None,
               candidates: Sequence[int] = CANDIDATES,
               thresholds: Sequence[float] = THRESHOLDS,
               weights: Sequence[float] = WEIGHTS, names: Sequence[str] = (),
               on_psf=None, on_estimate=None, on_solve=None, fit_sensor: bool = True,
               on_sensor=None, in_sample: bool = True, **psf_options) -> RecipeFit:
    """The recipe for ``psf`` fitted on its calibration pairs: each pair's PSF
    estimated without it (:func:`recon.analysis.psf_from_scenes.leave_one_out`), then
    :func:`fit_early_stop` and :func:`reference_db`, on the pairs binned by
    ``bin_factor`` (module docstring). The PSFs are estimated with the sensor's shading
    as a nuisance (:mod:`recon.analysis.sensor_response`; ``fit_sensor``): the PSF
    from every pair, when estimated here, with the response of every pair (fitted on
    the binned pairs), each held-out PSF with the response of its own pairs (the held-
    out pair unseen). The recipe's solves, like every reconstruction, take the
    measurements as captured (docs/real-data.md).

    The estimates (``psf``'s when not given, and the held-out ones) and then the
    recipe's solves run as :func:`recon.fft.map_jobs`: each on one FFT thread, as
    many at once as the caller's FFT workers.

    Parameters
    ----------
    scenes, measurements
        The calibration pairs, as for :func:`fit_early_stop` (at least two).
    psf : ndarray, optional
        The PSF estimated from every pair, at the pairs' size; default: estimated here
        (:func:`recon.analysis.psf_from_scenes.estimate_psf_from_scenes` with
        ``psf_options``, at full size) beside the held-out PSFs.
    bin_factor : int, optional
        Block size of the binning (>= 1); default :func:`fit_bin_factor` of the pairs.
    candidates, thresholds, weights, names, on_solve
        As for :func:`fit_early_stop`.
    on_psf : callable, optional
        ``on_psf(estimate)`` once the PSF from every pair is estimated here (progress).
    on_estimate : callable, optional
        ``on_estimate(k)`` after pair ``k``'s held-out PSF (progress; in the order the
        estimates end).
    fit_sensor : bool
        Estimate the PSFs with the sensor response (default); False: without (as before
        2026-11-29). A ``psf`` given should have been estimated the same way.
    on_sensor : callable, optional
        ``on_sensor(round, estimate)`` after each round of the sensor response's fit
        (progress).
    in_sample : bool
        Choose the recipe by the held-out errors moved towards the in-sample ones
        (default; module docstring, :func:`fit_early_stop`'s ``in_sample``); False: by
        the held-out errors alone (as before 2026-11-29).
    **psf_options
        Of :func:`recon.analysis.psf_from_scenes.estimate_psf_from_scenes`; a
        ``psf_shape`` is binned with the pairs.

    Returns
    -------
    RecipeFit

    Raises
    ------
    ReconInputError
        What :func:`fit_early_stop` or the estimate refuses, or a bin factor < 1 or
        larger than the pairs.
    """
    from ..preprocess.binning import box_bin
    from .psf_from_scenes import binned_psf_options, estimate_psf_from_scenes, held_out_estimate
    from .sensor_response import (
        estimate_with_sensor_response,
        fit_sensor_response,
        remove_sensor_response,
    )

    shape = check_pairs(scenes, measurements)[0][0].shape
    if len(scenes) < 2:
        raise ReconInputError("a recipe needs at least two pairs (each scored with the "
                              "PSF of the others); give more pairs")
    xs, bs = list(scenes), list(measurements)  # 2D stays 2D (check_pairs adds a channel)
    full_options = dict(psf_options)
    b = fit_bin_factor(shape) if bin_factor is None else as_int(bin_factor, "bin_factor", 1)
    if b > 1:
        if b > min(shape[:2]) // 2:
            raise ReconInputError(f"bin_factor {b} for pairs of shape {shape}: give "
                                  "a factor that leaves at least 2 pixels a side")
        xs, bs = [box_bin(np.asarray(x), b) for x in xs], [box_bin(np.asarray(m), b)
                                                            for m in bs]
        psf_options = binned_psf_options(psf_options, b)
    if psf is not None and tuple(n // b for n in np.shape(psf)[:2]) != np.shape(xs[0])[:2]:
        raise ReconInputError(f"PSF of shape {np.shape(psf)} for pairs of shape {shape} "
                              f"binned {b} x {b}: give the PSF estimated from the pairs")

    sensor = None
    if psf is None and fit_sensor:  # on the binned pairs: it is smooth
        sensor = fit_sensor_response(xs, bs, binned_by=b, on_round=on_sensor, **psf_options)

    def with_sensor(scenes_, measurements_, **options):
        return estimate_with_sensor_response(scenes_, measurements_, binned_by=b,
                                             **options)[0]

    def estimate(k):  # None: the PSF from every pair, full size (the largest job: first)
        if k is None:
            return estimate_psf_from_scenes(
                scenes, [remove_sensor_response(m, sensor) for m in measurements],
                **full_options)
        # as the PSF it stands for: with the response of its own pairs (pair k unseen)
        return held_out_estimate(xs, bs, k, estimate=with_sensor if fit_sensor else None,
                                 **psf_options)

    here = psf is None
    jobs = ([None] if here else []) + list(range(len(xs)))

    def done(index, result):  # in this thread, as each estimate ends (progress)
        if jobs[index] is None:
            if on_psf is not None:
                on_psf(result)
        elif on_estimate is not None:
            on_estimate(jobs[index])

    out = map_jobs(estimate, jobs, on_done=done)
    whole = out.pop(0) if here else None
    loo = LeaveOneOut(np.array([r for _, r in out]), [h for h, _ in out])
    psf = whole.psf if here else psf
    fit = fit_early_stop(xs, bs, loo.psfs, psf, candidates=candidates, thresholds=thresholds,
                         weights=weights, names=names, on_solve=on_solve, binned_by=b,
                         in_sample=in_sample)
    return RecipeFit(fit, loo, reference_db(xs, bs, loo.psfs, fit), b, whole, sensor)


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
                 weights: Sequence[float] = WEIGHTS, bin_factor: int | None = None,
                 fit_sensor: bool = True, in_sample: bool = True,
                 **psf_options) -> EarlyStop:
    """The early-stop fit that pair ``k`` may be scored with: fitted on the other pairs
    only (a benchmark's leave-one-out entry).

    The PSF is estimated from the other pairs as the calibration does (:func:`fit_recipe`,
    with the sensor response unless ``fit_sensor`` is False), or ``psf``, that
    estimate, given;
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
    candidates, thresholds, weights, bin_factor, fit_sensor, in_sample
        As for :func:`fit_recipe` (the calibration's own fit).
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
    scenes, measurements = list(scenes), list(measurements)
    if len(scenes) < 3 or not 0 <= int(k) < len(scenes):
        raise ReconInputError(f"pair {k} of {len(scenes)}: give at least three pairs and "
                              "the index of one of them")
    xs = [x for i, x in enumerate(scenes) if i != k]
    bs = [b for i, b in enumerate(measurements) if i != k]
    return fit_recipe(xs, bs, psf, bin_factor=bin_factor, candidates=candidates,
                      thresholds=thresholds, weights=weights, fit_sensor=fit_sensor,
                      in_sample=in_sample, **psf_options).fit


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

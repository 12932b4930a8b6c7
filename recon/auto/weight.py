"""Automatic regularisation weight: hold-out cross-validation between settled solves
along a warm-started continuation path; the chosen weight's solve is the result.

Criterion: hold-out cross-validation (Stone 1974; the pixel-wise form of the
generalised cross-validation of Golub, Heath & Wahba 1979) with the one-standard-
error rule (Breiman et al. 1984, Sec. 3.4.3). A random 10 % of the measured pixels,
in 32 x 32 blocks (:data:`~recon.auto.holdout.BLOCK`; the split is
:mod:`recon.auto.holdout`'s), are left out of the fits (folded into the sensor
weights, as the erasure mask of Eq. 3.10 is); for each weight, the fit to the other
90 % predicts the held-out pixels through the forward model, and the prediction
error is noise + model error + estimation error. Too large a weight leaves signal
unexplained; too small a weight fits the noise and the model's mismatch with
structure the held-out blocks do not share. The chosen weight is the largest whose
prediction error is within one standard error of the best (the minimum is flat,
its argmin noise), but at most :data:`MAX_ABOVE_MINIMUM` times the best's weight (the
one-standard-error step alone landed a factor of 3-7 above the minimum on the former
path, up to 2.4 dB below the best weight at low light); with the path's steps of
2.8x that is the held-out minimum itself. Unlike the discrepancy principle, it needs
neither the noise level nor the model error: on the virtual bench's spatially varying diffuser the
residual never settles at the noise level the camera predicts, and a discrepancy
rule ran to the smallest weight (7.7 dB on the demo scene against 18.5 dB at the
best fixed weight).

The path compares like with like (:mod:`recon.auto.path`). ADMM
(:func:`recon.solvers.admm_loop.run_admm`) runs on the fit pixels from :data:`START_WEIGHT`
down to :data:`END_WEIGHT` in steps of :data:`PATH_FACTOR` (:func:`weight_grid`), each
weight warm-started from the state the one before ended in (continuation; Hale, Yin &
Zhang 2008), and each runs until its held-out error has settled -- it could fall by at
most half a standard error more, a geometric bound on the remaining fall -- or no
longer falls, or its cap (:data:`STAGE_SHARE` of a fixed run's iterations) is reached;
an unsettled weight's bound is recorded and accounted for. The path stops when two
weights in a row predict the held-out pixels worse than the best by more than one
standard error *even after the fall their solves had left*, at the smallest weight,
or when the budget runs out: :data:`BUDGET` times a fixed run's iterations, and the
wall-clock ``seconds`` when given. The former path ran about 20 iterations per weight
and stopped at two rises of unsettled errors: on a dense, full-field photograph
(camera, bin 8, 3000 e-) it stopped at 1.4e-3, 13.7 dB against 22.8 dB at the best
fixed weight, because small weights need hundreds of iterations and their early
errors were transients. The chosen weight then runs on, with what the budget has left
(at most a fixed run's iterations; not when the path only chooses, ``path_only``, whose
caller solves afresh), from the state its own path solve ended in (a copy
kept for the best weight): where the held-out error is flat the image still improves,
so the iterate kept is the latest within half a standard error of the best
(:class:`recon.auto.path.Convergence`). The record (:class:`AutoWeight`) lists every
weight with its held-out error, iterations, whether it settled and its remaining
bound, and says why the path stopped.

Which result is kept is the model's choice (:data:`FINAL_ON_ALL_PIXELS`, measured
there). A convolution and a volume keep the chosen weight's iterate on the fit
pixels: cross-validated early stopping (Prechelt 1998) is what keeps a weak weight
from fitting noise into structure the measurements barely constrain (a photograph at
bin 8, 10000 e-: TV 1e-5 converges to 21.2 dB, peaking at 25.6 dB on the way), and
restarting on all pixels from the kept iterate lost 0.6-0.7 dB in ADMM's transient
after the restart (fresh duals; camera and shapes, full field, bin 8, 3000 e-; 1.8 dB
with an earlier version of the path). The 2D spatially varying model gains from a
final solve on all pixels from the chosen estimate (the virtual bench's demo: 0.6-1.2
dB). With a compact PSF the held-out blocks would hide object pixels (:func:`holdout_coverage`),
and the final solve runs on all pixels whatever the model (automatic stopping,
:class:`Stopping`).

The machinery takes any ADMM plan with the interface of
:class:`recon.solvers.admm.AdmmPlan` (``zeros``, ``warm``, ``run``, ``objective``): the
spatially varying models' and the volume's (:mod:`recon.auto.volume`, with its own
:class:`PathRule`: the 2D bound above was measured on 2D scenes and does not carry over
to 3D).
"""

from __future__ import annotations

import copy
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ReconInputError
from ..solvers.admm import AdmmPlan, check_penalties
from ..solvers.common import History, SolveResult
from .holdout import BLOCK, HOLDOUT, holdout_coverage, holdout_split
from .path import Convergence, run_candidate
from .xp_path import PathArrays, device_plan_of

__all__ = ["BUDGET", "PATH_RULES", "AutoWeight", "PathRule", "PathTuning", "Stopping", "admm_auto",
           "path_budget", "weight_grid"]

log = logging.getLogger(__name__)

#: First weight of the path per regulariser (scaled problem: unit-sum PSF,
#: measurement / max): TV far above the weights any scene of the benchmark wants
#: (1e-5 .. 3e-3); l1 where it already empties a bead scene.
START_WEIGHT = {"tv": 1e-2, "l1": 1.0}
#: Smallest weight on the path per regulariser. TV: below it ADMM's TV split is too
#: weak to condition the x-update and does worse than no TV at all (camera scene,
#: 300 e-: 10.6 dB at 1e-5 with balanced penalties against 20.3 dB without TV; at
#: 30000 e-, 17.2 dB at 1.2e-6 against 27.2 dB at 1e-5). l1: below 1e-3 it changes
#: nothing (bead scenes of the auto benchmark, 300-3000 e-: the same PSNR to 0.1 dB
#: from 1e-5 to 1e-3), and a path down to 1e-5 stepped by 5.2x at 200 iterations.
END_WEIGHT = {"tv": 1e-5, "l1": 1e-3}
#: Multiple of the held-out error's standard error within which the largest weight
#: is taken. Half a standard error was tried: at 300 photo-electrons it mends the
#: rule's worst cases (chelsea 1.8 dB below the oracle -> 0.45 below, astronaut 1.3
#: below -> 0.06 above), but at 3000 it chose 2.7e-5 for astronaut, 2.1 dB below (the
#: full rule: 7e-5, 0.0 dB). The bound :data:`MAX_ABOVE_MINIMUM` mends the low-light
#: cases instead.
SE_RULE = 1.0
#: The chosen weight is at most this multiple of the weight with the smallest
#: held-out error. Measured on the auto benchmark's 21 cases (200-iteration
#: fixed-weight PSNR at each path weight, the rules applied to the same held-out
#: paths): the plain one-standard-error rule was on average 0.30 dB below the best
#: path weight, at worst 2.4 (chelsea, 300 e-: 3.7e-3 against 5.2e-4); bounded to 2x
#: the minimum's weight, 0.18 and 0.9; the minimum itself (no rule) at worst 2.1
#: (astronaut, 3000 e-: 2.7e-5 against 7.2e-5); the geometric mean of the two at
#: worst 1.0.
MAX_ABOVE_MINIMUM = 2.0
#: Factor between consecutive weights of the path (:func:`weight_grid`).
PATH_FACTOR = 2 ** 1.5
#: The path takes at most this multiple of a fixed-weight run's iterations
#: (:func:`path_budget`); with the held-out scores every window, its wall time stays
#: within 4x that run's.
BUDGET = 3.5
#: Most iterations a candidate weight runs on the path, as a share of a fixed run's
#: (at least ``Convergence.min_iterations``); one still falling then hands its
#: state to the next weight, its remaining fall bounded and accounted for, and the
#: chosen weight is run on with what the budget has left when it had not settled.
STAGE_SHARE = 0.5
#: The final solve keeps to the fit pixels (watching the held-out ones) only when
#: every object pixel is still seen through them at least this much
#: (:func:`holdout_coverage`).
MIN_COVERAGE = 0.5
#: Relative rms error of the forward model's prediction, for the noise scale of
#: automatic stopping (:class:`Stopping`): the residual the real tutorial PSF at
#: bin 4 leaves on scenes rendered at bin 2 without noise is 0.5-0.7 % of ||b||.
MODEL_ERROR = 0.005
#: Which result the path keeps, per model: the chosen weight's iterate on the fit
#: pixels (the held-out blocks left out of its data term), or a final solve on all
#: pixels from the chosen estimate (fresh duals and penalties, automatic stopping, at
#: most a fixed run's iterations, taken from the budget). A model says which by its
#: ``final_on_all_pixels`` (absent: the fit pixels); a compact PSF always takes the
#: final solve (:data:`MIN_COVERAGE`). Measured (one run per case, seeds and scenes
#: as in the auto benchmark): on the 2D spatially varying model of the virtual
#: bench's demo, seeds 0-3, the final solve gives 21.80, 21.29, 21.43, 20.58 dB against
#: 20.65, 20.62, 20.19, 19.96 for the fit-pixel iterate, so that model takes it.
#: Checked on scenes it was not chosen on (the far-scene camera of
#: ``benchmarks.spatial_far``, full field, binned 2 x 2, 200 iterations; oracle:
#: the best of fixed TV 3e-5, 7.2e-5, 1.9e-4, 5.2e-4, 1.4e-3): shortfall to the oracle
#: with the final solve / with the fit-pixel iterate, dB: camera 0.26 / 1.66, beads 0.23
#: / 0.23, brick 0.13 / 0.34, text 0.05 / 0.08, camera at 300 e- 0.01 / 0.42, coffee at
#: 30000 e- -0.30 / 0.61, gravel 0.09 / 0.28, shapes 0.99 / 0.77, astronaut -0.16 /
#: 0.52, chelsea 0.25 / 1.28, lines 0.02 / 0.02 (mean 0.14 / 0.56). A convolution
#: keeps its fit pixels: with the final solve taken from the budget, the
#: path stopped short of the weights sparse scenes need (beads 35.25 -> 34.14 dB,
#: points 38.23 -> 37.78); with the final solve added to the budget instead, the
#: suite's scenes gained 0.02-0.25 dB, but up to a fixed run's iterations more would
#: take the slowest (3.7x one fixed solve) past the 4x goal (not timed), and
#: full-field photographs at bin 8 lost 0.6-0.7 dB in ADMM's transient after the
#: restart. A volume keeps its fit pixels (not measured with the final solve).
FINAL_ON_ALL_PIXELS = "final_on_all_pixels"

@dataclass(frozen=True)
class PathRule:
    """Where the held-out path runs and how it chooses (per regulariser and model).

    Attributes
    ----------
    start, end : float
        First and smallest weight of the path (scaled problem).
    se_rule : float
        Multiple of the held-out error's standard error within which the largest
        weight is taken.
    max_above_minimum : float
        The chosen weight is at most this multiple of the held-out minimum's weight.
    budget : float
        The path takes at most this multiple of a fixed-weight run's iterations.
    factor : float
        Factor between consecutive weights.
    block : int
        Side of the square blocks of sensor pixels held out together
        (:func:`holdout_split`).
    """

    start: float
    end: float
    se_rule: float = SE_RULE
    max_above_minimum: float = MAX_ABOVE_MINIMUM
    budget: float = BUDGET
    factor: float = PATH_FACTOR
    block: int = BLOCK


#: The 2D rules (:data:`START_WEIGHT`, :data:`END_WEIGHT`, :data:`SE_RULE`,
#: :data:`MAX_ABOVE_MINIMUM`); the 3D ones are :data:`recon.auto.volume.VOLUME_RULES`.
PATH_RULES = {reg: PathRule(START_WEIGHT[reg], END_WEIGHT[reg]) for reg in ("tv", "l1")}


@dataclass
class Stopping:
    """Stop when further iterations change the fit by less than the noise can explain.

    Every ``window`` iterations the data term 1/2 ||A x - b||^2 is compared with its
    value a window earlier; when it moved by less than ``tolerance`` times the noise
    target 1/2 E||n||^2 (a change no measurement could tell apart from noise), the
    solve stops. ``iterations`` remains the maximum.
    """

    window: int = 10
    tolerance: float = 1e-4

    def hook(self, target: float, b_norm: float):
        """``stop(history) -> bool`` for the solvers' ``stop`` option."""
        def stop(history: History) -> bool:
            if len(history.data_residual) <= self.window:
                return False
            return self.done(_data_terms(History(data_residual=history.data_residual[
                -1 - self.window:]), b_norm), target)
        return stop

    def done(self, data: list[float], target: float) -> bool:
        """Whether the data terms ``data`` (one per iteration) have settled."""
        if len(data) <= self.window or not target > 0:
            return False
        return abs(data[-1 - self.window] - data[-1]) < self.tolerance * target


@dataclass(frozen=True)
class PathTuning:
    """The automatic weight's settings a reconstruction leaves at their defaults (the
    tuning of :func:`admm_auto`, one object instead of six keywords).

    Attributes
    ----------
    stopping : Stopping
        Automatic stopping of the all-pixel final solve (only with a compact PSF,
        :func:`holdout_coverage`).
    mu : (mu1, mu2, mu3) or None
        Starting ADMM penalties (None: the solver's).
    model_error : float
        Relative rms error of the forward model; with the noise it sets the scale of
        automatic stopping: 1/2 (E||n||^2 + (model_error ||b||)^2).
    holdout : float
        Fraction of the (measured) pixels held out of the path's fits.
    seed : int
        Seed of the held-out pixels (:func:`holdout_split`).
    convergence : Convergence
        When a candidate counts as settled.
    """

    stopping: Stopping = field(default_factory=Stopping)
    mu: tuple | None = None
    model_error: float = MODEL_ERROR
    holdout: float = HOLDOUT
    seed: int = 0
    convergence: Convergence = field(default_factory=Convergence)


@dataclass
class AutoWeight:
    """How the weight was chosen (the record in the metrics JSON)."""

    weight: float
    criterion: str
    reason: str
    target: float
    path: list = field(default_factory=list)
    path_iterations: int = 0
    final_iterations: int = 0
    stopped_early: bool = False
    regulariser: str = "tv"
    kept_final_iteration: int | None = None
    holdout_coverage: float | None = None
    final_pixels: str | None = None
    stop_reason: str = ""
    budget_iterations: int = 0
    seconds: float = 0.0

    def as_dict(self) -> dict:
        return {"regulariser": self.regulariser, "weight": self.weight,
                "criterion": self.criterion, "reason": self.reason,
                "noise_target": self.target, "path": self.path,
                "path_iterations": self.path_iterations,
                "final_iterations": self.final_iterations,
                "stopped_early": self.stopped_early,
                "kept_final_iteration": self.kept_final_iteration,
                "holdout_coverage": self.holdout_coverage,
                "final_pixels": self.final_pixels, "stop_reason": self.stop_reason,
                "budget_iterations": self.budget_iterations,
                "candidates_settled": sum(bool(p.get("converged")) for p in self.path),
                "seconds": self.seconds}


def _data_terms(hist: History, b_norm: float) -> list[float]:
    return [0.5 * (r * b_norm) ** 2 for r in hist.data_residual]




def _merge(histories: list[History]) -> History:
    out = History()
    for h in histories:
        out.objective += h.objective
        out.data_residual += h.data_residual
        out.seconds += h.seconds
    return out


def path_budget(iterations: int, budget: float = BUDGET) -> int:
    """Iterations the path of :func:`admm_auto` may take for a fixed run's ``iterations``.

    Parameters
    ----------
    iterations : int
        Iterations of the fixed-weight run that automatic ADMM replaces (>= 1).
    budget : float
        Multiple of ``iterations`` (:data:`BUDGET`; the rule's ``budget``).

    Returns
    -------
    int
        ``max(2, round(budget * iterations))``.
    """
    return max(2, round(budget * int(iterations)))


def weight_grid(start: float, end: float, factor: float = PATH_FACTOR) -> list[float]:
    """The path's weights: ``start`` down to ``end``, geometric, steps of at most ``factor``.

    Returns
    -------
    list of float
        Descending, first ``start``, last ``end`` (one weight when they are equal).
    """
    if not (start > 0 and end > 0 and factor > 1):
        raise ReconInputError(f"weight path {start:g} .. {end:g} by {factor:g}: give "
                              "positive weights and a factor above 1")
    if start <= end:
        return [float(start)]
    n = math.ceil(math.log(start / end) / math.log(factor) - 1e-9) + 1
    return [float(start * (end / start) ** (k / (n - 1))) for k in range(n)]


def _choose(cands: list, rule: PathRule) -> tuple[int, int, float]:
    """(index of the held-out minimum, index chosen, chosen weight): the largest weight
    within ``rule.se_rule`` standard errors of the minimum, at most
    ``rule.max_above_minimum`` times its weight."""
    best = min(range(len(cands)), key=lambda i: cands[i].error)
    limit = cands[best].error + rule.se_rule * cands[best].standard_error
    bound = rule.max_above_minimum * cands[best].weight * (1 + 1e-9)
    k = next(i for i, c in enumerate(cands)
             if c.error <= limit and c.weight <= bound and c.x is not None)
    return best, k, cands[k].weight


def admm_auto(op, b: np.ndarray, *, iterations: int, noise_energy: float,
              regulariser: str = "tv", fixed: float = 0.0, path_only: bool = False,
              plan_of=None, rule: PathRule | None = None, seconds: float | None = None,
              tuning: PathTuning | None = None) -> tuple[SolveResult | None, AutoWeight]:
    """ADMM with its TV or l1 weight chosen by hold-out cross-validation between
    settled solves (the module docstring).

    Parameters
    ----------
    op : ConvolutionOperator, SpatialConvolutionOperator or VolumeConvolutionOperator
        Scaled forward model (unit-sum PSF or normalised stack; the spatial model and
        the volume model with their ``plan_of``).
    b : ndarray, float32, ``op.shape_out``
        Scaled measurement (weighted, divided by its maximum). An array of another
        array-API backend (CuPy, PyTorch) runs the path on its device (the generic
        ADMM, ``recon.solvers.xp_admm.XpAdmmPlan``, by default): iterates, kept
        estimates and held-out scores stay there, the result's ``x`` too; the held-out
        split and :func:`holdout_coverage` are computed on the host from ``op``.
    iterations : int
        Iterations of the fixed-weight run this replaces: each candidate weight runs
        at most this many, the whole path at most ``rule.budget`` times as many
        (:func:`path_budget`).
    noise_energy : float
        E||n||^2 of the scaled measurement (from :class:`recon.auto.noise.NoiseModel`).
    regulariser : {"tv", "l1"}
        Which weight the path chooses.
    fixed : float
        The other regulariser's weight, held fixed along the path (default 0).
    path_only : bool
        Return after choosing the weight (``result`` None), for another solver to
        use it.
    plan_of : callable, optional
        ``plan_of(op) -> plan`` for ``op`` and its copies with other sensor weights:
        default :meth:`recon.solvers.admm.AdmmPlan.of` (a convolution; with ``b`` on a
        device its ``recon.solvers.xp_admm.XpAdmmPlan``; a caller's ``plan_of``
        must make plans for ``b``'s backend);
        :meth:`recon.spatial.SpatialAdmmPlan.of` for a spatially varying model,
        :meth:`recon.volume.VolumeAdmmPlan.of` for a volume. A plan has ``op``,
        ``zeros(mu, use_tv)``, ``warm(x, mu, use_tv)``, ``run(b, state, iterations=,
        tv=, l1=, final=)`` and ``objective(b, x, tv=, l1=, b_norm=)``; its states
        ``x``, ``mx`` (the uncropped prediction plane) and ``mu``.
    rule : PathRule, optional
        The path's span, step, budget and choice rule; default :data:`PATH_RULES` of
        ``regulariser`` (the 2D rules).
    seconds : float, optional
        Wall-clock budget of the path, s: no candidate window starts after it (the
        record says where it stopped and how settled each candidate was).
    tuning : PathTuning, optional
        The final solve's stopping, the starting penalties, the model error, the
        held-out fraction and its seed, and when a candidate counts as settled
        (default ``PathTuning()``).

    Returns
    -------
    result : SolveResult
        The chosen candidate's kept iterate (the one that predicted the held-out
        pixels best); ``final_objective`` and ``final_relative_residual`` are that
        estimate's, on the pixels its solve fitted; ``history`` spans the path;
        ``params`` adds ``auto`` (the :class:`AutoWeight` record) and
        ``iterations_used``.
    choice : AutoWeight

    Raises
    ------
    ReconInputError
        Unknown ``regulariser``, a negative ``fixed`` weight or ``seconds``.
    """
    t_start = time.perf_counter()
    tuning = tuning or PathTuning()
    stopping, mu, conv = tuning.stopping, tuning.mu, tuning.convergence
    model_error, holdout, seed = tuning.model_error, tuning.holdout, tuning.seed
    if regulariser not in ("tv", "l1"):
        raise ReconInputError(f"regulariser {regulariser!r}: use 'tv' or 'l1'")
    if seconds is not None and not (seconds > 0 and math.isfinite(seconds)):
        raise ReconInputError(f"time budget {seconds} s: give a positive number of seconds")
    rule = rule or PATH_RULES[regulariser]
    cap = max(1, int(iterations))
    total = path_budget(cap, rule.budget)
    arrays = PathArrays(b)
    b_norm = arrays.norm(b)
    target = 0.5 * (float(noise_energy) + (model_error * b_norm) ** 2)
    fixed = float(fixed)
    if not (math.isfinite(fixed) and fixed >= 0):
        raise ReconInputError(f"the fixed {'l1' if regulariser == 'tv' else 'tv'} weight "
                              f"must be a finite number >= 0, got {fixed!r}")

    def weights(w: float) -> dict:
        """The plan's tv and l1 with the path's weight ``w``."""
        return {"tv": w, "l1": fixed} if regulariser == "tv" else {"tv": fixed, "l1": w}

    use_tv = regulariser == "tv" or fixed > 0
    w = op.sensor_weights
    keep, held = holdout_split(op, holdout, seed, rule.block)
    # the result is a final solve on all pixels, which takes a fixed run's iterations
    # from the budget, with a compact PSF (the held-out blocks hide object pixels) or
    # where the model asks for it (FINAL_ON_ALL_PIXELS)
    coverage = holdout_coverage(op, keep) if not path_only else None
    compact = coverage is not None and coverage < MIN_COVERAGE
    watch = path_only or not (compact or getattr(op, FINAL_ON_ALL_PIXELS, False))
    if not watch:
        total = max(1, total - cap)
    if plan_of is None:
        plan_of = AdmmPlan.of if arrays.numpy else device_plan_of(b, AdmmPlan.of)
    fit_plan = plan_of(op.with_weights(w * keep))
    if arrays.numpy:
        b_fit = np.ascontiguousarray(b * keep, np.float32)
        w_on, held_on = w, held
    else:  # the weights and masks on the device, once
        b_fit = b * arrays.put(keep)
        w_on, held_on = arrays.put(w), arrays.put(held, np.float64)
    n_held = int(np.count_nonzero(held))
    state = fit_plan.zeros(check_penalties(mu), use_tv)

    def score(st) -> tuple[float, float]:
        """Held-out prediction error of a fit's state, and its standard error."""
        return arrays.held_error(w_on * arrays.clip0(st.mx[op.crop]), b, held_on, n_held)

    deadline = None if seconds is None else t_start + float(seconds)
    grid = weight_grid(rule.start, rule.end, rule.factor)
    stage_cap = min(cap, max(conv.min_iterations, round(STAGE_SHARE * cap)))
    cands, used, rises, best, stop = [], 0, 0, None, None
    for weight in grid:  # the first weight runs whatever the budget
        if cands and used >= total:
            stop = (f"the iteration budget ran out ({used} of {total} = {rule.budget:g}x "
                    f"{cap}); weights below {cands[-1].weight:.3g} untried")
            break
        if cands and deadline is not None and time.perf_counter() > deadline:
            stop = (f"the time budget of {seconds:g} s ran out after {used} iterations; "
                    f"weights below {cands[-1].weight:.3g} untried")
            break
        c = run_candidate(fit_plan, b_fit, state, weights(weight), score, arrays.copy,
                          weight=weight, cap=min(stage_cap, total - used), conv=conv,
                          deadline=deadline, after_step=bool(cands))  # the first: from 0
        used += c.iterations
        cands.append(c)
        improved = best is None or c.error < best.error
        if improved:
            best, rises = c, 0
        elif c.error - c.remaining > best.error + best.standard_error:
            rises += 1  # worse by more than its scatter, even after its remaining fall
            if rises == 2:
                stop = (f"past the held-out minimum: two weights in a row ({cands[-2].weight:.3g}, "
                        f"{weight:.3g}) predict the held-out pixels worse than the best by "
                        "more than one standard error, even after the fall their solves "
                        "had left")
                break
        # keep only the iterates the rule may choose: the minimum's and larger weights
        # within max_above_minimum of it
        for d in cands:
            if d.weight > rule.max_above_minimum * best.weight * (1 + 1e-9) or \
                    d.weight < best.weight:
                d.x = None
            if d is not best:
                d.state = None
        if improved:  # the chosen weight runs on from here (copied once the copies of
            c.state = copy.deepcopy(state)  # the former best are dropped: a lower peak)
    if stop is None:
        stop = f"reached the smallest weight of the path ({grid[-1]:.3g})"
    i_min, k, chosen = _choose(cands, rule)
    pick = cands[k]
    settle = 0
    # a path that only chooses (``path_only``) ends here: the run-on below improves
    # the kept iterate, which such a caller drops (the RGB lead channel ran on for
    # 40-200 iterations it then threw away, 4-19 % of the image's ADMM iterations on the
    # real pairs, docs/real-data.md)
    if not path_only and used < total and (deadline is None
                                           or time.perf_counter() < deadline):
        # run on at the chosen weight with what the budget has left (at most a fixed
        # run's iterations), from the state its path solve ended in (a restart from the
        # kept iterate with fresh duals lost 3 dB for 50 iterations; from the path's
        # last state, at a smaller weight, 3 dB on smooth shapes): where the held-out
        # error is flat the image still improves
        if pick.state is not None:  # from the chosen weight's own state
            state = pick.state
        more = run_candidate(fit_plan, b_fit, state, weights(chosen), score, arrays.copy,
                             weight=chosen, cap=min(cap, total - used), conv=conv,
                             deadline=deadline, settle=False,
                             after_step=pick.state is None)
        settle = more.iterations
        used += settle
        cands[-1].histories += more.histories
        if more.error <= pick.error + conv.keep * pick.standard_error:
            pick.x, pick.kept_iteration = more.x, pick.iterations + more.kept_iteration
            pick.iterations += more.iterations
            pick.status = "run on" if more.status == "cap" else more.status
        more.x = None
    unsettled = [c.weight for c in cands if not c.converged]
    if settle:
        stop += f"; the chosen weight then ran on for {settle} iterations"
    reason = (f"hold-out cross-validation: {100 * holdout:g} % of the pixels held out in "
              f"{rule.block} x {rule.block} blocks; each weight solved (warm-started, at "
              f"most {cap} iterations) until its held-out error settled; the largest weight whose "
              f"fit predicts them within "
              f"{'one' if rule.se_rule == 1 else f'{rule.se_rule:g}'} standard "
              f"error ({best.standard_error:.3g}) of the best prediction "
              f"({best.error:.4g}, at weight {best.weight:.3g}), at most "
              f"{rule.max_above_minimum:g}x that weight. The path stopped: {stop}")
    if unsettled:
        reason += ("; not settled within their iterations: "
                   + ", ".join(f"{u:.3g}" for u in unsettled))
    if not pick.converged:
        log.warning("automatic %s weight %.3g: its solve had not settled (%d iterations, "
                    "held-out error could still fall by %.3g standard errors)", regulariser,
                    chosen, pick.iterations, pick.remaining / max(pick.standard_error, 1e-30))
    histories = [h for c in cands for h in c.histories]
    choice = AutoWeight(chosen, "holdout", reason, target, [c.record() for c in cands], used,
                        0, False, regulariser, pick.kept_iteration, coverage,
                        "fit, held-out watched", stop_reason=stop, budget_iterations=total,
                        seconds=time.perf_counter() - t_start)
    x, params = pick.x, cands[-1].params
    for c in cands:
        c.x = c.state = None
    if path_only:
        return None, choice
    final_plan, b_final, done = fit_plan, b_fit, 0
    if not watch:  # from the chosen estimate, on all pixels, fresh duals
        final_plan, b_final = plan_of(op), b
        state = final_plan.warm(x, check_penalties(mu), use_tv)
        final_data = []
        while done < cap:
            n = min(stopping.window, cap - done)
            res = final_plan.run(b, state, iterations=n, final=False, **weights(chosen))
            histories.append(res.history)
            final_data += _data_terms(res.history, b_norm)
            done += n
            if stopping.done(final_data, target):
                choice.stopped_early = done < cap
                break
        x, params = res.x, res.params
        choice.final_iterations, choice.kept_final_iteration = done, done
        choice.final_pixels = ("all (the held-out blocks hide object pixels)" if compact
                               else "all, from the chosen estimate (the model's rule)")
    choice.seconds = time.perf_counter() - t_start
    history = _merge(histories)
    history.extra["mu"] = [list(state.mu)]
    params = dict(params, auto=choice.as_dict(), iterations_used=used + done)
    objective, relative = final_plan.objective(b_final, x, **weights(chosen),
                                               b_norm=max(arrays.norm(b_final), 1e-30))
    return SolveResult(x, history, objective, relative, params), choice

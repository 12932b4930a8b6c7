"""One candidate weight of the automatic weight's path, solved until its held-out
error has settled (:func:`run_candidate`), and the bound on how much it could still
fall (:func:`remaining_bound`).

The path of :func:`recon.auto.weight.admm_auto` compares the held-out prediction errors
of candidate weights. A comparison after a fixed short number of iterations per weight
compares unconverged solves: a small weight needs hundreds of ADMM iterations (the
camera photograph through the real tutorial PSF at bin 4, 30000 e-: TV 1e-5 at 22.1 dB
after 100 iterations, 28.4 dB after 200), so its held-out error is still falling when
the next weight begins, and a path that stops at the first rises never reaches the
weights the scene needs (11 dB short of the best fixed weight on that photograph). Here
each candidate runs, warm-started from the one before, in windows of
``Convergence.window`` iterations until one of:

* **settled**: the held-out error could fall by at most ``Convergence.tolerance``
  of its standard error more (:func:`remaining_bound`: the last window's fall times
  r / (1 - r), r the slower of the last two contractions of the falls -- a geometric
  tail), or no longer falls;
* **rising**: after ``Convergence.min_iterations`` (ADMM's transient after a weight
  step is over: it spiked the error once, 0.97 -> 2.0 -> 1.04, with 80 % of the pixels
  erased), the last two windows' errors are both more than one standard error above the
  lowest of all its windows -- the solve is now fitting noise into what the held-out
  pixels do not share, and the iterate with the best held-out error after the transient
  is kept (cross-validated early stopping, Prechelt 1998);
* **cap**: the candidate's iteration cap or the path's budget (iterations or seconds)
  ran out first; its remaining bound then says how far from settled it was.

The candidate's score is its best held-out error once the transient after the weight
step is over (``Convergence.min_iterations``: before, the iterate is still the
previous weight's solution moving, and scoring it there compared a blend of two weights
with the others' own solves); the iterate kept is the latest within
``Convergence.keep`` standard errors of it (where the error is flat the image still
improves). The chosen weight is then run on from the path's state
(:func:`recon.auto.weight.admm_auto`), and its kept iterate is the result.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

__all__ = ["Candidate", "Convergence", "remaining_bound", "run_candidate"]


@dataclass(frozen=True)
class Convergence:
    """When a candidate's held-out error counts as settled.

    Attributes
    ----------
    window : int
        Iterations between held-out scores.
    tolerance : float
        Settled when the error could still fall by at most this many of its standard
        errors (:func:`remaining_bound`).
    min_iterations : int
        Iterations before a rise may end a candidate (ADMM's transient after a weight
        step).
    keep : float
        The kept iterate is the latest whose held-out error is within this many
        standard errors of the candidate's best: where the error is flat the image
        still improves (camera photograph, bin 8, 3000 e-, TV 2.7e-5 on the fit
        pixels: 20.5 / 22.6 / 23.0 dB after 100 / 200 / 400 iterations while the
        held-out error moved by less than a third of its standard error).
    """

    window: int = 10
    tolerance: float = 0.5
    min_iterations: int = 30
    keep: float = 0.5


@dataclass
class Candidate:
    """One weight of the path, as solved.

    Attributes
    ----------
    weight : float
    error, standard_error : float
        Held-out prediction error of the kept iterate, and its standard error.
    iterations : int
        Iterations run at this weight.
    kept_iteration : int
        Iteration (within this weight's run) of the kept iterate.
    remaining : float
        Bound on how much more the held-out error could fall (:func:`remaining_bound`).
    status : str
        ``"settled"``, ``"rising"`` or ``"cap"`` (see the module docstring), or
        ``"run on"`` (the chosen weight, run on after the path to its cap).
    x : array or None
        The kept iterate (non-negative), on the measurement's backend.
    histories : list of History
        The runs' histories, one per window.
    params : dict
        The last run's ``params``.
    state : object or None
        A copy of the plan's state where this weight's run ended (kept for the best
        weight: the chosen one runs on from it).
    """

    weight: float
    error: float
    standard_error: float
    iterations: int
    kept_iteration: int
    remaining: float
    status: str
    x: object = None
    histories: list = field(default_factory=list)
    params: dict = field(default_factory=dict)
    state: object = None

    @property
    def converged(self) -> bool:
        """Settled, or past its held-out minimum (nothing more to gain by iterating)."""
        return self.status in ("settled", "rising", "run on")

    def record(self) -> dict:
        """JSON-ready (without the iterate)."""
        return {"weight": self.weight, "holdout_error": self.error,
                "standard_error": self.standard_error, "iterations": self.iterations,
                "kept_iteration": self.kept_iteration, "remaining_bound": self.remaining,
                "remaining_in_standard_errors": (self.remaining / self.standard_error
                                                 if self.standard_error > 0 else None),
                "status": self.status, "converged": self.converged}


def remaining_bound(errors: list[float]) -> float:
    """How much further a falling held-out error could fall (a geometric tail).

    With the last three falls per window ``f1, f2, f3`` all positive and
    ``r = max(f3 / f2, f2 / f1)`` (the slower of the last two contractions): the tail
    ``f3 r / (1 - r)``. A fall that is not yet steady (fewer than four scores, an
    earlier window that rose -- a transient after a weight step --, or ``r >= 0.9``)
    is bounded as ``r = 0.9``: ``9 f3``; 0 when the error no longer falls.

    Parameters
    ----------
    errors : list of float
        Held-out errors, one per window, oldest first.

    Returns
    -------
    float
        >= 0, in the errors' units (``inf`` with fewer than two scores).
    """
    if len(errors) < 2:
        return float("inf")
    f3 = errors[-2] - errors[-1]
    if f3 <= 0:
        return 0.0
    r = 0.9
    if len(errors) >= 4:
        f1, f2 = errors[-4] - errors[-3], errors[-3] - errors[-2]
        if f1 > 0 and f2 > 0:
            r = min(0.9, max(f3 / f2, f2 / f1))
    return f3 * r / (1 - r)


def run_candidate(plan, b_fit, state, weights: dict, score, copy, *, weight: float,
                  cap: int, conv: Convergence, deadline: float | None = None,
                  settle: bool = True, after_step: bool = True) -> Candidate:
    """Run one path weight from ``state`` (warm, updated in place) until it settles.

    Parameters
    ----------
    plan : ADMM plan (:class:`recon.solvers.admm.AdmmPlan` interface)
    b_fit : array
        The fit pixels' measurement.
    state
        The plan's state, continued from the previous weight.
    weights : dict
        ``tv`` and ``l1`` for ``plan.run``.
    score : callable
        ``score(state) -> (error, standard_error)`` on the held-out pixels.
    copy : callable
        Copies an iterate (on its backend).
    weight : float
        The path weight (for the record).
    cap : int
        Most iterations at this weight (>= 1).
    conv : Convergence
    deadline : float, optional
        ``time.perf_counter()`` value after which no further window starts.
    settle : bool
        Stop when settled (False: run to ``cap`` unless rising).
    after_step : bool
        ``state`` is another weight's (the path's warm start): the windows within
        ``Convergence.min_iterations`` are not scored, since the iterate there is
        still the previous weight's solution moving (a held-out dip in it is a blend
        of the two weights that neither's solve keeps; the real 3D DiffuserCam sample
        at bin 4 scored such a blend best and returned it after 10 iterations, with
        half the fine structure of the settled solves). False for the path's first
        weight (from zero: its early iterates are that weight's early-stopped solves)
        and when running on from the weight's own state.

    Returns
    -------
    Candidate
        With ``x`` the kept iterate.
    """
    errors, histories, done = [], [], 0
    best = kept = None  # (error, se), (x, iteration)
    lowest = (float("inf"), 0.0)
    status, remaining = "cap", float("inf")
    least = min(conv.min_iterations, cap)
    score_from = least if after_step else 0
    while done < cap:
        n = min(conv.window, cap - done)
        res = plan.run(b_fit, state, iterations=n, final=False, **weights)
        histories.append(res.history)
        done += n
        err, se = score(state)
        errors.append(err)
        # within the transient after a weight step the iterate is still the previous
        # weight's solution moving: it is not scored as this weight's (like with like)
        # (a dip there is the two weights' blend, which neither weight's solve keeps);
        # the lowest error of all windows still tells a rise past the minimum
        lowest = min(lowest, (err, se))
        last = done >= cap or deadline is not None and time.perf_counter() > deadline
        if done >= score_from or best is None and last:
            if best is None or err < best[0]:
                best = (err, se)
            if err <= best[0] + conv.keep * best[1]:
                kept = None  # the former copy goes before the new one is made
                kept = (copy(res.x), done)
        remaining = remaining_bound(errors)
        if done >= least and len(errors) >= 2 and \
                min(errors[-2:]) > lowest[0] + lowest[1]:
            status, remaining = "rising", 0.0
            break
        if settle and done >= least and remaining <= conv.tolerance * best[1]:
            status = "settled"
            break
        if deadline is not None and time.perf_counter() > deadline:
            break
    return Candidate(weight, best[0], best[1], done, kept[1], remaining, status, kept[0],
                     histories, res.params)

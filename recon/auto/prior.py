"""The prior chosen by the data: each prior's held-out path, then the simplest that
predicts the held-out pixels as well as the best.

"Model no more than a scene needs" for the prior itself, not only its weight. For each
prior of :data:`recon.priors.AUTO_PRIORS` (TV, wavelet, DnCNN) the automatic weight's
hold-out cross-validation (:func:`recon.auto.weight.admm_auto`: the same held-out
blocks, the same seed, warm-started continuation, each candidate run until its
held-out error settles) chooses the prior's weight along its own path
(:data:`PRIOR_RULES`); each chosen candidate's held-out prediction error and its
standard error are then compared across priors. The data choose the *simplest*
prior (in :data:`~recon.priors.AUTO_PRIORS` order) whose held-out error is within
``se_rule`` standard errors of the best prior's -- the one-standard-error rule of
Breiman et al. 1984 (Sec. 3.4.3) applied between models of increasing complexity, as
the weight path applies it between weights -- and its path's result is the result.
The record (:class:`PriorChoice`) lists every prior's weight, held-out error,
standard error, iterations and seconds, and says why.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from ..errors import ReconInputError
from ..priors import AUTO_PRIORS, prior_of
from .weight import PATH_RULES, SE_RULE, PathRule

__all__ = ["PRIOR_RULES", "PriorChoice", "choose_prior", "prior_plan_of"]

#: The weight path of each prior. TV: the 2D rule; isotropic TV and TGV (a1 = 1) too,
#: their weights being on TV's scale (both at most an image's anisotropic TV). Wavelet:
#: the same span (its weight, like TV's, is an l1 weight on a linear transform of the
#: scaled image, and thresholds at weight / mu2). DnCNN: the weight is the denoiser's noise level
#: relative to the iterate's scale, from 0.3 down to 0.15 in steps of sqrt(2) (3
#: candidates). Measured on the priors benchmark (bin 8, 200 iterations): a path
#: from 0.2 down to 0.005 in the usual steps chose 0.08 on five of the six natural and
#: textured scenes, where the plug-and-play iterate keeps the noise the denoiser no
#: longer removes (chelsea 15.9 dB, brick 16.0, gravel 15.9 against 23.9, 22.4, 21.2 at
#: 0.2; the camera 18.3 at 0.1) while its held-out prediction error still fell: the
#: held-out blocks do not see that noise. Every scene's best fixed level was 0.2 or
#: 0.25, the sparse ones' (beads, text) 0.1.
PRIOR_RULES = {"tv": PATH_RULES["tv"], "tv-iso": PATH_RULES["tv"], "tgv": PATH_RULES["tv"],
               "wavelet": PathRule(1e-2, 1e-5),
               "dncnn": PathRule(0.3, 0.15, factor=2 ** 0.5)}


def prior_plan_of(prior, like):
    """``plan_of(op)`` for the automatic weight with ``prior`` on ``like``'s backend.

    Parameters
    ----------
    prior : str or Prior
        A name of :data:`recon.priors.PRIORS` or a prior.
    like : array
        Any array of the backend the path runs on (NumPy: the host).

    Returns
    -------
    callable or None
        None for TV on NumPy (:func:`~recon.auto.weight.admm_auto` then takes the
        fused plan, :meth:`recon.solvers.admm.AdmmPlan.of`), the fused plan's
        :meth:`~recon.solvers.admm.AdmmPlan.isotropic_view` for isotropic TV on NumPy;
        else ``op -> plan``
        making the generic plans (``recon.solvers.xp_admm.XpAdmmPlan``) with the
        prior.

    Raises
    ------
    ReconInputError
        An unknown prior name.
    """
    import numpy as np

    from ..solvers.admm import AdmmPlan
    from ..solvers.xp_admm import XpAdmmPlan

    p = prior_of(prior)
    if p.name == "tv" and isinstance(like, np.ndarray):
        return None
    if p.name == "tv-iso" and isinstance(like, np.ndarray):  # the fused passes too
        return lambda op: AdmmPlan.of(op).isotropic_view()
    return XpAdmmPlan.maker(like, AdmmPlan.of, prior=p)


@dataclass
class PriorChoice:
    """How the prior was chosen (the record's ``prior``).

    Attributes
    ----------
    prior : str
        The chosen prior's name.
    reason : str
        Why, in words.
    candidates : list of dict
        Per prior tried: ``prior``, ``weight`` (its path's choice), ``holdout_error``,
        ``standard_error``, ``iterations``, ``seconds``; or ``error`` when its path
        failed (diverged).
    se_rule : float
    results : dict
        Every finished prior's path result by name (not in the record: for a caller
        that compares them, the benchmark).
    """

    prior: str
    reason: str
    candidates: list = field(default_factory=list)
    se_rule: float = SE_RULE
    results: dict = field(default_factory=dict, repr=False)

    def as_dict(self) -> dict:
        """The record (JSON-ready; without ``results``)."""
        return {"prior": self.prior, "criterion": "holdout", "reason": self.reason,
                "se_rule": self.se_rule, "candidates": self.candidates}


def _chosen_score(choice) -> tuple[float, float]:
    """The held-out error and standard error of a path's chosen weight."""
    for p in choice.path:
        if p["weight"] == choice.weight:
            return float(p["holdout_error"]), float(p["standard_error"])
    raise ReconInputError("the weight path's record lacks its chosen weight")  # defensive


def choose_prior(path, priors=AUTO_PRIORS, se_rule: float = SE_RULE):
    """Run ``path(prior_name, rule)`` for each prior and choose between them.

    Parameters
    ----------
    path : callable
        ``path(name, rule) -> (result, AutoWeight)``: one prior's automatic weight
        (:func:`recon.auto.weight_path` with that prior's plans and rule), on the same
        measurement and held-out blocks for every prior.
    priors : sequence of str
        Names from :data:`recon.priors.PRIORS`, simplest first (default
        :data:`~recon.priors.AUTO_PRIORS`).
    se_rule : float
        Multiple of the best prior's standard error within which a simpler prior is
        taken.

    Returns
    -------
    result : SolveResult
        The chosen prior's path result (``params['prior']`` names it).
    weight : AutoWeight
        Its weight record.
    choice : PriorChoice

    Raises
    ------
    ReconInputError
        An unknown prior name, or none of the priors' paths finished (each error
        named).
    recon.errors.DivergenceError
        Not raised for one prior: a diverged path is recorded and the others compared.
    """
    from ..errors import DivergenceError

    names = [prior_of(p).name for p in priors]
    if not names:
        raise ReconInputError("choose among at least one prior")
    done, cands = [], []
    for name in names:
        t0 = time.perf_counter()
        try:
            res, weight = path(name, PRIOR_RULES[name])
        except DivergenceError as exc:
            cands.append({"prior": name, "error": str(exc),
                          "seconds": time.perf_counter() - t0})
            continue
        err, se = _chosen_score(weight)
        weight.regulariser = name
        cands.append({"prior": name, "weight": weight.weight, "holdout_error": err,
                      "standard_error": se, "iterations": weight.path_iterations,
                      "seconds": time.perf_counter() - t0})
        done.append((name, res, weight, err, se))
    if not done:
        raise ReconInputError("no prior's path finished: " + "; ".join(
            f"{c['prior']}: {c['error']}" for c in cands))
    best = min(done, key=lambda d: d[3])
    limit = best[3] + se_rule * best[4]
    pick = next(d for d in done if d[3] <= limit)  # the simplest within the limit
    scores = ", ".join(f"{d[0]} {d[3]:.4g} (weight {d[2].weight:.3g})" for d in done)
    if pick is best:
        why = f"{pick[0]} predicts the held-out pixels best"
    else:
        why = (f"{pick[0]} is the simplest prior within {se_rule:g} standard error "
               f"({best[4]:.3g}) of the best, {best[0]}")
    reason = (f"hold-out cross-validation between priors, each at the weight its own path "
              f"chose: {why}. Held-out errors: {scores}")
    if len(done) < len(names):
        reason += "; failed: " + ", ".join(c["prior"] for c in cands if "error" in c)
    name, res, weight = pick[0], pick[1], pick[2]
    if res is not None:
        res.params["prior"] = prior_of(name).record()
    return res, weight, PriorChoice(name, reason, cands, se_rule,
                                    {d[0]: d[1] for d in done})

"""ADMM penalties and their residual balancing, shared by every ADMM (2D and 3D).

The splittings of Eq. 4.5 / App. A.3 (Kuo 2020; Antipa et al. 2018) carry one
penalty per split (mu1 crop/data, mu2 TV, mu3 non-negativity). They start at
:attr:`AdmmPenalty.mu` and are balanced from the primal and dual residuals (Boyd et
al. 2011, Sec. 3.4.1, with the normalised residuals of Wohlberg 2017).
:class:`AdmmPenalty` holds these settings as one value that the solvers
(:func:`recon.solvers.admm.admm`, :func:`recon.volume.admm3d`,
:func:`recon.spatial.spatial_admm`, :class:`recon.live.LiveReconstructor`, and the loop
they all run, :func:`recon.solvers.admm_loop.run_admm`) take as ``penalty=``; the
functions below are the balancing steps themselves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ReconInputError
from ..validate import as_int, finite_float, positive

__all__ = ["DEFAULT_MU", "MU_RANGE", "AdmmPenalty", "admm_result", "balance_mode",
           "balanced_penalty", "check_balancing", "check_penalties", "check_penalty_settings",
           "rescale_duals", "tie_nonneg_penalty"]

#: Balancing moves penalties only within this range (scaled problem: unit-sum PSF,
#: |b| <= 1). The normalised dual residual of an inactive constraint (e.g. x >= 0
#: where x is positive anyway) has a dual near zero and would push its penalty
#: down without bound.
MU_RANGE = (1e-5, 1e2)

#: Initial penalties (mu1, mu2, mu3) when none are given, for the scaled problem.
DEFAULT_MU = (2e-3, 2e-3, 2e-3)


def check_balancing(balance_every, balance_until: float, balance_ratio: float,
                    balance_factor: float) -> None:
    """Validate residual-balancing settings (shared by the 2D and 3D ADMM).

    Raises
    ------
    ReconInputError
        ``balance_every`` not an integer >= 2 (mode-1 and mode-2 iterations must
        differ), ``balance_ratio`` or ``balance_factor`` not > 1 (the penalties
        would oscillate or not move), ``balance_until`` outside [0, 1].
    """
    as_int(balance_every, "balance_every", 2)
    finite_float(balance_until, "balance_until", lo=0.0, hi=1.0)
    finite_float(balance_ratio, "balance_ratio", lo=1.0, lo_open=True)
    finite_float(balance_factor, "balance_factor", lo=1.0, lo_open=True)


def check_penalties(mu) -> tuple[float, float, float]:
    """ADMM penalties ``(mu1, mu2, mu3)``: three positive finite numbers, default
    :data:`~recon.solvers.penalty.DEFAULT_MU`.

    Raises
    ------
    ReconInputError
        Not a sequence of three, or an entry not a positive finite number.
    """
    if mu is None:
        return DEFAULT_MU
    try:
        n = len(mu)
    except TypeError:
        n = None
    if n != 3 or isinstance(mu, str):
        raise ReconInputError(f"mu must be three ADMM penalties (mu1, mu2, mu3), got {mu!r}")
    return tuple(positive(m, f"mu[{i}] of the ADMM penalties") for i, m in enumerate(mu))


def balance_mode(k: int, balance_every: int, last_balance: int) -> int:
    """Mode of the fused split kernels at iteration ``k``.

    0: plain update; 1: store the scaled duals (the iteration before a balancing
    step); 2: also return the residual terms and balance. Balancing runs every
    ``balance_every`` iterations while ``k < last_balance``.
    """
    if k < last_balance:
        if k % balance_every == balance_every - 1:
            return 1
        if k % balance_every == 0 and k > 0:
            return 2
    return 0


def balanced_penalty(mu_i: float, r2: float, s2: float, n2: float, d2: float,
                     ratio: float, factor: float) -> float:
    """One penalty after residual balancing (Boyd et al. 2011, Sec. 3.4.1).

    With the normalised residuals of Wohlberg 2017, so the splits' different scales
    do not matter: ``r = sqrt(r2 / n2)`` (primal ||G x - z|| over max(||G x||, ||z||))
    and ``s = sqrt(s2 / d2)`` (dual mu ||z - z_prev|| over the dual's norm mu ||a||).
    ``mu_i`` is multiplied by ``factor`` when r > ratio s and divided when
    s > ratio r, within :data:`MU_RANGE`; unchanged when n2 or d2 is 0.

    Parameters
    ----------
    mu_i : float
        Current penalty.
    r2, s2, n2, d2 : float
        Sums over the split of (a - a_old)^2, (z - z_old)^2, max(g^2, z^2), a^2 (the
        terms of ``recon.jit.balance_terms``).
    ratio, factor : float
        ``balance_ratio`` and ``balance_factor`` (> 1).

    Returns
    -------
    float
    """
    if n2 > 0 and d2 > 0:
        r_i, s_i = math.sqrt(r2 / n2), math.sqrt(s2 / d2)
        if r_i > ratio * s_i and mu_i < MU_RANGE[1]:
            return mu_i * factor
        if s_i > ratio * r_i and mu_i > MU_RANGE[0]:
            return mu_i / factor
    return mu_i


def tie_nonneg_penalty(new: list, ratio: float, regularised: bool) -> None:
    """Without a TV (or l1) split, let the non-negativity penalty follow the data one.

    The non-negativity split's dual is zero wherever the constraint is inactive
    (most pixels), so its normalised dual residual is large and residual balancing
    drives mu3 down to the floor of :data:`MU_RANGE`. With a TV split, mu2 |F Psi|^2
    keeps the x-update's denominator mu1 |H|^2 + mu2 |F Psi|^2 + mu3 conditioned;
    without one, mu3 / mu1 is the x-update's only Tikhonov term and a tiny ratio
    turns each x-update into an inverse filter: on a simulated camera scene (real
    PSF, 3000 photo-electrons) ADMM with tv = 0 fell below the noise level
    (objective 6.8 against 7.9 for the noise alone, peak 20x the truth's) and 11.6 dB
    below FISTA. So mu3 keeps its starting ratio to mu1 (``new[2] = ratio * new[0]``),
    in place, when ``regularised`` is False.

    The volume's ADMM does not tie (``VolumeAdmmPlan.tie_nonneg``):
    there the data term is rank one per lateral frequency and mu3 I regularises the
    other n_z - 1 directions; tied, mu3 rose with mu1 and damped the fit. Measured on
    the 3D bead problem of the tests (5 planes of 128 x 128, 7 beads, 2 % noise), ADMM
    without TV, 150 iterations: tied, correlation with the truth 0.47 and relative
    residual 0.25 (0.58 and 0.20 after 400); balanced freely, 0.99 and 0.10 (the noise
    level), mu3 staying at 2e-3 while mu1 rose to 6.4e-2; with l1 1e-3, 0.50 against
    1.00.
    """
    if not regularised:
        new[2] = ratio * new[0]


def rescale_duals(splits) -> None:
    """Keep the q-form state consistent after penalties change, in place.

    Scaled duals are a = y / mu, so with the dual y fixed, q = z - a becomes
    z - a mu / mu' = q + a (1 - mu / mu'). ``splits`` yields ``(q, a, mu_old,
    mu_new)`` with ``a`` the duals stored by the mode-1 pass (overwritten here:
    the next mode-1 pass rewrites them before they are read again).
    """
    for q, a, old, new in splits:
        if old != new:
            a *= np.float32(1.0 - old / new)
            q += a


@dataclass(frozen=True)
class AdmmPenalty:
    """ADMM penalty settings: the initial penalties and their residual balancing.

    One value for what the 2D, spatially varying and live ADMM take as
    ``penalty=`` (default ``AdmmPenalty()``). Validated on construction.

    Attributes
    ----------
    mu : (mu1, mu2, mu3) or None
        Initial penalties of the crop/data, TV and non-negativity splits, positive
        and finite; None: the solver's default (:data:`~recon.solvers.penalty.DEFAULT_MU`
        in 2D). Balancing adapts them, so the start matters little.
    balance : bool
        Residual balancing on (default) or off (the penalties stay at ``mu``).
    balance_every : int
        Balance every this many iterations, >= 2 (the iteration before a balancing
        step stores the scaled duals).
    balance_until : float
        Fraction of the iterations in [0, 1] after which the penalties stay fixed.
    balance_ratio : float
        Residual ratio (> 1) beyond which a penalty moves.
    balance_factor : float
        Factor (> 1) by which it moves.

    Raises
    ------
    ReconInputError
        On construction: ``mu`` not three positive finite numbers, ``balance`` not a
        bool, or balancing settings out of range (:func:`check_balancing`).

    Examples
    --------
    >>> AdmmPenalty(mu=(1e-3, 2e-3, 3e-3), balance_every=10).initial()
    (0.001, 0.002, 0.003)
    >>> AdmmPenalty(balance=False).last_balance(100)
    0
    """

    mu: tuple[float, float, float] | None = None
    balance: bool = True
    balance_every: int = 5
    balance_until: float = 0.6
    balance_ratio: float = 10.0
    balance_factor: float = 2.0

    def __post_init__(self):
        if self.mu is not None:
            object.__setattr__(self, "mu", check_penalties(self.mu))
        if not isinstance(self.balance, bool | np.bool_):
            raise ReconInputError(f"balance must be True or False, got {self.balance!r}")
        check_balancing(self.balance_every, self.balance_until, self.balance_ratio,
                        self.balance_factor)
        object.__setattr__(self, "balance", bool(self.balance))
        object.__setattr__(self, "balance_every", int(self.balance_every))
        for name in ("balance_until", "balance_ratio", "balance_factor"):
            object.__setattr__(self, name, float(getattr(self, name)))

    def initial(self, default: tuple[float, float, float] = DEFAULT_MU
                ) -> tuple[float, float, float]:
        """The initial penalties: ``mu``, or ``default`` when ``mu`` is None."""
        return default if self.mu is None else self.mu

    def last_balance(self, iterations: int) -> int:
        """The iteration before which balancing runs in a solve of ``iterations``
        (0 when balancing is off)."""
        return int(self.balance_until * iterations) if self.balance else 0

    def mode(self, k: int, last_balance: int) -> int:
        """:func:`balance_mode` of iteration ``k`` with these settings."""
        return balance_mode(k, self.balance_every, last_balance)

    def balanced(self, mu_i: float, r2: float, s2: float, n2: float, d2: float) -> float:
        """:func:`balanced_penalty` with this ratio and factor."""
        return balanced_penalty(mu_i, r2, s2, n2, d2, self.balance_ratio, self.balance_factor)

    def rebalanced(self, mu: tuple[float, float, float], terms, ratio: float,
                   tie: bool) -> tuple[float, float, float]:
        """All three penalties after one balancing step (:meth:`balanced` per split).

        Parameters
        ----------
        mu : (mu1, mu2, mu3)
            Current penalties.
        terms : ((r2, s2, n2, d2) of v, of u or None, of w)
            The balancing sums per split (:class:`recon.solvers.admm_loop.SplitStep`);
            None for u without a u split (mu2 stays).
        ratio : float
            mu3 / mu1 at the start of the solve.
        tie : bool
            mu3 follows mu1 at ``ratio`` (:func:`tie_nonneg_penalty`) instead of being
            balanced.

        Returns
        -------
        (mu1, mu2, mu3)
        """
        new = [self.balanced(mu[0], *terms[0]),
               mu[1] if terms[1] is None else self.balanced(mu[1], *terms[1]),
               self.balanced(mu[2], *terms[2])]
        tie_nonneg_penalty(new, ratio, not tie)
        return tuple(new)


def check_penalty_settings(penalty) -> AdmmPenalty:
    """``penalty`` as an :class:`AdmmPenalty`: None gives the defaults.

    Raises
    ------
    ReconInputError
        Anything else than None or an :class:`AdmmPenalty` (e.g. the former keyword
        arguments as a dict: pass ``AdmmPenalty(**settings)``).
    """
    if penalty is None:
        return AdmmPenalty()
    if not isinstance(penalty, AdmmPenalty):
        raise ReconInputError(
            f"penalty must be an AdmmPenalty (recon.solvers.AdmmPenalty(mu=..., balance=...)), "
            f"got {type(penalty).__name__}")
    return penalty


def admm_result(x, history, objective: float, relative: float, *, tv: float, l1: float,
                mus: list, penalty: AdmmPenalty, iterations: int, used: int,
                nonneg: bool | None = None, **extra):
    """The :class:`~recon.solvers.common.SolveResult` every ADMM returns (2D and 3D,
    NumPy and generic path): the penalties' course in ``history.extra["mu"]`` and the
    parameters they all report.

    Parameters
    ----------
    x : array, float32
        The estimate (on the solve's device).
    history : SolveHistory
        The monitor's history (its ``extra["mu"]`` is set here).
    objective, relative : float
        Final objective and relative data residual.
    tv, l1 : float
        The weights solved with.
    mus : list of (mu1, mu2, mu3)
        The penalties at the start and after each change (the last: the final ones).
    penalty : AdmmPenalty
        Its ``balance`` is reported.
    iterations, used : int
        Iterations asked for and run (automatic stopping ends earlier).
    nonneg : bool, optional
        Reported after ``l1`` when given (every ADMM gives it).
    **extra
        Further parameters, reported last (``ffts_per_iteration``, ``backend``).

    Returns
    -------
    SolveResult
    """
    from .common import SolveResult

    history.extra["mu"] = [list(m) for m in mus]
    params = {"tv": tv, "l1": l1, **({} if nonneg is None else {"nonneg": nonneg}),
              "mu_initial": list(mus[0]), "mu_final": list(mus[-1]),
              "balance": penalty.balance, "iterations": iterations,
              "iterations_used": used, **extra}
    return SolveResult(x, history, objective, relative, params)

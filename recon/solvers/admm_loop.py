"""The ADMM loop shared by every ADMM of the project (2D, 3D, PSF grids; any backend).

One loop (:func:`admm_loop`, driven by :func:`run_admm`) solves

    min_x  f(v) + sum_i g_i(u_i)   s.t.  v = M x,  u_i = G_i x

in the scaled-dual form of Boyd et al. 2011 (Sec. 3.1.1) with the DiffuserCam split of
Kuo 2020 (Eq. 4.5, App. A.3; Antipa et al. 2018): v = M x the crop/data split with
penalty mu1, u = Psi x the regulariser's split (TV today) with mu2, w = x the
non-negativity (and l1) split with mu3. It owns what every ADMM shares: the
residual-balancing schedule and rule (:class:`~recon.solvers.penalty.AdmmPenalty`,
Boyd et al. 2011 Sec. 3.4.1 with Wohlberg 2017's normalised residuals, and for the 2D
models mu3 tied to mu1 without a u split,
:func:`~recon.solvers.penalty.tie_nonneg_penalty`), the
objective and history of each iterate, the divergence check
(:class:`~recon.solvers.common.Monitor`), the stopping rule (``stop(history)`` after
every iteration) and the result (``recon.solvers.penalty.admm_result``).

What differs between models and backends is a *kernel set*
(:class:`AdmmKernels`), made by the plan for one solve (``plan.kernels(...)``):
fused numba passes on NumPy arrays (:mod:`recon.solvers.admm`,
:mod:`recon.volume.admm`), whole-array operations on any array-API backend
(``recon.solvers.xp_admm``, shared by the 2D and 3D generic plans). Its
:meth:`AdmmKernels.splits` is the seam for the priors: every split-variable update --
the proximal step z_i = prox_{g_i / mu_i}(G_i x + a_i) of each g_i and its dual
update -- happens there and nowhere else, and the loop sees only their results (the
objective's terms and the balancing sums per penalty). The image's u-update is TV soft
thresholding today; another prior replaces that step (and, where its G_u differs, the
x-update's G_u^T terms) inside a kernel set, and keeps this loop, its stopping rule
and its penalty balancing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple, Protocol

from ..errors import ReconInputError
from .common import DEFAULT_ITERATIONS, History, Monitor, SolveResult
from .penalty import AdmmPenalty, admm_result, check_penalty_settings

__all__ = ["DEFAULT_ITERATIONS", "AdmmKernels", "AdmmPlanBase", "SplitStep", "admm_loop",
           "run_admm"]

# The ADMM entry points (:func:`recon.solvers.admm`, :func:`recon.volume.admm3d`,
# :func:`recon.spatial.spatial_admm`) default to :data:`recon.solvers.common.DEFAULT_ITERATIONS`
# (the declared one, re-exported here); their TV and l1 weights default to 0 and their
# penalties to ``AdmmPenalty()`` (:data:`~recon.solvers.penalty.DEFAULT_MU`, balanced).


class SplitStep(NamedTuple):
    """What one pass of split updates reports to the loop.

    Attributes
    ----------
    data_sq : float
        ``||D M x - b||^2`` of the iterate entering the iteration.
    terms : tuple of float
        The objective's other terms at that iterate, weighted (``tv TV(x)``,
        ``l1 ||x_+||_1``: the l1 norm of the estimate the iterate gives, its
        non-negative part with non-negativity); the history's objective is
        ``0.5 data_sq + sum(terms)``, added in this order.
    balance : tuple or None
        In a balancing iteration (mode 2): per penalty (mu1 v, mu2 u, mu3 w) the sums
        ``(r2, s2, n2, d2)`` of :func:`~recon.solvers.penalty.balanced_penalty`, None
        for the u entry without a u split; None otherwise.
    """

    data_sq: float
    terms: tuple
    balance: tuple | None = None


class AdmmKernels(Protocol):
    """One solve's backend passes, made by ``plan.kernels(b, state, ...)``.

    Attributes
    ----------
    state
        The plan's state (``mu``, ``use_tv``, the iterate and the q's of every split),
        updated in place by the passes.
    b : array, float32
        The validated measurement (the plan's backend).
    monitor : Monitor
        History and divergence check (on a device an
        ``recon.solvers.xp_common.XpMonitor``).
    report : dict
        Extra parameters of the result (``ffts_per_iteration``; ``backend`` on the
        generic path).
    """

    state: object
    b: object
    monitor: Monitor
    report: dict

    def splits(self, mode: int) -> SplitStep:
        """Every split's update in q-form (q_i = z_i - a_i): a_i = G_i x - q_i,
        z_i = prox_i(G_i x + a_i), q_i = z_i - a_i, at the state's penalties. ``mode``
        (:func:`~recon.solvers.penalty.balance_mode`): 0 plain, 1 also store the
        scaled duals a_i, 2 also return the balancing sums."""

    def set_penalties(self, old: tuple, new: tuple) -> None:
        """Adopt penalties ``new`` (in ``state.mu``), the q's rescaled so the duals
        y_i = mu_i a_i stay (:func:`~recon.solvers.penalty.rescale_duals`)."""

    def end_balancing(self) -> None:
        """Balancing is over for this solve: the stored duals may be released."""

    def x_update(self) -> None:
        """The x-update from the state's q's and penalties (x and M x replaced)."""

    def iterate(self):
        """The current iterate x (what the monitor keeps as the last good estimate)."""

    def estimate(self):
        """The estimate of the current iterate: x with its non-negativity applied."""


def admm_loop(kernels: AdmmKernels, *, iterations: int, penalty: AdmmPenalty,
              stop: Callable[[History], bool] | None = None, hint: str = "",
              tie: bool = False) -> tuple[int, list[tuple[float, float, float]]]:
    """Run ADMM iterations with ``kernels`` (their state updated in place).

    Iteration k::

        mode = penalty.mode(k)                  # balancing schedule
        step = kernels.splits(mode)             # z- and dual updates of every split
        if mode == 2: mu <- balanced(mu)        # Boyd et al. 2011, Sec. 3.4.1
        kernels.x_update()                      # x = argmin of the augmented Lagrangian
        record 0.5 step.data_sq + sum(step.terms), then ask stop(history)

    Residual balancing runs over the first ``penalty.balance_until`` of these
    iterations; with ``tie`` mu3 keeps its starting ratio to mu1
    (:func:`~recon.solvers.penalty.tie_nonneg_penalty`).

    Parameters
    ----------
    kernels : AdmmKernels
    iterations : int
        Maximum number of iterations (>= 1, validated by the caller).
    penalty : AdmmPenalty
        Balancing settings; the state carries the current penalties.
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration (automatic stopping,
        :class:`recon.auto.weight.Stopping`).
    hint : str
        Appended to a divergence error's message.
    tie : bool
        Tie mu3 to mu1 instead of balancing it (:func:`run_admm` asks for it without a
        u split where the plan's ``tie_nonneg`` says so: the 2D models).

    Returns
    -------
    used : int
        Iterations run (< ``iterations`` when ``stop`` ended the loop).
    mus : list of (mu1, mu2, mu3)
        The penalties at the start and after each change.

    Raises
    ------
    DivergenceError
        From the monitor: NaN/inf or an objective 100x that of the zero estimate.
    """
    state, monitor = kernels.state, kernels.monitor
    mu = tuple(state.mu)
    mus = [mu]
    ratio = mu[2] / mu[0]  # kept with tie (tie_nonneg_penalty)
    last_balance = penalty.last_balance(iterations)
    for k in range(iterations):
        monitor.start()
        if k == last_balance and k > 0:
            kernels.end_balancing()
        mode = penalty.mode(k, last_balance)
        step = kernels.splits(mode)
        if mode == 2:
            new = penalty.rebalanced(mu, step.balance, ratio, tie)
            if new != mu:
                kernels.set_penalties(mu, new)
                mu = new
                mus.append(mu)
        objective = 0.5 * step.data_sq
        for term in step.terms:  # of the iterate entering this iteration
            objective += term
        kernels.x_update()
        monitor.record(objective, step.data_sq, x=kernels.iterate(), hint=hint)
        if stop is not None and stop(monitor.history):
            return k + 1, mus
    return iterations, mus


def run_admm(plan, b, state, *, iterations: int, tv: float, l1: float = 0.0,
             nonneg: bool = True, penalty: AdmmPenalty | None = None, stop=None,
             final: bool = True) -> SolveResult:
    """Run ``iterations`` ADMM iterations of ``plan`` from ``state`` (updated in place).

    The one ADMM solve: :func:`recon.solvers.admm`, :func:`recon.volume.admm3d` and
    :func:`recon.spatial.spatial_admm` validate their parameters and call this from a
    cold state; the live view (:mod:`recon.live`) and the automatic weight
    (:func:`recon.auto.weight.admm_auto`) continue a warm one.

    Parameters
    ----------
    plan
        An ADMM plan: :class:`recon.solvers.admm.AdmmPlan` (and
        :class:`recon.spatial.SpatialAdmmPlan`), :class:`recon.volume.VolumeAdmmPlan`,
        or their generic forms ``recon.solvers.xp_admm.XpAdmmPlan``,
        ``recon.volume.xp_admm3d.XpVolumeAdmmPlan``; its ``kernels(b, state,
        tv=, l1=, nonneg=, balancing=)`` makes the kernel set.
    b : array, float32, ``plan.op.shape_out``
        Scaled, weighted measurement on the plan's backend (checked there).
    state
        The plan's state (``plan.zeros`` or ``plan.warm``), with its penalties;
        ``state.use_tv`` must equal ``tv > 0``. On return the last iterate (x before
        the non-negativity clip).
    iterations : int
    tv, l1 : float
        Weights (validated, >= 0).
    nonneg : bool
        Keep x >= 0 (the w split); False needs a ``signed`` plan (the volume's).
    penalty : AdmmPenalty, optional
        Residual balancing (default ``AdmmPenalty()``) over the first
        ``balance_until`` of this call's iterations; its ``mu`` is not used here.
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration; ``iterations`` stays the
        maximum.
    final : bool
        Evaluate the estimate's objective and residual (one forward model); False,
        for a caller that runs the solve in pieces, reports the last iteration's from
        the history (those of the iterate entering it).

    Returns
    -------
    SolveResult
        ``x`` the estimate (max(x, 0) with ``nonneg``) on the plan's backend;
        ``history.objective[k]`` = 1/2 ||D M x_k - b||^2 + tv TV(x_k) + l1 ||x_k+||_1
        for the iterate entering iteration k; ``history.extra['mu']`` the penalties'
        course; ``params`` tv, l1, nonneg, mu_initial, mu_final, balance, iterations
        (the maximum), iterations_used, ffts_per_iteration (and backend on the generic
        path).

    Raises
    ------
    DivergenceError
        NaN/inf or an objective 100x that of the zero estimate.
    ReconInputError
        A misshapen, non-finite or all-zero ``b``, a state made for the other sign of
        ``tv``, ``penalty`` not an :class:`AdmmPenalty`, or ``nonneg`` False on a plan
        that is not ``signed`` (2D).
    """
    penalty = check_penalty_settings(penalty)
    if not nonneg and not plan.signed:
        raise ReconInputError(f"{plan.label} keeps x >= 0 (its w split); use fista with "
                              "nonneg=False for a signed estimate")
    if state.use_tv != (tv > 0):
        raise ReconInputError(f"ADMM state was made for tv {'> 0' if state.use_tv else '= 0'}"
                              f" but tv={tv}; start from the plan's zeros(mu, tv > 0)")
    kernels = plan.kernels(b, state, tv=tv, l1=l1, nonneg=nonneg,
                           balancing=penalty.last_balance(iterations) > 0)
    used, mus = admm_loop(kernels, iterations=iterations, penalty=penalty, stop=stop,
                          hint=plan.hint, tie=plan.tie_nonneg and not state.use_tv)
    history = kernels.monitor.history
    x = kernels.estimate()
    if final:
        objective, relative = plan.objective(kernels.b, x, tv=tv, l1=l1,
                                             b_norm=kernels.monitor.b_norm)
    else:
        objective, relative = history.objective[-1], history.data_residual[-1]
    return admm_result(x, history, objective, relative, tv=tv, l1=l1, mus=mus,
                       penalty=penalty, iterations=iterations, used=used, nonneg=nonneg,
                       **kernels.report)


class AdmmPlanBase:
    """What every ADMM plan shares: :meth:`run` through :func:`run_admm`.

    A plan subclass has ``op``, ``label`` (the solver's name in errors), ``hint``
    (the divergence error's advice), ``signed``, ``tie_nonneg``, ``zeros(mu, use_tv)``,
    ``warm(x, mu, use_tv)``, ``objective(b, x, tv=, l1=, b_norm=)`` and ``kernels(b,
    state, tv=, l1=, nonneg=, balancing=)``: the interface of the automatic weight
    (:func:`recon.auto.weight.admm_auto`) and of the loop.
    """

    label = "ADMM"
    hint = ""
    #: Whether the w split may drop x >= 0 (``nonneg=False``): the volume's plans.
    signed = False
    #: Without a u split, tie mu3 to mu1
    #: (:func:`~recon.solvers.penalty.tie_nonneg_penalty`): measured for the 2D models;
    #: the volume's plan does not.
    tie_nonneg = True

    def run(self, b, state, *, iterations: int, tv: float, l1: float = 0.0,
            final: bool = True, **options) -> SolveResult:
        """:func:`run_admm` of this plan from ``state`` (updated in place);
        ``options``: ``nonneg``, ``penalty``, ``stop``."""
        return run_admm(self, b, state, iterations=iterations, tv=tv, l1=l1, final=final,
                        **options)

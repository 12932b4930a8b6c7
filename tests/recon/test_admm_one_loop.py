"""Every ADMM -- 2D and 3D, NumPy (numba kernels) and array API -- runs the one loop of
:mod:`recon.solvers.admm_loop`: the same stopping rule ends them at the same iteration,
the same balancing step moves their penalties, their objectives count the same terms,
their results carry the same keys, and their defaults come from one place.

The generic path runs here under ``array-api-strict`` (the standard and nothing more).
"""

from __future__ import annotations

import copy
import importlib
import inspect

import numpy as np
import pytest

from recon.solvers import AdmmPenalty, admm
from recon.solvers.admm import AdmmPlan, NumbaKernels2D
from recon.solvers.admm_loop import DEFAULT_ITERATIONS, run_admm
from recon.solvers.penalty import DEFAULT_MU
from recon.solvers.xp_admm import XpAdmmPlan, XpKernels
from recon.spatial import spatial_admm
from recon.volume import VolumeAdmmPlan, admm3d, volume_tv
from recon.volume.admm import NumbaKernels3D
from recon.volume.xp_admm3d import XpVolumeAdmmPlan

from .test_backends import _problem_2d, _problem_3d

xps = pytest.importorskip("array_api_strict")
loop_mod = importlib.import_module("recon.solvers.admm_loop")

#: Relative agreement of the generic path with the numba one (float32 rounding).
TOL = 1e-4


PATHS = {  # name: (solver, problem, measurement on the backend, kernel set)
    "2d-numpy": (admm, _problem_2d, lambda b: b, NumbaKernels2D),
    "2d-array-api": (admm, _problem_2d, xps.asarray, XpKernels),
    "3d-numpy": (admm3d, _problem_3d, lambda b: b, NumbaKernels3D),
    "3d-array-api": (admm3d, _problem_3d, xps.asarray, XpKernels),
}


def _host(x):
    return x if isinstance(x, np.ndarray) else np.asarray(x)


@pytest.fixture
def spy(monkeypatch):
    """Records the kernel set of every run of the one loop and every balancing step."""
    seen = {"kernels": [], "rebalanced": 0}
    real_loop, real_rebalanced = loop_mod.admm_loop, AdmmPenalty.rebalanced

    def loop(kernels, **kwargs):
        seen["kernels"].append(type(kernels))
        return real_loop(kernels, **kwargs)

    def rebalanced(self, *args):
        seen["rebalanced"] += 1
        return real_rebalanced(self, *args)

    monkeypatch.setattr(loop_mod, "admm_loop", loop)
    monkeypatch.setattr(AdmmPenalty, "rebalanced", rebalanced)
    return seen


@pytest.mark.parametrize("path", sorted(PATHS))
def test_the_same_stop_rule_ends_every_admm_at_the_same_iteration(path, spy):
    solver, problem, put, kernels = PATHS[path]
    op, b = problem()
    calls = []

    def stop(history):
        calls.append(len(history.objective))
        return len(history.objective) >= 7

    res = solver(op, put(b), iterations=50, tv=1e-3, stop=stop)
    assert spy["kernels"] == [kernels]  # the one loop, with this backend's kernel set
    assert calls == list(range(1, 8))  # asked after every iteration, then stopped
    assert res.params["iterations"] == 50 and res.params["iterations_used"] == 7
    assert len(res.history.objective) == 7
    assert spy["rebalanced"] >= 1  # the loop's balancing step ran (iteration 5)


@pytest.mark.parametrize("dim", ["2d", "3d"])
@pytest.mark.parametrize("tv,l1", [(1e-3, 0.0), (0.0, 1e-3)])
def test_both_backends_balance_alike(dim, tv, l1, spy):
    """The penalties' course is the same on both backends (the loop's rule on the
    kernels' sums); without TV the 2D plans tie mu3 to mu1 and the volume's does not
    (its measured choice, recon.solvers.penalty.tie_nonneg_penalty)."""
    solver, problem, _, _ = PATHS[f"{dim}-numpy"]
    op, b = problem()
    ref = solver(op, b, iterations=40, tv=tv, l1=l1)
    got = solver(op, xps.asarray(b), iterations=40, tv=tv, l1=l1)
    mus = ref.history.extra["mu"]
    assert got.history.extra["mu"] == mus and len(mus) > 1  # balanced, the same way
    assert spy["rebalanced"] >= 2 * 4  # 40 iterations: 4 balancing steps per solve
    ratios = {m[2] / m[0] for m in mus}
    if tv == 0:
        assert (len(ratios) == 1) == (dim == "2d")
    assert np.abs(_host(got.x) - ref.x).max() <= TOL * np.abs(ref.x).max()
    assert got.history.objective == pytest.approx(ref.history.objective, rel=TOL)


@pytest.mark.parametrize("path", sorted(PATHS))
@pytest.mark.parametrize("nonneg", [True, False])
def test_the_history_counts_the_same_terms(path, nonneg):
    """history.objective[k] is 1/2 ||A x_k - b||^2 + tv TV(x_k) + l1 ||x_k+||_1 of the
    iterate entering iteration k, x_k+ its non-negative part with non-negativity (the
    estimate it gives), x_k itself without; the same formula on every path."""
    solver, problem, put, _ = PATHS[path]
    op, b = problem()
    volume = solver is admm3d
    if not volume and not nonneg:
        pytest.skip("the 2D ADMM is non-negative")
    base = VolumeAdmmPlan.of(op) if volume else AdmmPlan.of(op)
    plan = base if put(b) is b else (XpVolumeAdmmPlan if volume else XpAdmmPlan)(base, put(b))
    tv, l1 = 1e-3, 3e-2
    state = plan.zeros(DEFAULT_MU, True)
    options = {"nonneg": nonneg} if volume else {}
    run_admm(plan, put(b), state, iterations=6, tv=tv, l1=l1, **options)
    x = _host(state.x).copy()  # x_6, before any clip
    assert x.min() < 0  # the two rules differ here
    without = copy.deepcopy(state)
    nxt = run_admm(plan, put(b), state, iterations=1, tv=tv, l1=l1, **options)
    base = run_admm(plan, put(b), without, iterations=1, tv=tv, l1=0.0, **options)
    r = op.forward(x) - b
    tv_x = volume_tv(x) if volume else sum(float(np.abs(np.roll(x, -1, axis=a) - x).sum())
                                            for a in (0, 1))
    assert base.history.objective[0] == pytest.approx(0.5 * float(np.vdot(r, r)) + tv * tv_x,
                                                      rel=1e-5)
    # the l1 term alone: the same iterate with and without it
    l1_term = (nxt.history.objective[0] - base.history.objective[0]) / l1
    want, other = np.maximum(x, 0).sum(), np.abs(x).sum()
    if not nonneg:
        want, other = other, want
    assert abs(want - other) > 1e-4 * want
    assert l1_term == pytest.approx(float(want), rel=2e-5)


def test_every_admm_reports_the_same_keys():
    keys = set()
    for path, (solver, problem, put, _) in PATHS.items():
        op, b = problem()
        res = solver(op, put(b), iterations=3, tv=1e-3)
        own = set(res.params) - {"backend"}
        assert not keys or own == keys, path
        keys = own
        assert set(res.history.extra) == {"mu"}
        assert res.params["nonneg"] is True
        assert ("backend" in res.params) == path.endswith("array-api")
    assert {"tv", "l1", "nonneg", "mu_initial", "mu_final", "balance", "iterations",
            "iterations_used", "ffts_per_iteration"} == keys


def test_the_defaults_come_from_one_place():
    """Iterations, weights and penalties: the entry points' signature defaults are the
    loop's, and a cold solve starts at DEFAULT_MU on every path."""
    for solver in (admm, admm3d, spatial_admm):
        params = inspect.signature(solver).parameters
        assert params["iterations"].default == DEFAULT_ITERATIONS
        assert params["tv"].default == 0.0 and params["l1"].default == 0.0
        if "penalty" in params:
            assert params["penalty"].default is None
    assert AdmmPenalty().initial() == DEFAULT_MU
    for solver, problem, put, _ in PATHS.values():
        op, b = problem()
        assert solver(op, put(b), iterations=1).params["mu_initial"] == list(DEFAULT_MU)

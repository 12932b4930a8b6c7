"""Tests for recon.volume.admm: 3D ADMM (Eq. 4.5, App. A.3) on the small synthetic
volume problem of test_fista.py (caustic-like PSFs magnified per depth, 5 planes,
64 x 64 sensor, 7 beads), plus exactness checks of the per-frequency x-update.

"Right plane" is measured as in test_fista: for each bead, the plane holding the
maximum of the 3 x 3 lateral neighbourhood of its true position.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.fft as sfft

from recon.errors import DivergenceError, ReconInputError
from recon.operators import ConvolutionOperator
from recon.solvers import AdmmPenalty
from recon.solvers.admm import difference_power
from recon.volume import VolumeConvolutionOperator, admm3d, fista3d, normalize_psf_stack
from recon.volume.admm import solve_x_update

from .test_fista import BEADS, _bead_planes, bead_problem, caustic_stack  # noqa: F401

TRUTH_PLANES = [z for z, _, _ in BEADS]


@pytest.fixture(scope="module")
def clean_problem():
    op = VolumeConvolutionOperator(caustic_stack())
    truth = np.zeros(op.shape_in, np.float32)
    for z, i, j in BEADS:
        truth[z, i, j] = 1.0
    b = op.forward(truth)
    return op, (b / b.max()).astype(np.float32)


# --------------------------------------------------------------------------- x-update


def _depth_laplacian(nz):
    lap = np.zeros((nz, nz))
    for k in range(nz - 1):  # D^T D of the non-wrapping forward differences
        lap[k, k] += 1
        lap[k + 1, k + 1] += 1
        lap[k, k + 1] = lap[k + 1, k] = -1
    return lap


@pytest.mark.parametrize("nz", [1, 2, 5])
@pytest.mark.parametrize("mu,use_tv", [((0.7, 0.3, 0.05), True), ((1e-6, 1e3, 1e-6), True),
                                       ((1e4, 1e-6, 1e4), True), ((0.5, 9.0, 0.2), False)])
def test_x_update_matches_dense_solve(nz, mu, use_tv):
    """Thomas + Sherman-Morrison equals np.linalg.solve of the n_z x n_z system."""
    rng = np.random.default_rng(nz)
    f0, f1 = 4, 3
    h = (rng.standard_normal((nz, f0, f1)) + 1j * rng.standard_normal((nz, f0, f1)))
    h = h.astype(np.complex64)
    d_lat = (4 * rng.random((f0, f1))).astype(np.float32)
    d_lat[0, 0] = 0.0  # DC: B is mu2 L_z + mu3 I, nearly singular for mu3 << mu2
    spec = (rng.standard_normal((nz + 1, f0, f1))
            + 1j * rng.standard_normal((nz + 1, f0, f1))).astype(np.complex64)
    mu1, mu2, mu3 = mu
    ref = np.empty(spec.shape, np.complex128)
    for i in range(f0):
        for j in range(f1):
            hv = h[:, i, j].astype(np.complex128)
            a = mu1 * np.outer(hv.conj(), hv) + mu3 * np.eye(nz)
            if use_tv:
                a += mu2 * (_depth_laplacian(nz) + d_lat[i, j] * np.eye(nz))
            x = np.linalg.solve(a, spec[:nz, i, j] + mu1 * hv.conj() * spec[nz, i, j])
            ref[:nz, i, j] = x
            ref[nz, i, j] = hv @ x
    out = solve_x_update(spec.copy(), h, d_lat, mu, use_tv)
    for k in range(nz + 1):  # relative to each plane's scale (1/mu3 modes can dominate)
        np.testing.assert_allclose(out[k], ref[k], rtol=0,
                                   atol=2e-5 * float(np.abs(ref[k]).max()) + 1e-30)


def test_x_update_minimises_the_augmented_lagrangian():
    """In real space, x = argmin mu1/2 ||M x - q_v||^2 + mu2/2 ||Psi x - q_u||^2 +
    mu3/2 ||x - q_w||^2: its gradient vanishes (checks the rfft half-spectrum
    handling and the Psi^T of the TV splits)."""
    rng = np.random.default_rng(5)
    op = VolumeConvolutionOperator(normalize_psf_stack(rng.random((3, 6, 7)))[0])
    nz, shape = op.n_z, op.padded_shape
    mu1, mu2, mu3 = 0.8, 0.3, 0.1
    qv = rng.standard_normal(shape).astype(np.float32)
    qw = rng.standard_normal(op.shape_in).astype(np.float32)
    qu = [rng.standard_normal(op.shape_in).astype(np.float32) for _ in range(3)]  # z, y, x
    qu[0][-1] = 0.0  # the last plane has no depth difference

    def psi(x):
        dz = np.zeros_like(x)
        dz[:-1] = x[1:] - x[:-1]
        return [dz, np.roll(x, -1, axis=1) - x, np.roll(x, -1, axis=2) - x]

    def psi_t(u):
        dz = np.zeros_like(u[0])
        dz[1:] += u[0][:-1]
        dz -= u[0]
        return dz + (np.roll(u[1], 1, axis=1) - u[1]) + (np.roll(u[2], 1, axis=2) - u[2])

    stack = np.empty((nz + 1, *shape), np.float32)
    stack[:nz] = mu2 * psi_t(qu) + mu3 * qw
    stack[nz] = qv
    spec = sfft.rfftn(stack, axes=(-2, -1))
    solve_x_update(spec, op.spectra, difference_power(shape), (mu1, mu2, mu3), True)
    out = sfft.irfftn(spec, s=shape, axes=(-2, -1))
    x = out[:nz].astype(np.float64)
    m = lambda v: sfft.irfftn(op.sum_spectrum(v.astype(np.float32)), s=shape)  # noqa: E731
    np.testing.assert_allclose(out[nz], m(x), atol=1e-4 * np.abs(out[nz]).max())
    mt = op.backproject(sfft.rfftn((m(x) - qv).astype(np.float32)),
                        np.empty(op.shape_in, np.float32))
    grad = mu1 * mt + mu2 * psi_t([p - q for p, q in zip(psi(x), qu, strict=True)]) \
        + mu3 * (x - qw)
    assert np.abs(grad).max() < 1e-5 * np.abs(stack).max()  # float32 solve


# --------------------------------------------------------------------------- solver


@pytest.mark.parametrize("kwargs", [{}, {"l1": 1e-3}, {"tv": 1e-4}, {"tv": 1e-4, "l1": 1e-3}],
                         ids=["plain", "l1", "tv", "tv+l1"])
def test_beads_at_their_planes_and_fista_agrees(bead_problem, kwargs):  # noqa: F811
    op, b, lip = bead_problem
    res = admm3d(op, b, iterations=150, **kwargs)
    assert res.x.dtype == np.float32 and res.x.shape == op.shape_in
    assert res.x.min() >= 0
    planes = _bead_planes(res.x)
    assert all(abs(p - t) <= 1 for p, t in zip(planes, TRUTH_PLANES, strict=True)), planes
    assert sum(p == t for p, t in zip(planes, TRUTH_PLANES, strict=True)) >= len(BEADS) - 1
    # the 7 brightest voxels sit at (or next to) the beads
    top = np.argsort(res.x.ravel())[::-1][:len(BEADS)]
    for z, i, j in zip(*np.unravel_index(top, res.x.shape), strict=True):
        assert any(abs(z - bz) <= 1 and abs(i - bi) <= 1 and abs(j - bj) <= 1
                   for bz, bi, bj in BEADS)
    assert res.final_relative_residual < 0.2  # the noise alone is 0.10 of ||b||
    fista = fista3d(op, b, iterations=150, lipschitz=lip, **kwargs)
    assert _bead_planes(fista.x) == planes  # all 7 exact for both when written


def test_objective_decreases(bead_problem):  # noqa: F811
    op, b, _ = bead_problem
    res = admm3d(op, b, iterations=80, tv=1e-3, l1=1e-2)
    obj = np.array(res.history.objective)
    assert len(obj) == 80 == len(res.history.seconds) == len(res.history.data_residual)
    assert obj[-1] < 0.25 * obj[0]  # 0.20 seen (strong weights on purpose)
    # ADMM is not monotone, but the trend is: each 10-iteration block beats the first
    blocks = obj.reshape(8, 10).min(axis=1)
    assert np.all(blocks[1:] < blocks[0]) and blocks[-1] <= blocks[2]
    assert res.final_objective <= 1.05 * obj[-1]
    assert res.params["ffts_per_iteration"] == {"rfft2": op.n_z + 1, "irfft2": op.n_z + 1}
    sparse = admm3d(op, b, iterations=80, l1=0.3)
    assert np.count_nonzero(sparse.x) < np.count_nonzero(res.x)


@pytest.mark.parametrize("mu", [(1e-6, 1e3, 1e-6), (1e4, 1e-6, 1e4)])
def test_balancing_rescues_bad_penalties(clean_problem, mu):
    op, b = clean_problem
    zero = 0.5 * float(np.vdot(b, b))
    good = admm3d(op, b, iterations=300, tv=1e-4, penalty=AdmmPenalty(mu=mu, balance=True))
    bad = admm3d(op, b, iterations=300, tv=1e-4, penalty=AdmmPenalty(mu=mu, balance=False))
    # balanced: residual 0.034 / 0.079, objective 0.008 / 0.012 x zero when written;
    # fixed: 0.91 / 0.995 and 0.83 / 0.99
    assert good.final_relative_residual < 0.15
    assert good.final_objective < 0.03 * zero
    assert bad.final_relative_residual > 0.8
    assert bad.final_objective > 10.0 * good.final_objective
    assert _bead_planes(good.x) == TRUTH_PLANES
    assert good.params["mu_initial"] == list(mu)
    # the data-split and TV-split penalties moved at least 100x away from their bad
    # start, in the right direction (the TV one may overshoot past O(1): the TV
    # weight is small, so its split's natural scale is too)
    for f, m in zip(good.params["mu_final"][:2], mu[:2], strict=True):
        assert math.log10(f / m) * -math.copysign(1.0, math.log10(m)) >= 2.0
    assert all(1e-5 / 2 <= f <= 1e2 * 2 for f in good.params["mu_final"])
    assert len(good.history.extra["mu"]) > 1
    assert bad.history.extra["mu"] == [list(mu)] and bad.params["mu_final"] == list(mu)


def test_without_nonneg_goes_negative(bead_problem):  # noqa: F811
    op, b, _ = bead_problem
    assert admm3d(op, b, iterations=20, nonneg=False).x.min() < 0


def test_huge_weights_are_caught_or_kept_finite(bead_problem):  # noqa: F811
    op, b, _ = bead_problem
    try:
        res = admm3d(op, b, iterations=10,
                     penalty=AdmmPenalty(mu=(1e30, 1e30, 1e30), balance=False))
    except DivergenceError as err:
        assert "3D ADMM" in str(err)
    else:
        assert np.all(np.isfinite(res.x))


@pytest.mark.parametrize("kwargs,fragment", [
    ({"iterations": 0}, "iterations"), ({"iterations": 2.5}, "iterations"),
    ({"tv": -1.0}, "TV"), ({"l1": float("nan")}, "l1"),
    ({"mu": (0.5, 0.0, 0.5)}, "penalties"), ({"mu": (0.5, 1.0, -0.5)}, "penalties"),
    ({"mu": (np.inf, 1.0, 0.5)}, "penalties"), ({"mu": (1.0, 2.0)}, "three"),
    ({"balance_every": 1}, "balance_every"), ({"balance_factor": 1.0}, "balance"),
])
def test_invalid_parameters_are_refused(bead_problem, kwargs, fragment):  # noqa: F811
    op, b, _ = bead_problem
    settings = {k: kwargs.pop(k) for k in list(kwargs) if k == "mu" or k.startswith("balance")}
    with pytest.raises(ReconInputError, match=fragment):  # the penalty settings are
        penalty = AdmmPenalty(**settings) if settings else None  # checked when made
        admm3d(op, b, **({"iterations": 5} | kwargs), penalty=penalty)


def test_bad_operator_and_measurement_are_refused(bead_problem):  # noqa: F811
    op, b, _ = bead_problem
    with pytest.raises(ReconInputError, match="VolumeConvolutionOperator"):
        admm3d(ConvolutionOperator(op.psf_stack[0]), b, iterations=2)
    with pytest.raises(ReconInputError, match="shape"):
        admm3d(op, b[:-1], iterations=2)
    with pytest.raises(ReconInputError, match="zero"):
        admm3d(op, np.zeros_like(b), iterations=2)
    bad = b.copy()
    bad[3, 4] = np.nan
    with pytest.raises(ReconInputError, match="NaN"):
        admm3d(op, bad, iterations=2)


# ------------------------------------------------------------ plan, state, warm start


def test_run_in_pieces_equals_one_run(clean_problem):
    """Without balancing, 3D ADMM continued from its state (run_admm, what the
    automatic weight's path does) is the same iteration as one call of admm3d."""
    from recon.solvers.admm_loop import run_admm
    from recon.volume import VolumeAdmmPlan

    op, b = clean_problem
    whole = admm3d(op, b, iterations=12, tv=1e-4, penalty=AdmmPenalty(balance=False))
    plan = VolumeAdmmPlan.of(op)
    state = plan.zeros((2e-3, 2e-3, 2e-3), True)
    run_admm(plan, b, state, iterations=5, tv=1e-4, penalty=AdmmPenalty(balance=False))
    last = run_admm(plan, b, state, iterations=7, tv=1e-4, penalty=AdmmPenalty(balance=False))
    assert np.allclose(last.x, whole.x, rtol=1e-5, atol=1e-6 * float(whole.x.max()))
    assert last.history.objective[-1] == pytest.approx(whole.history.objective[-1], rel=1e-5)


def test_warm_start_carries_the_estimate(clean_problem):
    """A state warmed at a converged estimate starts where that estimate is (its M x and
    q's consistent with it): its first objective is that estimate's, far below the cold
    start's, and the plan's objective agrees with the solver's."""
    from recon.volume import VolumeAdmmPlan

    op, b = clean_problem
    ref = admm3d(op, b, iterations=80, tv=1e-4)
    plan = VolumeAdmmPlan.of(op)
    warm = plan.warm(ref.x, (2e-3, 2e-3, 2e-3), True)
    assert np.allclose(op.forward(ref.x), warm.mx[op.crop], atol=1e-5)
    cont = plan.run(b, warm, iterations=3, tv=1e-4)
    cold = plan.run(b, plan.zeros((2e-3, 2e-3, 2e-3), True), iterations=3, tv=1e-4)
    assert cont.history.objective[0] < 0.1 * cold.history.objective[0]
    objective, relative = plan.objective(b, ref.x, tv=1e-4, l1=0.0,
                                         b_norm=float(np.linalg.norm(b)))
    assert objective == pytest.approx(ref.final_objective, rel=1e-6)
    assert relative == pytest.approx(ref.final_relative_residual, rel=1e-6)
    with pytest.raises(ReconInputError, match="state was made for tv > 0"):
        plan.run(b, warm, iterations=1, tv=0.0)
    with pytest.raises(ReconInputError, match="VolumeConvolutionOperator"):
        VolumeAdmmPlan.of(ConvolutionOperator(np.ones((8, 8), np.float32)))

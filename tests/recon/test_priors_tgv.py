"""Isotropic TV and second-order TGV as priors of the ADMM's u split (recon.priors)."""

from __future__ import annotations

import numpy as np
import pytest

from recon.options import ReconOptions
from recon.priors import PRIORS, IsotropicTV, TgvPrior, TotalVariation, prior_of
from recon.priors import _kernels as k
from recon.solvers import admm


def _iso_reference(a, b, thr):
    """The group soft threshold pixel by pixel (the slow reference)."""
    za, zb = np.zeros_like(a), np.zeros_like(b)
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            n = float(np.hypot(a[i, j], b[i, j]))
            s = max(1.0 - thr / n, 0.0) if n > 0 else 0.0
            za[i, j], zb[i, j] = a[i, j] * s, b[i, j] * s
    return za, zb


def test_names_reach_the_solvers_and_the_options():
    assert {"tv-iso", "tgv"} <= set(PRIORS)
    assert isinstance(prior_of("tv-iso"), IsotropicTV)
    assert isinstance(prior_of("tgv"), TgvPrior)
    assert {"tv-iso", "tgv"} <= set(ReconOptions.spec("prior").choices)
    assert ReconOptions.from_text({"--method": "admm", "--prior": "tgv"}).prior == "tgv"


def test_isotropic_prox_is_the_group_soft_threshold():
    rng = np.random.default_rng(1)
    a, b = (rng.standard_normal((17, 23)).astype(np.float32) for _ in range(2))
    b[3, 4] = a[3, 4] = 0.0  # a zero gradient stays zero
    za, zb = IsotropicTV().prox(np, (a, b), 0.7, 1.0)  # the fused numba pass
    ra, rb = _iso_reference(a, b, 0.7)
    np.testing.assert_allclose(za, ra, atol=1e-6)
    np.testing.assert_allclose(zb, rb, atol=1e-6)
    # the whole-array path (another dtype, as another backend takes it) agrees
    generic = IsotropicTV().prox(np, (a.astype(np.float64), b.astype(np.float64)), 0.7, 1.0)
    np.testing.assert_allclose(generic[0], ra, atol=1e-6)
    np.testing.assert_allclose(generic[1], rb, atol=1e-6)
    # and it is rotation-invariant, unlike the anisotropic soft threshold
    c, s = np.cos(0.6), np.sin(0.6)
    ya, yb = IsotropicTV().prox(np, (c * a - s * b, s * a + c * b), 0.7, 1.0)
    np.testing.assert_allclose(ya, c * za - s * zb, atol=1e-5)
    ta, tb = TotalVariation().prox(np, (c * a - s * b, s * a + c * b), 0.7, 1.0)
    assert np.abs(ta - (c * za - s * zb)).max() > 0.1
    assert IsotropicTV().value(np, None, (a, b)) == pytest.approx(
        float(np.hypot(a, b).sum()), rel=1e-5)


def _K(x, w1, w2):
    """The TGV operator K(x, w) = (D+ x - w, E w) by the kernels' dual step (from zero
    duals, sigma 1, radii too large to project)."""
    p1, p2, q11, q22, q12 = (np.zeros_like(x) for _ in range(5))
    big = np.float32(1e30)
    k.tgv_dual_step(x.copy(), w1.copy(), w2.copy(), p1, p2, q11, q22, q12, np.float32(1.0),
                    big, big)
    return p1, p2, q11, q22, q12


def _KT(p1, p2, q11, q22, q12):
    """K^T(p, q) by the kernels' primal step from x = w = 0, t = 0, tau 1: x_new =
    -D+^T p / 2, w_new = p - E^T q."""
    x, w1, w2, xb, w1b, w2b, t = (np.zeros_like(p1) for _ in range(7))
    k.tgv_primal_step(x, w1, w2, xb, w1b, w2b, p1, p2, q11, q22, q12, t, np.float32(1.0))
    return -2 * x, -w1, -w2


def test_tgv_operator_adjoint_and_step_bound():
    """<K u, v> = <u, K^T v> (the duals' inner product counts q12 twice, as the
    Frobenius norm of E w does) and ||K||^2 <= TGV_NORM_SQ, the steps' bound."""
    rng = np.random.default_rng(2)
    shape = (19, 26)
    u = [rng.standard_normal(shape).astype(np.float32) for _ in range(3)]
    v = [rng.standard_normal(shape).astype(np.float32) for _ in range(5)]
    ku, ktv = _K(*u), _KT(*v)
    lhs = sum(float((a * b).sum()) for a, b in zip(ku[:4], v[:4], strict=True))
    lhs += 2 * float((ku[4] * v[4]).sum())
    rhs = sum(float((a * b).sum()) for a, b in zip(u, ktv, strict=True))
    assert lhs == pytest.approx(rhs, rel=1e-4)
    z = u
    for _ in range(200):  # power iteration on K^T K
        z = _KT(*_K(*z))
        norm = float(np.sqrt(sum((a.astype(np.float64) ** 2).sum() for a in z)))
        z = [(a / norm).astype(np.float32) for a in z]
    assert 8.0 < norm <= k.TGV_NORM_SQ


def _tgv_objective(z, w1, w2, t, lam, ratio):
    """0.5 ||z - t||^2 + lam (||D+ z - w||_{2,1} + ratio ||E w||_{F,1}) in float64
    NumPy (the slow reference of the kernels' value)."""
    z, w1, w2 = (a.astype(np.float64) for a in (z, w1, w2))
    gx, gy = np.roll(z, -1, 1) - z - w1, np.roll(z, -1, 0) - z - w2
    e11, e22 = w1 - np.roll(w1, 1, 1), w2 - np.roll(w2, 1, 0)
    e12 = 0.5 * (w1 - np.roll(w1, 1, 0) + w2 - np.roll(w2, 1, 1))
    reg = np.hypot(gx, gy).sum() + ratio * np.sqrt(e11 ** 2 + e22 ** 2 + 2 * e12 ** 2).sum()
    return 0.5 * ((z - t) ** 2).sum() + lam * reg


def test_tgv_prox_minimises_its_objective():
    """Run to convergence, the step's (z, w) minimises 0.5 ||z - t||^2 + lam TGV-term
    jointly: no random perturbation, nor the input itself, nor the TV-like w = 0 with
    the same z, does better; the kernels' value agrees with the NumPy reference."""
    rng = np.random.default_rng(4)
    yy, xx = np.mgrid[:24, :32].astype(np.float32)
    t = (0.02 * xx + (yy > 11) * 0.5 + 0.05 * rng.standard_normal(xx.shape)).astype(np.float32)
    lam = 0.08
    prior = TgvPrior(inner_iterations=3000)
    z, w1, w2 = prior.denoise(t, lam)[:3]
    best = _tgv_objective(z, w1, w2, t, lam, 2.0)
    assert best == pytest.approx(0.5 * ((z - t) ** 2).sum(dtype=np.float64)
                                 + lam * k.tgv_upper_value(z, w1, w2, 1.0, 2.0), rel=1e-5)
    assert best < _tgv_objective(t, 0 * w1, 0 * w2, t, lam, 2.0)
    assert best < _tgv_objective(z, 0 * w1, 0 * w2, t, lam, 2.0)
    for _ in range(20):
        dz, d1, d2 = (1e-3 * rng.standard_normal(t.shape).astype(np.float32) for _ in range(3))
        assert best <= _tgv_objective(z + dz, w1 + d1, w2 + d2, t, lam, 2.0) + 1e-6
    # the ADMM's steps (20 iterations each, warm-started) reach the converged one
    step = TgvPrior()
    cold = step.prox(np, (t,), lam, 1.0)[0]
    assert np.linalg.norm(cold - z) > 0.2 * np.linalg.norm(z - t)  # one step: far
    for _ in range(30):
        (z20,) = step.prox(np, (t,), lam, 1.0)
    assert np.linalg.norm(z20 - z) < 0.02 * np.linalg.norm(z - t)
    step.reset()
    np.testing.assert_array_equal(step.prox(np, (t,), lam, 1.0)[0], cold)


def test_tgv_denoises_a_ramp_without_the_staircase():
    """A piecewise-smooth image (two ramps and a step) with 5 % noise: the TGV step,
    each at its best weight, beats anisotropic TV's prox (which staircases the
    ramps) in PSNR."""
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[:64, :96].astype(np.float32)
    clean = np.where(xx < 48, xx / 96, 0.9 - xx / 160) + 0.002 * yy
    clean = clean.astype(np.float32)
    noisy = (clean + 0.05 * rng.standard_normal(clean.shape)).astype(np.float32)

    def psnr(z):
        return 10 * np.log10(1.0 / np.mean((z[2:-2, 2:-2] - clean[2:-2, 2:-2]) ** 2))

    def tv_denoise(lam):  # ROF with anisotropic TV: ADMM on the differences, 300 steps
        x, q = noisy.copy(), [np.zeros_like(noisy), np.zeros_like(noisy)]
        ky, kx = np.meshgrid(np.arange(64), np.arange(96), indexing="ij")
        dd = 4 * np.sin(np.pi * kx / 96) ** 2 + 4 * np.sin(np.pi * ky / 64) ** 2  # |F D+|^2
        rho = 2.0
        for _ in range(300):
            g = (np.roll(x, -1, 1) - x, np.roll(x, -1, 0) - x)
            z = TotalVariation().prox(np, tuple(a + b for a, b in zip(g, q, strict=True)),
                                      lam, rho)
            q = [qq + gg - zz for qq, gg, zz in zip(q, g, z, strict=True)]
            r = [zz - qq for zz, qq in zip(z, q, strict=True)]
            rhs = noisy + rho * (np.roll(r[0], 1, 1) - r[0] + np.roll(r[1], 1, 0) - r[1])
            x = np.real(np.fft.ifft2(np.fft.fft2(rhs) / (1 + rho * dd))).astype(np.float32)
        return x

    best_tv = max(psnr(tv_denoise(lam)) for lam in (0.01, 0.02, 0.04, 0.08))
    best_tgv = max(psnr(TgvPrior(inner_iterations=1000).prox(np, (noisy,), lam, 1.0)[0])
                   for lam in (0.01, 0.02, 0.04, 0.08))
    assert best_tgv > best_tv + 1.0, (best_tgv, best_tv)


@pytest.mark.parametrize("prior", ["tv-iso", "tgv"])
def test_admm_runs_the_new_priors_and_they_help(prior):
    """Through :func:`recon.solvers.admm` (the generic loop with the prior): the record
    names it, and the estimate beats no prior on a noisy, ill-posed problem."""
    from skimage import data

    from recon.operators import ConvolutionOperator

    rng = np.random.default_rng(3)
    psf = rng.random((48, 64)).astype(np.float32) ** 12
    psf /= psf.sum()
    op = ConvolutionOperator(psf)
    x = np.zeros(op.shape_in, np.float32)
    x[24:72, 32:96] = data.camera()[::8, ::8][:48, :64].astype(np.float32) / 255
    b = op.forward(x)
    b = (b + 0.05 * b.max() * rng.standard_normal(b.shape)).astype(np.float32)
    scale = float(b.max())
    b, x = b / scale, x / scale
    res = admm(op, b, iterations=60, tv=1e-3, prior=prior)
    assert res.params["prior"]["prior"] == prior
    plain = admm(op, b, iterations=60)
    crop = op.crop
    assert (np.linalg.norm(res.x[crop] - x[crop])
            < 0.9 * np.linalg.norm(plain.x[crop] - x[crop]))


def test_isotropic_tv_runs_in_the_fused_passes_as_the_generic_set_does():
    """On NumPy, ADMM with tv-iso runs the fused numba split pass (no generic backend in
    its record) and gives what the generic kernel set with the group soft threshold
    gives: the same iterates, objective history and automatic-weight plan."""
    from recon.auto.prior import prior_plan_of
    from recon.operators import ConvolutionOperator
    from recon.solvers.admm import AdmmPlan
    from recon.solvers.admm_loop import run_admm
    from recon.solvers.xp_admm import XpAdmmPlan

    rng = np.random.default_rng(7)
    psf = rng.random((40, 56)).astype(np.float32) ** 10
    op = ConvolutionOperator(psf / psf.sum())
    x = np.zeros(op.shape_in, np.float32)
    x[30:50, 40:70] = 1.0
    b = op.forward(x) + 0.02 * rng.standard_normal(op.shape_out).astype(np.float32)
    b = (b / b.max()).astype(np.float32)
    fused = admm(op, b, iterations=40, tv=2e-3, prior="tv-iso")
    assert "backend" not in fused.params and fused.params["prior"]["prior"] == "tv-iso"
    plan = XpAdmmPlan(AdmmPlan.of(op), b, prior="tv-iso")
    generic = run_admm(plan, b, plan.zeros((2e-3,) * 3, True), iterations=40, tv=2e-3)
    assert np.abs(generic.x - fused.x).max() <= 1e-4 * np.abs(fused.x).max()
    np.testing.assert_allclose(fused.history.objective, generic.history.objective, rtol=1e-4)
    assert fused.final_objective == pytest.approx(generic.final_objective, rel=1e-4)
    anisotropic = admm(op, b, iterations=40, tv=2e-3)
    assert np.abs(anisotropic.x - fused.x).max() > 1e-3 * np.abs(fused.x).max()
    assert prior_plan_of("tv-iso", b)(op).isotropic

"""Tests for recon.solvers: Wiener, gradient descent, FISTA (Algorithm 1) and ADMM
(App. A.3) on a small synthetic problem with a known answer (see conftest.py).

PSNR bounds are on the central sensor-sized region of the padded grid, peak 1; the
all-zero image scores about 6 dB there. Each bound sits about 3 dB or more below
what the solver reached when the test was written (noted next to it).
"""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from recon.errors import DivergenceError, ReconInputError
from recon.operators import ConvolutionOperator, PixelErasure
from recon.solvers import AdmmPenalty, admm, fista, gradient_descent, wiener
from recon.solvers.wiener import auto_regularization

ITERATIONS = 200
TV = 1e-3  # ADMM TV weight (objective of the zero image is ~46)
TV_FISTA = 3e-4

SOLVERS = {
    "gd": lambda op, b, n, **kw: gradient_descent(op, b, iterations=n, **kw),
    "fista": lambda op, b, n, **kw: fista(op, b, iterations=n, **kw),
    "admm": lambda op, b, n, **kw: admm(op, b, iterations=n, **({"tv": TV} | kw)),
}


def _relative_residual(op, x, b) -> float:
    r = op.forward(x).astype(np.float64) - b
    return float(np.linalg.norm(r) / np.linalg.norm(b.astype(np.float64)))


# --------------------------------------------------------------------------- Wiener


def test_wiener_matches_numpy_formula(conv_problem):
    """x = F^-1[conj(H) F(P b) / (|H|^2 + lambda)] with full complex FFTs."""
    op, b = conv_problem.op, conv_problem.b_noisy
    lam = 1e-2
    res = wiener(op, b, lam)
    padded = np.zeros(op.padded_shape)
    padded[op.crop] = op.psf
    h = np.fft.fft2(np.fft.ifftshift(padded))
    pb = np.zeros(op.padded_shape)
    pb[op.crop] = b
    ref = np.fft.ifft2(np.conj(h) * np.fft.fft2(pb) / (np.abs(h) ** 2 + lam)).real
    assert res.x.shape == op.padded_shape
    np.testing.assert_allclose(res.x, ref, rtol=0, atol=1e-5 * np.abs(ref).max())
    assert res.params["regularization"] == lam
    assert len(res.history.objective) == len(res.history.data_residual) == 1
    assert res.final_relative_residual == pytest.approx(
        _relative_residual(op, res.x, b), rel=1e-4)


def test_wiener_recovers_compact_scene(conv_problem):
    """When the blurred scene fits on the sensor the crop loses nothing and Wiener
    with a small lambda is nearly exact (37.8 dB when written)."""
    op = conv_problem.op
    c0, c1 = op.padded_shape[0] // 2, op.padded_shape[1] // 2
    truth = np.zeros(op.padded_shape, np.float32)
    truth[c0 - 8:c0 + 8, c1 - 8:c1 + 8] = conv_problem.truth[c0 - 8:c0 + 8, c1 - 8:c1 + 8]
    truth[c0 - 6:c0 - 2, c1 - 7:c1 + 3] = 0.6
    full = op.convolve_full(truth)
    assert np.abs(full).sum() - np.abs(full[op.crop]).sum() < 1e-3  # all light on sensor
    b = op.forward(truth)
    res = wiener(op, b, 1e-4)
    err = res.x[op.crop] - truth[op.crop]
    assert 10 * np.log10(1.0 / np.mean(err.astype(np.float64) ** 2)) > 32.0


def test_wiener_preview_beats_zero_image(conv_problem):
    zero_psnr = conv_problem.psnr(np.zeros_like(conv_problem.truth))
    res = wiener(conv_problem.op, conv_problem.b_noisy, 1e-2)
    assert conv_problem.psnr(res.x) > zero_psnr + 5.0  # 14.1 vs 6.2 dB when written


def test_wiener_auto_regularization_estimates_noise(conv_problem):
    b = conv_problem.b_noisy
    sigma = 0.01 * float(conv_problem.b_clean.max())
    nsr = sigma**2 / float(np.mean(b.astype(np.float64) ** 2))
    lam = auto_regularization(b)
    assert nsr / 1.5 < lam < 1.5 * nsr  # 5.18e-4 vs 5.04e-4 when written
    assert auto_regularization(conv_problem.b_clean) == pytest.approx(1e-4)  # the floor
    res = wiener(conv_problem.op, b)
    assert res.params["regularization"] == pytest.approx(lam)
    assert np.all(np.isfinite(res.x))


# --------------------------------------------------------------------------- iterative


@pytest.mark.parametrize("name,kwargs,bound", [
    ("gd", {}, 22.0),  # 25.2 dB
    ("fista", {}, 35.0),  # 43.0 dB
    ("fista", {"tv": TV_FISTA}, 33.0),  # 37.8 dB
    ("admm", {"tv": TV, "penalty": AdmmPenalty(balance=True)}, 26.0),  # 29.3 dB
    ("admm", {"tv": TV, "penalty": AdmmPenalty(balance=False)}, 24.5),  # 27.7 dB
], ids=["gd", "fista", "fista-tv", "admm-balanced", "admm-fixed-mu"])
def test_solver_recovers_scene(conv_problem, name, kwargs, bound):
    op, b = conv_problem.op, conv_problem.b_clean
    b_before = b.copy()
    res = SOLVERS[name](op, b, ITERATIONS, **kwargs)
    np.testing.assert_array_equal(b, b_before)  # measurement untouched
    assert res.x.shape == op.padded_shape and res.x.dtype == np.float32
    assert res.x.min() >= 0.0
    assert conv_problem.psnr(res.x) > bound
    # the reported residual is that of the returned estimate (ADMM reports it from its
    # last M x, before the final projection onto x >= 0: agree to a few per mille)
    assert res.final_relative_residual == pytest.approx(
        _relative_residual(op, res.x, b), rel=1e-2 if name == "admm" else 1e-4)


@pytest.mark.parametrize("name", ["gd", "fista", "admm"])
def test_history_lengths_and_trends(conv_problem, name):
    n = 37
    b = conv_problem.b_noisy
    res = SOLVERS[name](conv_problem.op, b, n)
    h = res.history
    assert len(h.objective) == len(h.data_residual) == len(h.seconds) == n
    assert all(s >= 0 for s in h.seconds)
    # iteration 0 is evaluated at the zero image: objective 1/2 ||b||^2, residual 1
    zero = conv_problem.zero_objective(b)
    assert h.objective[0] == pytest.approx(zero, rel=1e-5)
    assert h.data_residual[0] == pytest.approx(1.0, rel=1e-6)
    dr = np.asarray(h.data_residual)
    assert dr[-1] < 0.1 * dr[0]
    assert dr[-5:].mean() < 0.5 * dr[:5].mean()
    assert h.objective[-1] < h.objective[0] / 10
    d = h.as_dict()
    assert len(d["objective"]) == n


def test_admm_objective_decreases_overall(conv_problem):
    b = conv_problem.b_clean
    res = admm(conv_problem.op, b, iterations=ITERATIONS, tv=TV)
    obj = np.asarray(res.history.objective)
    assert obj[-1] < obj[0] / 10
    assert obj[-1] < 0.01 * conv_problem.zero_objective(b)  # 0.0023 when written
    # the second half stays near its floor (ADMM need not be monotone per iteration)
    half = obj[len(obj) // 2:]
    assert half.max() < 2.0 * half.min()
    assert res.final_objective < 1.05 * obj[-1]


def test_admm_and_fista_agree_on_the_objective(conv_problem):
    """Both minimise 1/2||Ax-b||^2 + tau TV(x), x >= 0 (FISTA with the Haar-shift
    approximation of TV): their final objectives are close."""
    op, b = conv_problem.op, conv_problem.b_clean
    f_admm = admm(op, b, iterations=ITERATIONS, tv=TV).final_objective
    f_fista = fista(op, b, iterations=ITERATIONS, tv=TV).final_objective
    assert f_admm == pytest.approx(f_fista, rel=0.1)  # 0.1055 vs 0.1088 when written


def test_fista_tv_beats_no_tv_on_noisy_scene(conv_problem):
    op, b = conv_problem.op, conv_problem.b_noisy
    plain = conv_problem.psnr(fista(op, b, iterations=ITERATIONS).x)
    tv = conv_problem.psnr(fista(op, b, iterations=ITERATIONS, tv=TV_FISTA).x)
    assert tv > plain + 5.0  # 31.5 vs 21.1 dB when written
    assert tv > 28.0


def test_fista_without_nonneg_goes_negative(conv_problem):
    res = fista(conv_problem.op, conv_problem.b_noisy, iterations=ITERATIONS, nonneg=False)
    assert res.x.min() < -0.05
    assert res.params["nonneg"] is False


def test_fista_uses_given_lipschitz(conv_problem):
    op = conv_problem.op
    lip = op.lipschitz()
    res = fista(op, conv_problem.b_clean, iterations=3, lipschitz=2.0 * lip, step_scale=0.5)
    assert res.params["lipschitz"] == pytest.approx(2.0 * lip)
    assert res.params["step"] == pytest.approx(0.25 / lip)


@pytest.mark.parametrize("name,kwargs,bound", [
    ("fista", {"tv": TV_FISTA}, 26.0),  # 30.5 dB
    ("admm", {"tv": TV_FISTA}, 21.0),  # 24.8 dB
])
def test_erased_pixels_are_recovered(conv_problem, name, kwargs, bound):
    """Eq. 3.10: half the sensor pixels erased, the mask folded into the model."""
    op = PixelErasure.random(conv_problem.op.sensor_shape, 0.5, seed=3) @ conv_problem.op
    assert isinstance(op, ConvolutionOperator)
    b = op.forward(conv_problem.truth)
    res = SOLVERS[name](op, b, ITERATIONS, **kwargs)
    assert conv_problem.psnr(res.x) > bound


# --------------------------------------------------------------------------- edges


@pytest.mark.parametrize("mu", [(1e-6, 1e3, 1e-6), (1e4, 1e-6, 1e4)])
def test_admm_balancing_rescues_bad_penalties(conv_problem, mu):
    op, b = conv_problem.op, conv_problem.b_clean
    zero = conv_problem.zero_objective(b)
    good = admm(op, b, iterations=ITERATIONS, tv=TV, penalty=AdmmPenalty(mu=mu, balance=True))
    bad = admm(op, b, iterations=ITERATIONS, tv=TV, penalty=AdmmPenalty(mu=mu, balance=False))
    # balanced: 0.036 / 0.027 residual and 0.0036 / 0.0029 x zero objective when written
    assert good.final_relative_residual < 0.06
    assert good.final_objective < 0.01 * zero
    # fixed badly scaled penalties: 0.52 / 0.99 residual, 0.27 / 0.98 x zero objective
    assert bad.final_relative_residual > 3.0 * good.final_relative_residual
    assert bad.final_objective > 10.0 * good.final_objective
    assert conv_problem.psnr(good.x) > conv_problem.psnr(bad.x) + 3.0
    # the data-split and TV-split penalties moved at least 10x towards O(1); the
    # non-negativity penalty may stay small (an inactive constraint has a dual near
    # zero, so normalised balancing need not raise it). The fixed run kept them.
    assert good.params["mu_initial"] == list(mu)
    assert all(abs(math.log10(f)) < abs(math.log10(m)) - 1.0
               for f, m in zip(good.params["mu_final"][:2], mu[:2], strict=True))
    assert all(1e-5 / 2 <= f <= 1e2 * 2 for f in good.params["mu_final"])
    assert len(good.history.extra["mu"]) > 1
    assert bad.history.extra["mu"] == [list(mu)]
    assert bad.params["mu_final"] == list(mu)


@pytest.mark.parametrize("solver", [fista, gradient_descent])
@pytest.mark.parametrize("step_scale", [3.0, 5.0])
def test_over_large_step_raises_divergence(conv_problem, solver, step_scale):
    b = conv_problem.b_noisy
    n = 100
    with pytest.raises(DivergenceError, match="step") as info:
        solver(conv_problem.op, b, iterations=n, step_scale=step_scale)
    hist = info.value.history
    assert isinstance(hist, dict)
    obj = hist["objective"]
    assert 1 <= len(obj) < n
    assert len(hist["data_residual"]) == len(obj)
    assert f"iteration {len(obj)}" in str(info.value)
    assert not obj[-1] < 100 * conv_problem.zero_objective(b)  # past the limit (or NaN)
    assert all(math.isfinite(v) and v < 100 * conv_problem.zero_objective(b)
               for v in obj[:-1])


def _all_solvers():
    return [
        pytest.param(lambda op, b: fista(op, b, iterations=10), id="fista"),
        pytest.param(lambda op, b: gradient_descent(op, b, iterations=10), id="gd"),
        pytest.param(lambda op, b: admm(op, b, iterations=10), id="admm"),
        pytest.param(lambda op, b: wiener(op, b, 1e-3), id="wiener"),
        pytest.param(lambda op, b: wiener(op, b), id="wiener-auto"),
    ]


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("bad", [np.nan, np.inf])
@pytest.mark.parametrize("run", _all_solvers())
def test_non_finite_measurement_is_caught(conv_problem, run, bad):
    b = conv_problem.b_noisy.copy()
    b[5, 7] = bad
    with pytest.raises((DivergenceError, ReconInputError)):
        run(conv_problem.op, b)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("run", _all_solvers())
def test_all_zero_measurement_is_refused(conv_problem, run):
    with pytest.raises(ReconInputError, match="zero"):
        run(conv_problem.op, np.zeros(conv_problem.op.shape_out, np.float32))


def _masked_window(op):
    return op @ PixelErasure(np.ones(op.shape_in, np.float32))  # a generic Composition


@pytest.mark.parametrize("call,fragment", [
    (lambda op, b: fista(op, b, iterations=0), "iterations"),
    (lambda op, b: gradient_descent(op, b, iterations=0), "iterations"),
    (lambda op, b: admm(op, b, iterations=0), "iterations"),
    (lambda op, b: fista(op, b, iterations=5, tv=-1e-3), "TV"),
    (lambda op, b: fista(op, b, iterations=5, tv=float("nan")), "TV"),
    (lambda op, b: gradient_descent(op, b, iterations=5, tv=-1.0), "TV"),
    (lambda op, b: admm(op, b, iterations=5, tv=-1e-3), "TV"),
    (lambda op, b: gradient_descent(op, b, iterations=5, momentum=1.0), "momentum"),
    (lambda op, b: gradient_descent(op, b, iterations=5, momentum=-0.1), "momentum"),
    (lambda op, b: fista(op, b, iterations=5, step_scale=0.0), "step"),
    (lambda op, b: fista(op, b, iterations=5, step_scale=-1.0), "step"),
    (lambda op, b: wiener(op, b, 0.0), "regularization"),
    (lambda op, b: wiener(op, b, -1e-3), "regularization"),
    (lambda op, b: wiener(op, b, float("nan")), "regularization"),
    (lambda op, b: wiener(_masked_window(op), b, 1e-3), "Convolution"),
    (lambda op, b: admm(_masked_window(op), b, iterations=5), "Convolution"),
    (lambda op, b: admm(PixelErasure(np.ones(op.shape_out)), b, iterations=5), "Convolution"),
    (lambda op, b: admm(op, b, iterations=5, penalty=AdmmPenalty(mu=(0.5, 0.0, 0.5))),
     "penalties"),
    (lambda op, b: admm(op, b, iterations=5, penalty=AdmmPenalty(mu=(0.5, 1.0, -0.5))),
     "penalties"),
    (lambda op, b: admm(op, b, iterations=5, penalty=AdmmPenalty(mu=(np.inf, 1.0, 0.5))),
     "penalties"),
    (lambda op, b: admm(op, b, iterations=5, penalty=AdmmPenalty(balance_every=1)),
     "balance_every"),
    (lambda op, b: fista(ConvolutionOperator(np.zeros((32, 32))), b, iterations=5), "zero"),
], ids=["fista-it0", "gd-it0", "admm-it0", "fista-tv-neg", "fista-tv-nan", "gd-tv-neg",
        "admm-tv-neg", "gd-momentum-1", "gd-momentum-neg", "fista-step-0", "fista-step-neg",
        "wiener-reg-0", "wiener-reg-neg", "wiener-reg-nan", "wiener-composition",
        "admm-composition", "admm-erasure-only", "admm-mu-0", "admm-mu-neg", "admm-mu-inf",
        "admm-balance-every", "fista-zero-psf"])
def test_invalid_parameters_are_refused(conv_problem, call, fragment):
    with pytest.raises(ReconInputError, match=fragment):
        call(conv_problem.op, conv_problem.b_clean)


# ------------------------------------------------------------------ allocation behaviour


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc allocator only")
@pytest.mark.parametrize("method", ["admm", "fista"])
def test_iterations_do_not_page_fault_fresh_memory(method):
    """No per-iteration cost of freshly faulted pages (deterministic, not timed):
    the FFT outputs are reused from the heap (recon.fft.retain_freed_memory)."""
    import resource

    from recon.fft import RETAINS_FREED_MEMORY

    assert RETAINS_FREED_MEMORY
    rng = np.random.default_rng(0)
    psf = rng.random((300, 400)).astype(np.float32) ** 8
    op = ConvolutionOperator(psf / psf.sum())  # padded 600 x 800: 1.9 MB per array
    b = op.forward(rng.random(op.shape_in).astype(np.float32))
    run = (lambda n: admm(op, b, iterations=n, tv=1e-4)) if method == "admm" else (
        lambda n: fista(op, b, iterations=n, tv=1e-4, lipschitz=1.0))
    run(3)  # warm-up: compile, plans, first touch

    def faults():
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt

    def faults_of(n):
        before = faults()
        run(n)
        return faults() - before

    # marginal faults per iteration (setup buffers of each call cancel out)
    per_iteration = (faults_of(40) - faults_of(10)) / 30
    # one fresh 600 x 800 float32 array is ~470 pages; default glibc gave ~1000-2000
    assert per_iteration < 100, per_iteration


def test_admm_penalty_settings_are_one_validated_value(conv_problem):
    """AdmmPenalty: frozen, validated on construction, and each setting reaches the loop."""
    import dataclasses

    penalty = AdmmPenalty(mu=[1e-3, 2e-3, 3e-3], balance_every=np.int64(4))
    assert penalty.mu == (1e-3, 2e-3, 3e-3) and penalty.balance_every == 4
    with pytest.raises(dataclasses.FrozenInstanceError):
        penalty.balance = False
    for bad, fragment in [({"balance": "yes"}, "balance"), ({"balance_until": 1.5},
                          "balance_until"), ({"balance_ratio": 1.0}, "balance_ratio"),
                          ({"balance_factor": 0.5}, "balance_factor"), ({"mu": (1, 2)}, "mu")]:
        with pytest.raises(ReconInputError, match=fragment):
            AdmmPenalty(**bad)
    op, b = conv_problem.op, conv_problem.b_noisy
    with pytest.raises(ReconInputError, match="AdmmPenalty"):
        admm(op, b, iterations=5, penalty={"mu": (1e-3, 1e-3, 1e-3)})
    mu = (1e-4, 1e-1, 1e-4)  # badly scaled: balancing moves them when allowed
    moved = admm(op, b, iterations=40, tv=TV, penalty=AdmmPenalty(mu=mu))
    assert moved.params["mu_initial"] == list(mu) and len(moved.history.extra["mu"]) > 1
    # balancing only before iteration 0.0 * 40, or off: the penalties stay at mu
    for frozen in (AdmmPenalty(mu=mu, balance_until=0.0), AdmmPenalty(mu=mu, balance=False)):
        res = admm(op, b, iterations=40, tv=TV, penalty=frozen)
        assert res.history.extra["mu"] == [list(mu)] and res.params["mu_final"] == list(mu)
    # balancing every 10 iterations changes the penalties at most 2 times in 40 x 0.6
    sparse = admm(op, b, iterations=40, tv=TV, penalty=AdmmPenalty(mu=mu, balance_every=10))
    assert 1 < len(sparse.history.extra["mu"]) <= 3 < len(moved.history.extra["mu"])
    assert moved.params["iterations"] == moved.params["iterations_used"] == 40

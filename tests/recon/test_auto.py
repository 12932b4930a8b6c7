"""Automatic regularisation, stopping and method choice (recon.auto)."""

from __future__ import annotations

import numpy as np
import pytest

import recon
from recon.auto import NoSignalError, Stopping, estimate_noise, parse_weight
from recon.auto.weight import END_WEIGHT, START_WEIGHT, admm_auto
from recon.errors import ReconInputError
from recon.metrics import psnr
from recon.operators import ConvolutionOperator
from recon.solvers import admm


def _piecewise(shape, rng):
    img = np.zeros(shape, np.float32)
    for _ in range(6):
        r, c = rng.integers(0, shape[0] - 8), rng.integers(0, shape[1] - 8)
        h, w = rng.integers(4, 12, 2)
        img[r:r + h, c:c + w] += rng.uniform(0.3, 1.0)
    return img


def test_noise_model_recovers_poisson_gaussian_parameters():
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:256, 0:256]
    clean = 20 + 1500 * (0.5 + 0.5 * np.sin(xx / 40.0) * np.cos(yy / 55.0))  # smooth
    gain, read = 0.5, 15.0  # DN per electron, DN
    frame = gain * rng.poisson(clean / gain) + rng.normal(0, read, clean.shape)
    model = estimate_noise(frame)
    assert model.shot == pytest.approx(gain, rel=0.15)  # var = gain * signal + read^2
    assert model.read == pytest.approx(read**2, rel=0.3)
    true_energy = float(np.sum(gain * clean + read**2))
    assert model.energy(frame) == pytest.approx(true_energy, rel=0.05)


def test_holdout_weight_on_a_denoising_problem_with_a_computable_optimum():
    """Identity blur (a delta PSF): TV denoising, whose MSE-optimal weight is found by
    brute force against the truth. The held-out choice lands within a factor 4 of it
    and within 1 dB of its PSNR."""
    rng = np.random.default_rng(3)
    psf = np.zeros((48, 48), np.float32)
    psf[24, 24] = 1.0
    op = ConvolutionOperator(psf)
    truth = np.zeros(op.padded_shape, np.float32)
    truth[op.crop] = _piecewise((48, 48), rng)
    sigma = 0.08
    b = (op.forward(truth) + rng.normal(0, sigma, op.shape_out)).astype(np.float32)
    scale = float(np.abs(b).max())
    bs = b / np.float32(scale)
    weights = START_WEIGHT["tv"] / 2.0 ** np.arange(11)  # the path's grid, 1e-2 .. 1e-5
    scores = [psnr(admm(op, bs, iterations=300, tv=w).x[op.crop], truth[op.crop])
              for w in weights]
    best = int(np.argmax(scores))
    res, choice = admm_auto(op, bs, iterations=300, noise_energy=bs.size * (sigma / scale) ** 2)
    got = psnr(res.x[op.crop], truth[op.crop])
    assert weights[best] / 4 <= choice.weight <= weights[best] * 4, (choice.weight,
                                                                       weights[best])
    assert got > scores[best] - 1.0, (got, scores[best])
    assert choice.criterion == "holdout" and "cross-validation" in choice.reason


@pytest.mark.parametrize("kind, photons", [("text", 300.0), ("photo:camera", 30000.0),
                                           ("photo:chelsea", 300.0)])
def test_auto_within_bound_of_the_oracle_on_small_scenes(kind, photons):
    """Chelsea at 300 e- is where the one-standard-error rule alone takes the path's
    first weight (1e-2, 20x the held-out minimum's); the bound keeps it within 2x."""
    from benchmarks.auto_scenes import render_case
    from recon.auto.weight import MAX_ABOVE_MINIMUM

    case = render_case(kind, photons, coarse_bin=8)
    grid = [psnr(admm(case.op, case.b, iterations=200, tv=w).x[case.op.crop], case.truth)
            for w in (1e-5, 1e-4, 3e-4, 1e-3, 3e-3)]
    out = recon.reconstruct(case.op.psf, case.raw_e, preprocess=False, iterations=200)
    got = psnr(out.image, case.truth)
    assert got > max(grid) - 1.5, (got, grid)
    rec = out.metrics(1e-3)["auto"][0]
    assert rec["method"]["method"] == "admm" and rec["weight"]["reason"]
    assert END_WEIGHT["tv"] <= out.info["tv"] <= START_WEIGHT["tv"]
    path = rec["weight"]["path"]
    w_min = min(path, key=lambda p: p["holdout_error"])["weight"]
    assert w_min <= out.info["tv"] <= MAX_ABOVE_MINIMUM * w_min * (1 + 1e-9), (
        out.info["tv"], w_min)


def test_fixed_weight_stops_when_the_fit_settles(conv_problem):
    p = conv_problem
    stop = Stopping(window=10, tolerance=1e-3).hook(0.5 * p.b_noisy.size * 1e-4, 1.0)
    stopped = admm(p.op, p.b_noisy, iterations=500, tv=1e-3, stop=stop)
    full = admm(p.op, p.b_noisy, iterations=500, tv=1e-3)
    used = stopped.params["iterations_used"]
    assert used < 500 and len(stopped.history.objective) == used
    assert full.params["iterations_used"] == 500
    assert p.psnr(stopped.x) > p.psnr(full.x) - 0.5


def test_time_budget_of_one_frame_gives_wiener_and_says_why(conv_problem):
    p = conv_problem
    out = recon.reconstruct(p.op.psf, p.b_noisy, preprocess=False, seconds=1e-6)
    assert out.info["method"] == "wiener"
    reasons = out.info["auto"][0]["method"]["reasons"]
    assert any("Wiener" in r and "time budget" in r for r in reasons)
    with pytest.raises(ReconInputError, match="needs method 'auto'"):
        recon.reconstruct(p.op.psf, p.b_noisy, "admm", preprocess=False, seconds=1.0)


def test_all_dark_frame_is_refused():
    psf = np.zeros((32, 32), np.float32)
    psf[14:18, 14:18] = 1.0
    with pytest.raises(ReconInputError, match="constant .every sample 0"):
        recon.reconstruct(psf, np.zeros((32, 32), np.float32), preprocess=False)


def test_pure_noise_says_the_data_carry_no_signal():
    rng = np.random.default_rng(5)
    psf = np.zeros((64, 64), np.float32)
    psf[28:36, 28:36] = rng.random((8, 8)) ** 4
    noise = (rng.poisson(5.0, (64, 64)) - 5.0 + rng.normal(0, 2, (64, 64))).astype(np.float32)
    # every method checks the raw after its dark level (here none: preprocess=False)
    for method in ("auto", "admm", "wiener"):
        with pytest.raises(ReconInputError, match="carries no signal above the dark level 0"):
            recon.reconstruct(psf, noise, method, preprocess=False, iterations=30)
    # the automatic check of the noise model still refuses a frame whose light is too
    # weak for its noise
    with pytest.raises(NoSignalError, match="carry no signal"):
        recon.reconstruct(psf, noise + 0.5, preprocess=False, iterations=30)


def test_saturated_frame_warns_and_stays_finite():
    from recon.preprocess import SaturationWarning

    rng = np.random.default_rng(6)
    psf = np.zeros((64, 64), np.float32)
    psf[28:36, 28:36] = rng.random((8, 8)) ** 4
    raw = (1000 + 30000 * rng.random((64, 64))).astype(np.uint16)
    raw[:8] = 65535  # 12.5 % saturated: warned, reconstructed
    with pytest.warns(SaturationWarning):
        out = recon.reconstruct(psf, raw, iterations=30, dark="none")
    assert np.all(np.isfinite(out.image)) and out.image.min() >= 0
    assert out.image.max() > 0  # not blank
    raw[:56] = 65535  # 87.5 % saturated: the linear model fails on most of the frame
    with pytest.raises(ReconInputError, match="87.5% of the raw is at full scale"):
        recon.reconstruct(psf, raw, iterations=30, dark="none")


def test_psf_much_smaller_than_the_sensor():
    """A 6 x 6 PSF on a 96 x 96 sensor: auto converges to the scene, not a blank."""
    rng = np.random.default_rng(7)
    psf = np.zeros((96, 96), np.float32)
    psf[45:51, 45:51] = rng.random((6, 6)) ** 2
    op = ConvolutionOperator(psf / psf.sum())
    truth = np.zeros(op.padded_shape, np.float32)
    truth[op.crop] = _piecewise((96, 96), rng)
    clean = op.forward(truth) * 2000.0
    raw = (rng.poisson(np.maximum(clean, 0)) + rng.normal(0, 3, clean.shape)).astype(np.float32)
    out = recon.reconstruct(psf, raw, preprocess=False, iterations=150)
    assert np.all(np.isfinite(out.image)) and out.image.max() > 0
    assert psnr(out.image, truth[op.crop]) > 20.0


def test_parse_weight():
    assert parse_weight(None, "tv") == "auto" and parse_weight(" AUTO ", "tv") == "auto"
    assert parse_weight(1e-4, "tv") == 1e-4 and parse_weight(np.float32(0), "l1") == 0.0
    for bad in ("1e-4", True, [0.1]):  # the command line converts with weight_arg
        with pytest.raises(ReconInputError, match="^tv weight must be"):
            parse_weight(bad, "tv")
    from recon.auto import weight_arg

    assert weight_arg("Auto") == "auto" and weight_arg("1e-4") == 1e-4
    with pytest.raises(ValueError):
        weight_arg("x")
    with pytest.raises(ReconInputError, match="tv weight must be a finite number >= 0"):
        parse_weight(-1, "tv")


def test_path_budget_and_grid():
    from recon.auto.weight import BUDGET, PATH_FACTOR, path_budget, weight_grid

    for n in (1, 20, 60, 150, 200, 500):
        assert path_budget(n) == max(2, round(BUDGET * n))
    grid = weight_grid(1e-2, 1e-5)
    assert grid[0] == 1e-2 and grid[-1] == pytest.approx(1e-5)
    steps = [a / b for a, b in zip(grid, grid[1:], strict=False)]
    assert max(steps) <= PATH_FACTOR * (1 + 1e-9) and min(steps) == pytest.approx(max(steps))
    assert weight_grid(1e-3, 1e-3) == [1e-3]
    with pytest.raises(ReconInputError, match="positive weights"):
        weight_grid(0.0, 1e-5)


def test_a_short_cap_leaves_candidates_unsettled_and_the_record_says_so(conv_problem):
    p = conv_problem
    bs = p.b_noisy / np.float32(np.abs(p.b_noisy).max())
    _, choice = admm_auto(p.op, bs, iterations=20, noise_energy=bs.size * 1e-4,
                          path_only=True)
    rec = choice.as_dict()
    assert rec["stop_reason"] and rec["budget_iterations"] == 70
    assert rec["path_iterations"] <= 70
    unsettled = [q for q in rec["path"] if not q["converged"]]
    assert unsettled and all(q["status"] == "cap" for q in unsettled)
    assert "not settled within their iterations" in choice.reason


def test_final_solve_stops_where_the_held_out_pixels_say_the_noise_starts():
    """Camera photograph at bin 8, 10000 photo-electrons: the held-out path picks TV
    1e-5, whose solve peaks on the way and converges to 21 dB (noise fitted into the
    null space); the watched final solve keeps the iterate before that (26.4 dB
    measured) -- within 1 dB of fixed ADMM at the former default (25.7 dB)."""
    from benchmarks.auto_scenes import render_case

    case = render_case("photo:camera", 10000.0, coarse_bin=8)
    fixed = psnr(admm(case.op, case.b, iterations=200, tv=3e-4).x[case.op.crop], case.truth)
    out = recon.reconstruct(case.op.psf, case.raw_e, preprocess=False, iterations=200)
    rec = out.metrics(1e-3)["auto"][0]["weight"]
    assert rec["final_pixels"].startswith("fit") and rec["holdout_coverage"] > 0.5
    chosen = next(q for q in rec["path"] if q["weight"] == rec["weight"])
    assert rec["kept_final_iteration"] <= chosen["iterations"]
    assert psnr(out.image, case.truth) > fixed - 1.0, (psnr(out.image, case.truth), fixed)


def test_a_compact_psf_s_final_solve_uses_every_pixel():
    from recon.auto.holdout import holdout_coverage, holdout_mask

    delta = np.zeros((48, 48), np.float32)
    delta[24, 24] = 1.0
    spread = np.random.default_rng(0).random((48, 48)).astype(np.float32) ** 8
    keep = holdout_mask((48, 48), 0.1, 0, block=8)  # a 48 x 48 sensor's blocks
    assert holdout_coverage(ConvolutionOperator(delta), keep) < 0.01  # blocks unseen
    assert 0.5 < holdout_coverage(ConvolutionOperator(spread), keep) < 1.0


def test_a_transient_after_a_weight_step_does_not_end_the_path():
    """The failure map's camera photograph, bin 8, 1000 photo-electrons, 80 % of the
    pixels erased: after the first step the held-out error spikes (0.97 -> 2.0) and
    falls back (1.04) while still above the first weight's; counting both as rises
    ended the path at 1e-2 (16.2 dB). A falling error is not a rise."""
    from benchmarks.auto_scenes import render_case

    case = render_case("photo:camera", 1000.0, coarse_bin=8)
    rng = np.random.default_rng(1)  # the failure map's tenth erasure mask
    masks = [rng.random(case.op.sensor_shape) >= e for e in (0.5, 0.8, 0.9, 0.95) * 2
             + (0.5, 0.8)]
    mask = masks[-1].astype(np.float32)
    op, b = case.op.with_weights(mask), np.ascontiguousarray(case.b * mask, np.float32)
    res, choice = admm_auto(op, b, iterations=200, noise_energy=float(b.size) * 1e-6)
    assert len(choice.path) > 3
    assert choice.weight < 1e-3 and psnr(res.x[op.crop], case.truth) > 19.0


def test_a_fixed_l1_weight_is_used_along_the_automatic_tv_path(conv_problem, monkeypatch):
    """``tv="auto"`` with ``l1=0.05``: every ADMM run of the path and of the final solve
    has l1 0.05 (it was dropped, while the record said 0.05), and the record says it."""
    import importlib

    # every plan's run calls run_admm in the loop's module
    admm_module = importlib.import_module("recon.solvers.admm_loop")

    seen = []
    real = admm_module.run_admm

    def spy(plan, b, state, **kw):
        seen.append((kw["tv"], kw["l1"]))
        return real(plan, b, state, **kw)

    monkeypatch.setattr(admm_module, "run_admm", spy)
    p = conv_problem
    out = recon.reconstruct(p.op.psf, p.b_noisy, preprocess=False, tv="auto", l1=0.05,
                            iterations=60)
    assert seen and all(l1 == 0.05 and tv > 0 for tv, l1 in seen)
    assert out.info["l1"] == 0.05 and out.info["tv"] == out.info["auto"][0]["weight"]["weight"]
    with pytest.raises(ReconInputError, match="fixed l1 weight"):
        admm_auto(p.op, p.b_noisy, iterations=20, noise_energy=1.0, fixed=-1.0)


def test_the_l1_path_spans_the_weights_that_matter_in_fine_steps(conv_problem):
    """l1 from 1 down to 1e-3 (below it l1 changes nothing): at 200 iterations its steps
    are fine (down to 1e-5 they were 5.2x, flagged as too coarse)."""
    p = conv_problem
    bs = p.b_noisy / np.float32(np.abs(p.b_noisy).max())
    _, choice = admm_auto(p.op, bs, iterations=200, noise_energy=bs.size * 1e-4,
                          regulariser="l1", path_only=True)
    weights = [q["weight"] for q in choice.path]
    assert "caution" not in choice.reason
    assert weights[0] == START_WEIGHT["l1"] and min(weights) >= END_WEIGHT["l1"] * 0.999
    assert max(a / b for a, b in zip(weights, weights[1:], strict=False)) < 4.0


def test_the_reported_objective_is_the_returned_estimate_s(conv_problem):
    """The pieces of the path and the final solve skip their own final evaluation (one
    forward model each); the result reports the objective and residual of the estimate
    it returns, on the pixels its solve fitted."""
    from recon.solvers.common import anisotropic_tv

    p = conv_problem
    bs = p.b_noisy / np.float32(np.abs(p.b_noisy).max())
    res, choice = admm_auto(p.op, bs, iterations=150, noise_energy=bs.size * 1e-4)
    # this PSF is compact, so the final solve fitted every pixel
    assert choice.final_pixels.startswith("all")
    keep = np.ones(p.op.sensor_shape, np.float32)
    fit = p.op.with_weights(keep)
    r = fit.forward(res.x) - bs * keep
    want = 0.5 * float(np.vdot(r, r)) + choice.weight * anisotropic_tv(res.x)
    assert res.final_objective == pytest.approx(want, rel=1e-4)
    assert res.final_relative_residual == pytest.approx(
        float(np.linalg.norm(r) / np.linalg.norm(bs * keep)), rel=1e-4)


def test_held_out_blocks_are_32_pixels_wide_and_shrink_on_a_small_sensor():
    """Blocks wider than the spatially varying model's correlated error (on the demo,
    8 x 8 blocks chose TV 7.2e-5, 19.1 dB, against 1.9e-4, 21.4 dB, fixed); smaller
    blocks where the sensor holds too few of them; the volume keeps 8 x 8."""
    from recon.auto.holdout import BLOCK, holdout_split
    from recon.auto.volume import VOLUME_RULES
    from recon.auto.weight import PATH_RULES

    assert BLOCK == 32 and PATH_RULES["tv"].block == 32 and VOLUME_RULES["tv"].block == 8

    def split(shape, seed=0, block=BLOCK):
        keep, held = holdout_split(ConvolutionOperator(np.ones(shape, np.float32)), 0.1,
                                   seed, block)
        assert held.sum() >= 16 and keep.any() and not (keep & held).any()
        return held

    def aligned(held, side):  # every held-out block fills its cell of a side-wide grid
        cells = held.reshape(held.shape[0] // side, side, held.shape[1] // side, side)
        return np.array_equal(cells.any((1, 3)), cells.all((1, 3)))

    assert aligned(split((256, 320)), 32)
    held8 = split((256, 320), block=8)
    assert aligned(held8, 8) and not aligned(held8, 32)
    # a 64 x 64 sensor holds four 32 x 32 blocks: 8 x 8 blocks instead
    held = split((64, 64))
    assert aligned(held, 8) and not aligned(held, 32)


def test_a_path_that_only_chooses_does_not_run_on_at_its_weight(conv_problem):
    """The run-on at the chosen weight improves the kept iterate, which a caller of
    ``path_only`` (the RGB lead channel, FISTA at an automatic weight) drops: such a
    path chooses the same weight and stops with the last candidate."""
    p = conv_problem
    bs = p.b_noisy / np.float32(np.abs(p.b_noisy).max())
    kw = {"iterations": 200, "noise_energy": bs.size * 1e-4}
    _, full = admm_auto(p.op, bs, **kw)
    assert "ran on for" in full.stop_reason  # this problem's chosen weight runs on
    none, chosen = admm_auto(p.op, bs, path_only=True, **kw)
    assert none is None and chosen.weight == full.weight
    assert "ran on" not in chosen.stop_reason
    assert chosen.path_iterations == sum(c["iterations"] for c in chosen.path)
    assert chosen.path_iterations < full.path_iterations

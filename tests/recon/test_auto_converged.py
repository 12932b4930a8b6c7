"""The automatic weight compares settled solves (recon.auto.path, recon.auto.weight).

The pinned failure: a dense, full-field photograph (scikit-image ``camera`` filling the
field of view) rendered through the tutorial PSF at bin 2 with a dark level in the raw,
reconstructed by :func:`recon.reconstruct` at bin 8, 3000 photo-electrons, 200
iterations. The former path (about 20 iterations per weight, stopped at two rises of the
held-out error) chose TV 1.4e-3 there: 13.7 dB against 22.8 dB at the best fixed weight
(9 dB short; measured with the former code); at 10000 e- 13.6 against 22.9. The rises
were unconverged transients.
"""

from __future__ import annotations

import numpy as np
import pytest

import recon
from recon.auto.path import Convergence, remaining_bound, run_candidate
from recon.auto.weight import admm_auto
from recon.metrics import psnr


def test_remaining_bound_is_the_geometric_tail():
    assert remaining_bound([1.0]) == float("inf")
    assert remaining_bound([1.0, 1.1]) == 0.0  # rising: nothing left to fall
    # falls 0.8, 0.4, 0.1: r = max(0.25, 0.5), tail 0.1 * 0.5 / 0.5
    assert remaining_bound([3.0, 2.2, 1.8, 1.7]) == pytest.approx(0.1)
    # not slowing: bounded as r = 0.9
    assert remaining_bound([2.0, 1.9, 1.8, 1.7]) == pytest.approx(0.1 * 9)
    # too few falls, or a transient spike before them: r = 0.9
    assert remaining_bound([2.0, 1.6, 1.4]) == pytest.approx(0.2 * 9)
    assert remaining_bound([1.0, 2.0, 1.0, 0.9]) == pytest.approx(0.1 * 9)


class _Plan:
    """A plan whose held-out score follows a script (one value per window)."""

    def __init__(self):
        self.calls = 0

    def run(self, b, state, *, iterations, final, tv, l1):
        from recon.solvers.common import History, SolveResult

        self.calls += 1
        return SolveResult(np.full(2, float(self.calls)), History(), 0.0, 0.0, {})


def _scripted(errors, **kw):
    plan = _Plan()
    it = iter(errors)
    return run_candidate(plan, None, None, {"tv": 1.0, "l1": 0.0},
                         lambda st: (next(it), 0.1), np.copy, weight=1.0,
                         conv=Convergence(window=10, tolerance=0.5, min_iterations=30), **kw)


def test_a_candidate_runs_until_settled_or_past_its_minimum():
    # settled: the falls shrink geometrically below half a standard error
    c = _scripted([3.0, 2.0, 1.5, 1.4, 1.39, 1.389, 1.3889], cap=200)
    # falls 0.5, 0.1, 0.01 by 50 iterations: r = 0.2, tail 0.0025 <= 0.5 * 0.1
    assert c.status == "settled" and c.converged and c.iterations == 50
    assert c.remaining == pytest.approx(0.0025)
    # a transient spike in the first windows does not end it; an error that no longer
    # falls does, and the kept iterate is the latest within half a standard error of
    # the best
    c = _scripted([1.0, 2.0, 1.0, 0.9, 0.8, 0.84, 1.0], cap=200)
    assert c.status == "settled" and c.error == 0.8 and c.kept_iteration == 60
    assert c.x[0] == 6.0 and c.iterations == 60
    # past its minimum from the start (a weight below the best): "rising"; the dip in the
    # transient after the weight step is the previous weight's solution, not scored as
    # this weight's: the score and the iterate kept come from after the transient
    c = _scripted([0.5, 0.7, 0.9, 1.0], cap=200)
    assert c.status == "rising" and c.converged and c.kept_iteration == 30
    assert c.iterations == 30 and c.x[0] == 3.0 and c.error == 0.9
    # running on from the weight's own state (no step): every window is scored
    c = _scripted([0.5, 0.7, 0.9, 1.0], cap=200, after_step=False)
    assert c.status == "rising" and c.kept_iteration == 10 and c.error == 0.5
    # the cap: unsettled, and the bound says how far from settled
    c = _scripted([3.0, 2.0, 1.0, 0.5], cap=40)
    assert c.status == "cap" and not c.converged and c.remaining > 0.4


def test_the_time_budget_stops_the_path_and_the_record_says_so(conv_problem):
    p = conv_problem
    bs = p.b_noisy / np.float32(np.abs(p.b_noisy).max())
    _, choice = admm_auto(p.op, bs, iterations=200, noise_energy=bs.size * 1e-4,
                          path_only=True, seconds=1e-6)
    assert len(choice.path) == 1 and choice.path[0]["iterations"] == 10
    assert "time budget of 1e-06 s ran out" in choice.stop_reason
    with pytest.raises(recon.errors.ReconInputError, match="time budget"):
        admm_auto(p.op, bs, iterations=20, noise_energy=1.0, seconds=-1.0)


def test_a_dense_full_field_scene_reaches_the_small_weights_it_needs():
    from skimage.transform import downscale_local_mean

    from benchmarks.auto_scenes import make_scene
    from recon.sample import load_sample
    from recon.simulate import simulate_measurement

    psf = load_sample(2).psf
    scene = make_scene("photo:camera", psf.shape, inset=1.0)
    sim = simulate_measurement(psf, scene, bin_factor=1, photons=3000.0, read_noise_e=3.0,
                               seed=0)
    truth = downscale_local_mean(scene, (4, 4))
    out = recon.reconstruct(psf + 100.0, sim.b + 100.0, bin_factor=4, iterations=200)
    got = psnr(out.image, truth)
    # the oracle over the weights around the best (ADMM, the same 200 iterations)
    fixed = [psnr(recon.reconstruct(psf + 100.0, sim.b + 100.0, "admm", bin_factor=4,
                                    iterations=200, tv=tv).image, truth)
             for tv in (1e-5, 3e-5, 1e-4)]
    assert max(fixed) > 22.0  # the scene allows it
    assert got > max(fixed) - 1.0, (got, fixed)
    rec = out.info["auto"][0]["weight"]
    assert out.info["tv"] < 1e-4 and rec["stop_reason"]
    assert all({"converged", "remaining_bound", "status", "iterations"} <= set(q)
               for q in rec["path"])
    chosen = next(q for q in rec["path"] if q["weight"] == rec["weight"])
    assert chosen["converged"]
    assert rec["path_iterations"] <= rec["budget_iterations"] == 700

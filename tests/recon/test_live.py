"""recon.live: per-PSF reconstructor, exact against recon.reconstruct, warm-started ADMM."""

from __future__ import annotations

import numpy as np
import pytest

import recon
from instrument.benchmarks.live import moving_scene, warm_vs_cold
from recon.errors import ReconInputError
from recon.live import LiveReconstructor
from recon.options import ReconOptions
from recon.solvers import AdmmPenalty


def _raw_pair(shape=(64, 80), seed=1):
    """A uint16 PSF (sparse caustic-like) and measurement with a 100 DN dark offset."""
    rng = np.random.default_rng(seed)
    psf = (rng.random(shape) ** 8 * 4000 + 100 + rng.normal(0, 2, shape)).astype(np.uint16)
    raw = (rng.random(shape) * 3000 + 100).astype(np.uint16)
    return psf, raw


@pytest.mark.parametrize("prior", ["tv", "wavelet"])
def test_live_runs_the_prior_of_its_options(prior):
    """The live stream runs the options' prior, not a TV of its own (the default,
    tv-iso, is the test below): cold, it equals recon.reconstruct with that prior."""
    psf, raw = _raw_pair()
    options = ReconOptions.from_defaults(prior=prior)
    live = LiveReconstructor(psf, options, tv=1e-3)
    got = live.admm(raw, iterations=8, warm_start=False)
    ref = recon.reconstruct(psf, raw, "admm", iterations=8, tv=1e-3, prior=prior,
                            auto_stop=False)
    np.testing.assert_array_equal(got.image, ref.image)
    other = "tv-iso"
    differs = recon.reconstruct(psf, raw, "admm", iterations=8, tv=1e-3, prior=other,
                                auto_stop=False)
    assert not np.array_equal(got.image, differs.image)
    assert live.admm(raw, iterations=3).warm  # its state carries on frame to frame


def test_live_refuses_the_automatic_prior():
    psf, _ = _raw_pair()
    with pytest.raises(ReconInputError, match="one prior for the whole stream"):
        LiveReconstructor(psf, ReconOptions.from_defaults(prior="auto"))


@pytest.mark.parametrize("bin_factor", [1, 2])
def test_cold_admm_equals_reconstruct_exactly(bin_factor):
    psf, raw = _raw_pair()
    penalty = AdmmPenalty(mu=(1e-3, 2e-3, 3e-3))
    options = ReconOptions.from_defaults(bin_factor=bin_factor)
    live = LiveReconstructor(psf, options, tv=1e-3, penalty=penalty)
    got = live.admm(raw, iterations=12, warm_start=False)
    ref = recon.reconstruct(psf, raw, "admm", iterations=12, bin_factor=bin_factor, tv=1e-3,
                            auto_stop=False, penalty=penalty)
    np.testing.assert_array_equal(got.image, ref.image)
    np.testing.assert_array_equal(got.estimate, ref.estimate)
    assert got.solve.history.objective == ref.results[0].history.objective
    assert not got.warm and got.image.shape == live.sensor_shape
    # the first call has no state to start from: warm_start=True is cold too
    again = LiveReconstructor(psf, options, tv=1e-3, penalty=penalty)
    first = again.admm(raw, iterations=12)
    assert not first.warm
    np.testing.assert_array_equal(first.image, ref.image)


def test_wiener_equals_reconstruct_exactly():
    psf, raw = _raw_pair()
    auto = LiveReconstructor(psf, ReconOptions.from_defaults(bin_factor=2))
    got = auto.wiener(raw)
    ref = recon.reconstruct(psf, raw, "wiener", bin_factor=2)
    np.testing.assert_array_equal(got.image, ref.image)
    lam = ref.results[0].params["regularization"]
    assert auto.regularization == lam  # estimated on the first frame, then kept
    other = (raw[::-1] // 2 + 50).astype(np.uint16)
    np.testing.assert_array_equal(
        auto.wiener(other).image,
        recon.reconstruct(psf, other, "wiener", bin_factor=2, regularization=lam).image)
    fixed = LiveReconstructor(psf, ReconOptions.from_defaults(dark="none"),
                              regularization=0.05).wiener(raw)
    np.testing.assert_array_equal(
        fixed.image, recon.reconstruct(psf, raw, "wiener", dark="none",
                                       regularization=0.05).image)


@pytest.mark.parametrize("dark", ["auto", None, "none", 100.0])
def test_dark_means_what_it_means_at_the_front_door(dark):
    """One dark vocabulary: ``"auto"`` estimates from the PSF's corner, None and
    ``"none"`` subtract nothing, a level is subtracted; as :func:`recon.reconstruct`."""
    psf, raw = _raw_pair()
    got = LiveReconstructor(psf, ReconOptions.from_defaults(dark=dark),
                            regularization=0.05).wiener(raw)
    ref = recon.reconstruct(psf, raw, "wiener", dark=dark, regularization=0.05)
    np.testing.assert_array_equal(got.image, ref.image)


def test_warm_state_is_carried_and_reset():
    psf, raw = _raw_pair()
    live = LiveReconstructor(psf)
    cold = live.admm(raw, iterations=3)
    warm = live.admm(raw, iterations=3)
    assert warm.warm
    # the whole state (x, M x, every q = z - a, penalties) is carried: 3 + 3 iterations
    # on one frame are the 6 iterations of one solve (no balancing step below 10)
    six = LiveReconstructor(psf).admm(raw, iterations=6, warm_start=False)
    np.testing.assert_array_equal(warm.image, six.image)
    # the warm start also survives a change of frame scale (state rescaled)
    brighter = live.admm((raw.astype(np.float64) * 1.5).astype(np.uint16), iterations=3)
    assert brighter.warm and brighter.raw_scale > warm.raw_scale
    live.reset()
    again = live.admm(raw, iterations=3)
    assert not again.warm
    np.testing.assert_array_equal(again.image, cold.image)


def test_frames_of_the_wrong_shape_or_colour_are_refused():
    psf, raw = _raw_pair()
    live = LiveReconstructor(psf)
    with pytest.raises(ReconInputError, match="shape"):
        live.wiener(raw[:, :-1])
    with pytest.raises(ReconInputError, match="zero after dark"):
        LiveReconstructor(psf, ReconOptions.from_defaults(dark="none")).admm(
            np.zeros_like(raw), iterations=5)
    with pytest.raises(ReconInputError, match="iterations"):
        live.admm(raw, iterations=0)
    with pytest.raises(ReconInputError, match="2D"):
        LiveReconstructor(np.dstack([psf] * 3))


def test_warm_start_beats_cold_start_on_a_moving_scene():
    """Noisy frames rendered on a finer grid (no inverse crime) of a panning scene; the
    PSNR is against each frame's own truth."""
    rng = np.random.default_rng(4)
    fine = np.zeros((96, 128))
    fine[24:72, 32:96] = rng.random((48, 64)) ** 10
    sims = moving_scene(fine, 5, shift_px=2, photons=3000.0, seed=7)
    res = warm_vs_cold(fine, sims, max_iterations=3)
    cold, warm = np.array(res["cold_db"]), np.array(res["warm_db"])
    np.testing.assert_array_equal(cold[:, 0], warm[:, 0])  # frame 1 starts cold in both
    assert np.all(warm[:, 1:] > cold[:, 1:] + 0.1), (cold, warm)
    assert res["gain_db"][-1] > 0.5


def test_run_admm_refuses_a_state_made_for_the_other_tv():
    from recon.solvers.admm import AdmmState, run_admm

    psf, raw = _raw_pair()
    live = LiveReconstructor(psf)
    b, _ = live.prepare(raw)
    state = AdmmState.zeros(live.plan, (2e-3,) * 3, use_tv=False)
    with pytest.raises(ReconInputError, match="tv"):
        run_admm(live.plan, b, state, iterations=2, tv=1e-3)

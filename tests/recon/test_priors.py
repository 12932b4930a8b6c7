"""The priors of the ADMM's u split (recon.priors) and the generic loop that runs them."""

from __future__ import annotations

import numpy as np
import pytest
from skimage import data
from skimage.metrics import peak_signal_noise_ratio

from recon.errors import ReconInputError
from recon.operators import ConvolutionOperator
from recon.priors import PRIORS, DncnnPrior, TotalVariation, WaveletPrior, prior_of
from recon.solvers import admm
from recon.solvers.admm import AdmmPlan
from recon.solvers.admm_loop import run_admm
from recon.solvers.xp_admm import IDENTITY, XpAdmmPlan, XpAdmmState


@pytest.fixture(scope="module")
def problem():
    """A random-caustic PSF, the camera downsampled, 5 % white noise (scaled problem)."""
    rng = np.random.default_rng(3)
    psf = rng.random((48, 64)).astype(np.float32) ** 12
    psf /= psf.sum()
    op = ConvolutionOperator(psf)
    x = np.zeros(op.shape_in, np.float32)
    cam = data.camera()[::8, ::8].astype(np.float32) / 255
    x[24:72, 32:96] = cam[:48, :64]
    b = op.forward(x)
    b = (b + 0.05 * b.max() * rng.standard_normal(b.shape)).astype(np.float32)
    scale = float(b.max())  # the scaled problem: b / max, the truth with it
    return op, b / scale, x / scale


def test_names_and_unknown_prior():
    assert PRIORS == ("tv", "tv-iso", "tgv", "wavelet", "dncnn")
    assert isinstance(prior_of("wavelet"), WaveletPrior)
    assert isinstance(prior_of(None), TotalVariation)  # the solvers' default
    p = TotalVariation()
    assert prior_of(p) is p
    with pytest.raises(ReconInputError, match="tv, tv-iso, tgv, wavelet, dncnn"):
        prior_of("bm3d")


def test_tv_on_the_generic_kernel_set_matches_the_fused_numba_passes(problem):
    op, b, _ = problem
    fused = admm(op, b, iterations=25, tv=1e-3)
    plan = XpAdmmPlan(AdmmPlan.of(op), b, prior="tv")
    generic = run_admm(plan, b, plan.zeros((2e-3,) * 3, True), iterations=25, tv=1e-3)
    assert np.abs(generic.x - fused.x).max() <= 1e-5 * np.abs(fused.x).max()
    assert "prior" not in fused.params  # TV: the record as before


def test_wavelet_prox_with_one_shift_is_the_exact_proximal_operator():
    """z = prox(t) minimises 1/2 ||z - t||^2 + thr ||D W z||_1: no perturbation lowers it,
    and a zero threshold returns t (W orthonormal, the periodic transform exact)."""
    rng = np.random.default_rng(0)
    t = rng.standard_normal((32, 48)).astype(np.float32)
    w = WaveletPrior("db2", levels=2, shifts=1)
    thr = 0.3

    def f(z):
        return 0.5 * float(np.sum((z - t) ** 2)) + thr * w.value(np, z, (z,))

    (z,) = w.prox(np, (t,), thr, 1.0)
    for _ in range(20):
        assert f(z) <= f(z + 1e-2 * rng.standard_normal(z.shape).astype(np.float32)) + 1e-6
    for shifts in (1, 2, 4):
        (same,) = WaveletPrior("sym4", 3, shifts).prox(np, (t,), 0.0, 1.0)
        np.testing.assert_allclose(same, t, atol=1e-5)


def test_wavelet_refuses_what_is_not_an_orthonormal_transform():
    with pytest.raises(ReconInputError, match="not orthogonal"):
        WaveletPrior("bior2.2")
    with pytest.raises(ReconInputError, match="shifts 1, 2 or 4"):
        WaveletPrior(shifts=3)
    with pytest.raises(ReconInputError, match="sym4"):
        WaveletPrior("nonsense")


def test_wavelet_acts_plane_by_plane_on_a_stack():
    rng = np.random.default_rng(1)
    stack = rng.random((3, 32, 40)).astype(np.float32)
    w = WaveletPrior()
    (z,) = w.prox(np, (stack,), 0.05, 1.0)
    for k in range(3):
        np.testing.assert_allclose(z[k], w.prox(np, (stack[k],), 0.05, 1.0)[0], atol=1e-6)


def test_shipped_dncnn_denoises_an_image_it_was_not_trained_on():
    """scikit-image's camera is in the scene suite, not in the training images."""
    from scripts.train_dncnn import TRAINING_IMAGES

    assert "camera" not in TRAINING_IMAGES
    clean = data.camera()[128:384, 128:384].astype(np.float32) / 255
    rng = np.random.default_rng(0)
    d = DncnnPrior()
    for sigma in (0.02, 0.1):
        noisy = clean + sigma * rng.standard_normal(clean.shape).astype(np.float32)
        gain = (peak_signal_noise_ratio(clean, d.denoise(noisy, sigma), data_range=1)
                - peak_signal_noise_ratio(clean, noisy, data_range=1))
        assert gain > 2.0, sigma
    meta = d.training()
    assert meta["images"] == list(TRAINING_IMAGES) and meta["depth"] >= 4


def test_dncnn_step_keeps_the_iterate_scale_and_batches_planes():
    rng = np.random.default_rng(2)
    d = DncnnPrior()
    a = rng.random((2, 24, 32)).astype(np.float32) * 50.0  # far from [0, 1]
    (z,) = d.prox(np, (a,), 0.1, 1e-3)
    assert z.shape == a.shape and z.dtype == np.float32
    assert 0.5 < z.mean() / a.mean() < 2.0  # denoised in the network's unit, scaled back
    (same,) = d.prox(np, (a,), 0.0, 1e-3)
    assert same is a
    np.testing.assert_allclose(d.denoise(a[1] / 50, 0.1), d.denoise(a / 50, 0.1)[1],
                               atol=1e-5)
    with pytest.raises(ReconInputError, match="not found"):
        DncnnPrior("/nonexistent/model.onnx")


def test_identity_split_x_update_solves_its_normal_equations(problem):
    """With G_u = I the x-update is the exact minimiser of
    mu1/2 ||M x - q_v||^2 + mu2/2 ||x - q_u||^2 + mu3/2 ||x - q_w||^2."""
    op, b, _ = problem
    plan = XpAdmmPlan(AdmmPlan.of(op), b, prior="wavelet")
    assert plan.differences is IDENTITY
    rng = np.random.default_rng(4)
    shape = op.padded_shape
    qv, qu, qw = (rng.standard_normal(shape).astype(np.float32) for _ in range(3))
    mu = (0.05, 0.01, 0.002)
    state = XpAdmmState(np.zeros(shape, np.float32), np.zeros(shape, np.float32), qv, (qu,),
                        qw, mu, None, True)
    state.set_penalties(plan, mu)
    x, mx = plan.x_update(state)
    # M^T of the circular convolution through the operator's spectrum
    r = np.fft.rfft2(op.convolve_full(x) - qv)
    grad = mu[0] * np.fft.irfft2(np.conj(op.spectrum) * r, s=shape)
    grad = grad + mu[1] * (x - qu) + mu[2] * (x - qw)
    assert np.abs(grad).max() < 1e-4 * np.abs(mu[1] * qu).max()
    np.testing.assert_allclose(mx, op.convolve_full(x), atol=1e-5)


@pytest.mark.parametrize("prior,weight", [("wavelet", 1e-3), ("dncnn", 0.2)])
def test_admm_with_a_prior_runs_the_one_loop_and_says_which(problem, prior, weight):
    op, b, truth = problem
    res = admm(op, b, iterations=60, tv=weight, prior=prior)
    assert res.params["prior"]["prior"] == prior
    assert res.x.dtype == np.float32 and res.x.min() >= 0
    assert res.params["iterations_used"] == 60
    # the penalties were balanced by the same rule (the loop's mu history)
    assert len(res.history.extra["mu"]) >= 1
    # the prior helps against no prior at all on this noisy, ill-posed problem
    plain = admm(op, b, iterations=60)
    crop = op.crop
    err = np.linalg.norm(res.x[crop] - truth[crop])
    assert err < 0.9 * np.linalg.norm(plain.x[crop] - truth[crop])


def test_volume_prior_on_each_plane_with_an_uncoupled_x_update():
    """3D ADMM with a prior on the volume: u = x (no axial coupling); its x-update solves
    mu1 M^T (M x - q_v) + mu2 (x - q_u) + mu3 (x - q_w) = 0 at every lateral frequency."""
    from recon.volume import VolumeConvolutionOperator, admm3d
    from recon.volume.admm import VolumeAdmmPlan
    from recon.volume.xp_admm3d import XpVolumeAdmmPlan

    rng = np.random.default_rng(6)
    psf = rng.random((3, 24, 32)).astype(np.float32) ** 10
    psf /= psf.sum(axis=(1, 2), keepdims=True) * 3
    op = VolumeConvolutionOperator(psf)
    plan = XpVolumeAdmmPlan(VolumeAdmmPlan.of(op), np.zeros(1, np.float32), prior="dncnn")
    assert plan.differences is IDENTITY
    shape, pad = op.shape_in, plan.xop.padded_shape
    qv = rng.standard_normal(pad).astype(np.float32)
    qu, qw = (rng.standard_normal(shape).astype(np.float32) for _ in range(2))
    mu = (0.05, 0.01, 0.002)
    state = XpAdmmState(np.zeros(shape, np.float32), np.zeros(pad, np.float32), qv, (qu,), qw,
                        mu, None, True)
    x, mx = plan.x_update(state)
    spectra = np.asarray(plan.xop.spectra)
    r = np.fft.rfft2(mx - qv)
    mt = np.fft.irfft2(np.conj(spectra) * r[None], s=pad)
    grad = mu[0] * mt + mu[1] * (x - qu) + mu[2] * (x - qw)
    assert np.abs(grad).max() < 1e-4 * np.abs(mu[1] * qu).max()
    x3 = np.zeros(shape, np.float32)
    x3[1, 10:30, 12:40] = 1.0
    b = op.forward(x3)
    res = admm3d(op, (b / b.max()).astype(np.float32), iterations=10, tv=1e-3,
                 prior="wavelet")
    assert res.params["prior"]["prior"] == "wavelet" and res.x.shape == shape

"""The live reconstructor on a device (:mod:`recon.xp_live`) against its NumPy path.

:class:`recon.live.LiveReconstructor` with ``device=`` a non-NumPy backend keeps the
PSF spectrum, the Wiener filter and the warm-start ADMM state on that backend; here it
runs under ``array-api-strict``, PyTorch's CPU backend, and CuPy / PyTorch on a CUDA GPU
when one is visible, over a sequence of frames whose brightness changes (the warm state
is rescaled between frames) with enough ADMM iterations per frame for residual
balancing to change the penalties. Tolerances as tests/recon/test_backends.py.
"""

from __future__ import annotations

import numpy as np
import pytest

import recon.xp_live
from recon.errors import ReconInputError
from recon.live import LiveReconstructor
from recon.operators import ConvolutionOperator
from recon.options import ReconOptions
from recon.solvers import AdmmPenalty
from recon.solvers.xp_admm import XpAdmmState
from recon.xp_live import live_memory_bytes
from tests.recon.test_backends import GENERIC, SOLVER_TOL, _backend
from tests.recon.test_device import no_gpu

PENALTY = AdmmPenalty(mu=(1e-3, 2e-3, 3e-3), balance_every=3)


def _video(shape=(40, 48), frames=4, seed=1):
    """A uint16 PSF (dark 100 DN) and frames of a scene moving sideways whose exposure
    changes from frame to frame."""
    rng = np.random.default_rng(seed)
    psf = np.zeros(shape, np.float32)
    psf[rng.integers(8, shape[0] - 8, 40), rng.integers(8, shape[1] - 8, 40)] = rng.random(40)
    op = ConvolutionOperator(psf / psf.sum())
    scene = np.zeros(op.padded_shape, np.float32)
    scene[30:50, 40:60] = 1.0
    scene[45:48, 30:70] = 2.0
    raw = [(op.forward(np.roll(scene, 2 * k, axis=1)) * 3000 * (1 + 0.4 * k) + 100
            + rng.normal(0, 5, shape)).astype(np.uint16) for k in range(frames)]
    return (psf * 4000 / psf.max() + 100).astype(np.uint16), raw


def _close(got, ref) -> None:
    assert isinstance(got, np.ndarray) and got.dtype == np.float32 and got.shape == ref.shape
    assert np.abs(got - ref).max() <= SOLVER_TOL * np.abs(ref).max()


@pytest.mark.parametrize("name", GENERIC)
def test_wiener_and_warm_admm_match_the_numpy_path(name):
    backend = _backend(name)
    psf, frames = _video()
    ref = LiveReconstructor(psf, ReconOptions.from_defaults(bin_factor=1), tv=1e-3, penalty=PENALTY)
    dev = LiveReconstructor(psf, ReconOptions.from_defaults(bin_factor=1, device=backend), tv=1e-3,
                            penalty=PENALTY)
    assert dev.backend is backend and ref.backend.is_numpy
    kind = type(dev._device.xop.spectrum)
    assert not issubclass(kind, np.ndarray)  # the PSF spectrum lives on the backend
    w_ref, w_dev = ref.wiener(frames[0]), dev.wiener(frames[0])
    assert dev.regularization == ref.regularization  # estimated on the host, once
    _close(w_dev.image, w_ref.image)
    assert type(w_dev.solve.x) is kind and w_dev.solve.params["device"] == backend.label
    _close(w_dev.estimate, w_ref.estimate)
    assert w_dev.solve.final_objective == pytest.approx(w_ref.solve.final_objective,
                                                        rel=SOLVER_TOL)
    balanced = False
    for k, raw in enumerate(frames):
        r_ref, r_dev = ref.admm(raw, iterations=9), dev.admm(raw, iterations=9)
        assert r_dev.warm == r_ref.warm == (k > 0)
        assert r_dev.raw_scale == r_ref.raw_scale
        _close(r_dev.image, r_ref.image)
        _close(r_dev.estimate, r_ref.estimate)
        assert r_dev.solve.history.objective == pytest.approx(r_ref.solve.history.objective,
                                                              rel=SOLVER_TOL)
        assert r_dev.solve.history.extra["mu"] == r_ref.solve.history.extra["mu"]
        balanced |= len(r_ref.solve.history.extra["mu"]) > 1
        # the warm-start state stays on the backend between frames
        assert isinstance(dev.state, XpAdmmState)
        assert all(type(a) is kind for a in (dev.state.x, dev.state.mx, dev.state.qv,
                                             *dev.state.qu, dev.state.qw))
        assert dev.state.mu == pytest.approx(ref.state.mu, rel=SOLVER_TOL)
    assert balanced  # residual balancing changed the penalties somewhere in the video


@pytest.mark.parametrize("name", ["array-api-strict", "torch-cpu"])
def test_the_warm_start_is_what_the_device_carries(name):
    """Warm frames differ from cold ones by far more than the tolerance, so the
    comparison above checks the carried state; reset() starts cold again."""
    backend = _backend(name)
    psf, frames = _video()
    dev = LiveReconstructor(psf, ReconOptions.from_defaults(device=backend), tv=1e-3)
    cold = LiveReconstructor(psf, tv=1e-3)
    dev.admm(frames[0], iterations=5)
    warm = dev.admm(frames[1], iterations=5)
    ref_cold = cold.admm(frames[1], iterations=5, warm_start=False)
    assert warm.warm
    assert np.abs(warm.image - ref_cold.image).max() > 10 * SOLVER_TOL * np.abs(
        ref_cold.image).max()
    dev.reset()
    assert dev.state is None
    again = dev.admm(frames[1], iterations=5)
    assert not again.warm
    _close(again.image, ref_cold.image)
    # a cold frame with warm_start=False keeps the new state for the next frame
    dev.admm(frames[2], iterations=5, warm_start=False)
    assert isinstance(dev.state, XpAdmmState)


def test_a_live_view_too_large_for_the_device_is_refused_before_anything_moves(
        monkeypatch):
    backend = _backend("torch-cpu")
    psf, _ = _video(shape=(600, 800))

    def no_upload(*args, **kwargs):
        raise AssertionError("moved to the device before the memory check")

    monkeypatch.setattr(recon.xp_live, "free_device_bytes", lambda b: 2**20)
    monkeypatch.setattr(recon.xp_live, "to_device", no_upload)
    needed = live_memory_bytes((1200, 1600))
    assert needed > 30 * 4 * 1200 * 1600  # the ADMM solve's planes and the live state's
    with pytest.raises(ReconInputError) as info:
        LiveReconstructor(psf, ReconOptions.from_defaults(device=backend))
    text = str(info.value)
    assert (f"live reconstruction at 600 x 800 (binned) needs {needed / 2**30:.2f} GiB on "
            f"{backend.label}, 0.00 GiB are free") in text
    assert "--bin" in text and "(device cpu)" in text
    # what fits is accepted
    monkeypatch.undo()
    monkeypatch.setattr(recon.xp_live, "free_device_bytes", lambda b: needed)
    binned = LiveReconstructor(psf, ReconOptions.from_defaults(bin_factor=2, device=backend))
    assert binned.sensor_shape == (300, 400)


@no_gpu
def test_cuda_without_a_gpu_is_refused_and_auto_is_the_numpy_path():
    psf, frames = _video()
    with pytest.raises(ReconInputError, match="cuda requested but"):
        LiveReconstructor(psf, ReconOptions.from_defaults(device="cuda"))
    auto = LiveReconstructor(psf, ReconOptions.from_defaults(device="auto"))
    assert auto.backend.is_numpy and auto._device is None
    np.testing.assert_array_equal(auto.admm(frames[0], 3).image,
                                  LiveReconstructor(psf).admm(frames[0], 3).image)
    with pytest.raises(ReconInputError, match="not one of cpu, cuda, auto"):
        LiveReconstructor(psf, ReconOptions.from_defaults(device="tpu"))

"""Optimiser (Algorithm 1 / App. A.4), one-step and no-mask baselines (Eq. 7.11-7.13).

One-step back-propagation is checked on hand-computed cases; the optimiser on
behaviour the dissertation reports (it beats one-step, frequency constraints beat
plain L2 after the perceptual filter, a complex SLM beats a phase-only one, several
planes can show different images) and on its FFT budget per iteration.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from recon.cgh import (
    IntensityLoss,
    ScatteringDisplay,
    no_mask_hologram,
    one_step_hologram,
    optimize_hologram,
    project,
)
from recon.cgh.protocol import image_metrics, load_bundled, prepare_target
from recon.errors import ReconInputError


def _wrap(a):
    return np.angle(np.exp(1j * a))


def test_one_step_hand_computed_point_at_zero_order():
    # target: one bright sample at the zero order -> F_c^H gives a constant field
    # e^{i theta}/sqrt(G); binning conj(m) per SLM pixel gives e^{i theta} * (block sum
    # of m)/sqrt(G), so the phase is theta where the block sum is > 0, theta + pi where < 0
    mask = np.array([[1, 1, -1, -1],
                     [1, -1, -1, 1],
                     [1, 1, 1, -1],
                     [1, 1, -1, -1]], np.float32)  # block sums: [[2, -2], [4, -2]]
    d = ScatteringDisplay((2, 2), 2, mask=mask)
    target = np.zeros(d.grid_shape, np.float32)
    target[2, 2] = 1.0
    res = one_step_hologram(d, target, seed=3)
    rel = _wrap(res.phase - res.phase[0, 0])
    np.testing.assert_allclose(np.abs(rel), [[0, math.pi], [0, math.pi]], atol=1e-5)
    np.testing.assert_allclose(np.abs(res.field), 1.0, rtol=1e-6)
    assert math.isnan(res.loss) and res.iterations == 0


def test_one_step_hand_computed_off_axis_point_is_a_phase_ramp():
    # clear mask, k = 1: a point at (centre + a, centre + b) back-propagates to the ramp
    # exp(+2 pi i (a r / G_y + b c / G_x)); the display then shows exactly that point
    d = ScatteringDisplay((8, 12), 1, mask="clear")
    a, b = 2, -3
    target = np.zeros(d.grid_shape, np.float32)
    target[4 + a, 6 + b] = 1.0
    res = one_step_hologram(d, target, seed=0)
    r, c = np.indices(d.slm_shape)
    expected = _wrap(2 * math.pi * (a * r / 8 + b * c / 12))
    np.testing.assert_allclose(_wrap(res.phase - res.phase[0, 0] - expected), 0, atol=1e-5)
    inten = d.intensity(res.field)
    assert np.unravel_index(np.argmax(inten), inten.shape) == (4 + a, 6 + b)
    assert inten.max() == pytest.approx(inten.sum(), rel=1e-5)


def test_one_step_complex_slm_keeps_amplitude():
    d = ScatteringDisplay((6, 6), 2, mask_seed=1)
    t = np.random.default_rng(0).random(d.grid_shape)
    res = one_step_hologram(d, t, seed=1, slm="complex")
    amp = np.abs(res.field)
    assert amp.max() == pytest.approx(1.0) and amp.min() < 0.9


@pytest.fixture(scope="module")
def camera96():
    return prepare_target(load_bundled("camera"), 96)


def test_methods_order_after_the_perceptual_filter(camera96):
    d = ScatteringDisplay((24, 24), 4, mask_seed=0)
    n_slm = 24 * 24
    psnr = {}
    for name, loss in (("l2", IntensityLoss.l2()), ("frequency", IntensityLoss.frequency())):
        res = optimize_hologram(d, camera96, loss, 100, seed=1)
        psnr[name] = image_metrics(d.intensity(res.field), camera96, n_slm)["psnr_full"]
        h = res.history
        assert len(h.objective) == len(h.seconds) == res.iterations == 100
        assert h.objective[-1] < h.objective[0]
        assert res.stop_reason == "iterations"
        np.testing.assert_allclose(np.abs(res.field), 1.0, rtol=1e-5)  # phase-only (Eq. A.6)
    one = one_step_hologram(d, camera96, seed=1)
    psnr["one-step"] = image_metrics(d.intensity(one.field), camera96, n_slm)["psnr_full"]
    assert psnr["frequency"] > psnr["l2"] + 1.0 > psnr["one-step"] + 1.0


@pytest.mark.parametrize("loss,base,per_backtrack", [
    (IntensityLoss.l2(), 2.0, 1.0),
    (IntensityLoss.frequency(), 3.5, 1.5),
    (IntensityLoss.spatial(), 5.0, 2.0),
])
def test_fft_budget_per_iteration(loss, base, per_backtrack):
    d = ScatteringDisplay((16, 20), 2, mask_seed=2)
    t = np.random.default_rng(1).random(d.grid_shape)
    res = optimize_hologram(d, t, loss, 12, step_scale=64.0)  # forces early backtracks
    ex = res.history.extra
    assert sum(ex["backtracks"]) > 0
    for f, b in zip(ex["ffts"], ex["backtracks"], strict=True):
        assert f == base + per_backtrack * b
    assert base <= res.ffts_per_iteration < base + per_backtrack * 2
    assert ex["step"][-1] < 64.0 / 4  # backtracking lowered the step


def test_complex_slm_beats_phase_only(camera96):
    d = ScatteringDisplay((24, 24), 4, mask_seed=0)
    loss = IntensityLoss.frequency()
    ph = optimize_hologram(d, camera96, loss, 80, seed=2)
    cx = optimize_hologram(d, camera96, loss, 80, seed=2, slm="complex")
    assert np.abs(cx.field).max() <= 1.0 + 1e-6
    assert cx.loss < ph.loss
    m_ph = image_metrics(d.intensity(ph.field), camera96, 576)
    m_cx = image_metrics(d.intensity(cx.field), camera96, 576)
    assert m_cx["psnr_full"] > m_ph["psnr_full"]


def test_spatial_weights_favour_the_fovea(camera96):
    d = ScatteringDisplay((24, 24), 4, mask_seed=0)
    freq = optimize_hologram(d, camera96, IntensityLoss.frequency(), 80, seed=2)
    fov = optimize_hologram(d, camera96, IntensityLoss.spatial(), 80, seed=2)
    m_f = image_metrics(d.intensity(freq.field), camera96, 576)
    m_s = image_metrics(d.intensity(fov.field), camera96, 576)
    assert m_s["psnr_centre"] > m_f["psnr_centre"] + 2.0
    assert m_s["psnr_full"] < m_f["psnr_full"]


def test_two_planes_show_two_images():
    a = prepare_target(load_bundled("camera"), 64)
    b = prepare_target(load_bundled("coins"), 64)
    d = ScatteringDisplay((32, 32), 2, mask_seed=0, planes_mm=(0.0, 2.0), focal_length_mm=5.0)
    res = optimize_hologram(d, np.stack([a, b]), IntensityLoss.frequency(), 120, seed=0)
    inten = d.intensity(res.field)
    n = 32 * 32
    own = [image_metrics(inten[0], a, n)["psnr_full"], image_metrics(inten[1], b, n)["psnr_full"]]
    cross = [image_metrics(inten[0], b, n)["psnr_full"],
             image_metrics(inten[1], a, n)["psnr_full"]]
    assert own[0] > cross[0] + 1.0 and own[1] > cross[1] + 1.0
    assert res.ffts_per_iteration >= 7.0  # twice the single-plane budget


def test_no_mask_reference_at_native_etendue(camera96):
    native = prepare_target(load_bundled("camera"), 24)
    d, res = no_mask_hologram(native, IntensityLoss.frequency(), steps=60)
    assert d.k == 1 and d.grid_shape == (24, 24)
    m = image_metrics(d.intensity(res.field), native, 24 * 24)
    assert m["psnr_full"] > 20.0


def test_checkpoints_callback_and_determinism():
    d = ScatteringDisplay((12, 12), 2, mask_seed=4)
    t = np.random.default_rng(3).random(d.grid_shape)
    seen = []

    def cb(it, field, loss):
        seen.append((it, loss))
        return it == 7

    r = optimize_hologram(d, t, IntensityLoss.frequency(), 20, checkpoints=(3, 5), callback=cb)
    assert r.iterations == 7 and r.stop_reason == "stopped by callback"
    assert sorted(r.checkpoints) == [3, 5] and r.checkpoint_seconds[5] >= r.checkpoint_seconds[3]
    assert [s for s, _ in seen] == list(range(1, 8))
    r1 = optimize_hologram(d, t, IntensityLoss.frequency(), 10, seed=5)
    r2 = optimize_hologram(d, t, IntensityLoss.frequency(), 10, seed=5)
    np.testing.assert_allclose(r1.field, r2.field, atol=1e-5)
    r3 = optimize_hologram(d, t, IntensityLoss.frequency(), 10, init=r1.phase)
    assert r3.history.objective[0] <= r1.history.objective[-1] * 1.01


def test_projection():
    v = np.array([3 + 4j, 0, 0.5j], np.complex64)
    np.testing.assert_allclose(project(v.copy(), "phase"), [0.6 + 0.8j, 1, 1j], atol=1e-7)
    np.testing.assert_allclose(project(v.copy(), "complex"), [0.6 + 0.8j, 0, 0.5j], atol=1e-7)


@pytest.mark.parametrize("kwargs,msg", [
    (dict(steps=0), "steps"),
    (dict(step_scale=-1.0), "step_scale"),
    (dict(step_growth=0.5), "step_growth"),
    (dict(slm="amplitude"), "slm"),
    (dict(loss="l2"), "IntensityLoss"),
    (dict(init=np.zeros((3, 3))), "init"),
    (dict(init="zeros"), "init"),
])
def test_bad_optimiser_input(kwargs, msg):
    d = ScatteringDisplay((4, 4), 2)
    with pytest.raises(ReconInputError, match=msg):
        optimize_hologram(d, np.ones(d.grid_shape), **kwargs)
    with pytest.raises(ReconInputError, match="ScatteringDisplay"):
        optimize_hologram("display", np.ones(d.grid_shape))

"""Losses (Eq. 7.16-7.19, 7.23) and the Wirtinger gradient (Eq. A.7-A.9).

The Butterworth passband is counted against the Gauss circle problem, the losses are
compared with a plain float64 numpy implementation, and the gradient with a hand
computation and with central finite differences in double precision.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from recon.cgh import (
    IntensityLoss,
    ScatteringDisplay,
    butterworth_lowpass,
    cutoff_radius,
    foveation_map,
    loss_and_gradient,
    lowpass,
    passband_count,
)
from recon.errors import ReconInputError


def _rand_c(rng, shape):
    return rng.standard_normal(shape) + 1j * rng.standard_normal(shape)


def test_passband_holds_as_many_frequencies_as_slm_pixels_hand_count():
    # 16 x 16 SLM: r0^2 = 256 / pi = 81.49, so the passband is x^2 + y^2 <= 81:
    # the Gauss circle count N(9) = 253 lattice points (hand/brute count below)
    assert cutoff_radius(256) ** 2 == pytest.approx(256 / math.pi)
    brute = sum(1 for x in range(-10, 11) for y in range(-10, 11) if x * x + y * y <= 81)
    assert brute == 253
    assert passband_count((64, 64), 256) == 253
    assert passband_count((64, 96), 256) == 253  # independent of the grid's aspect


@pytest.mark.parametrize("slm,k", [((540, 960), 4), ((120, 120), 2), ((80, 80), 6)])
def test_passband_count_matches_slm_pixel_count(slm, k):
    n = slm[0] * slm[1]
    grid = (slm[0] * k, slm[1] * k)
    assert passband_count(grid, n) == pytest.approx(n, rel=4.0 / math.sqrt(n))


def test_butterworth_shape_and_layouts():
    grid, n = (48, 64), 144
    h = butterworth_lowpass(grid, n, layout="full")
    assert h[0, 0] == 1.0 and h.dtype == np.float32
    r0 = cutoff_radius(n)
    # 5th order: c_f = 1 / (1 + (f^2/r0^2)^5) -> 1/2 at r0, 1/(1 + 2^10) at 2 r0
    fx = 2 * r0
    assert 1.0 / (1.0 + (fx * fx / (r0 * r0)) ** 5) == pytest.approx(1 / 1025)
    assert h[0, 13] == pytest.approx(1.0 / (1.0 + (13 ** 2 / r0 ** 2) ** 5), rel=1e-6)
    hr = butterworth_lowpass(grid, n, layout="rfft")
    np.testing.assert_array_equal(hr, h[:, : grid[1] // 2 + 1])
    hc = butterworth_lowpass(grid, n, layout="centred")
    np.testing.assert_array_equal(hc, np.fft.fftshift(h))
    with pytest.raises(ReconInputError):
        butterworth_lowpass(grid, n, layout="polar")


def test_lowpass_removes_the_highest_frequencies():
    grid = (32, 32)
    checker = np.indices(grid).sum(0) % 2 * 2.0 - 1.0
    out = lowpass(checker, butterworth_lowpass(grid, 64).astype(np.float64))
    assert np.abs(out).max() < 1e-3
    flat = lowpass(np.ones(grid), butterworth_lowpass(grid, 64).astype(np.float64))
    np.testing.assert_allclose(flat, 1.0, atol=1e-12)


def test_foveation_map_centre_one_periphery_floor():
    w = foveation_map((200, 240))
    assert w[100, 120] == 1.0
    assert w[0, 0] == pytest.approx(0.1, abs=1e-6)
    assert w.min() >= 0.1 - 1e-7 and w.max() <= 1.0
    r = np.hypot(np.arange(200)[:, None] - 100, np.arange(240)[None, :] - 120)
    assert np.all(w[r <= 50] == 1.0)  # radius = min(shape)/4
    row = w[100, 120:]
    assert np.all(np.diff(row) <= 0)  # falls off monotonically
    moved = foveation_map((200, 240), centre=(50, 60))
    assert moved[50, 60] == 1.0 and moved[100, 120] < 1.0


def _reference_loss(display, s, target, loss):
    """Plain float64 numpy version of Eq. 7.16/7.17/7.19 summed over planes (Eq. 7.23)."""
    gy, gx = display.grid_shape
    k = display.k
    x0 = np.kron(s, np.ones((k, k)))
    total_power = float(display.mask_energy.astype(np.float64).sum())
    t = np.asarray(target, np.float64).reshape(display.n_planes, gy, gx)
    h = butterworth_lowpass((gy, gx), s.size, loss.order).astype(np.float64)
    w = loss.weight_map((gy, gx))
    acc = 0.0
    for p in range(display.n_planes):
        m = display.plane_masks[p].astype(np.complex128)
        inten = np.abs(np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(m * x0), norm="ortho"))) ** 2
        tn = t[p] * total_power / t[p].sum()
        sigma = tn.sum() / inten.sum() if loss.match_mean else 1.0
        r = sigma * inten - tn
        if loss.lowpass:
            r = lowpass(r, h)
        if w is not None:
            r = w.astype(np.float64) * r
        acc += 0.5 * float(np.sum(r * r))
    return acc


LOSSES = [IntensityLoss.l2(), IntensityLoss.frequency(), IntensityLoss.spatial(),
          IntensityLoss.spatial(lowpass=False), IntensityLoss.l2(match_mean=False),
          IntensityLoss.frequency(match_mean=False)]


@pytest.mark.parametrize("loss", LOSSES, ids=lambda ls: f"{ls.name}-{ls.lowpass}-{ls.match_mean}")
@pytest.mark.parametrize("planes", [(0.0,), (0.0, 0.5)])
def test_loss_matches_reference_and_gradient_matches_finite_differences(loss, planes):
    rng = np.random.default_rng(7)
    d = ScatteringDisplay((6, 8), 2, mask_seed=3, planes_mm=planes, focal_length_mm=15.0)
    # float32 targets: the optimiser stores targets in single precision
    target = rng.random((d.n_planes, *d.grid_shape)).squeeze().astype(np.float32)
    s = _rand_c(rng, d.slm_shape)
    val, g = loss_and_gradient(d, s, target, loss, double=True)
    assert g.dtype == np.complex128 and g.shape == d.slm_shape
    # single plane: equal to rounding; with a Fresnel plane the complex64 defocus phase
    # has |h| = 1 only to 1e-7, and the optimiser takes sum I from Parseval (exact |h| = 1)
    assert val == pytest.approx(_reference_loss(d, s, target, loss),
                                rel=1e-9 if len(planes) == 1 else 1e-6)
    for _ in range(3):
        ds = _rand_c(rng, d.slm_shape)
        eps = 1e-5
        lp, _ = loss_and_gradient(d, s + eps * ds, target, loss, double=True)
        lm, _ = loss_and_gradient(d, s - eps * ds, target, loss, double=True)
        fd = (lp - lm) / (2 * eps)
        assert np.vdot(g, ds).real == pytest.approx(fd, rel=1e-7, abs=1e-9 * abs(val))


def test_single_precision_gradient_agrees_with_double():
    rng = np.random.default_rng(2)
    d = ScatteringDisplay((10, 12), 4, mask_seed=0)
    target = rng.random(d.grid_shape)
    s = np.exp(1j * rng.uniform(-np.pi, np.pi, d.slm_shape))
    v32, g32 = loss_and_gradient(d, s, target)
    v64, g64 = loss_and_gradient(d, s, target, double=True)
    assert g32.dtype == np.complex64
    assert v32 == pytest.approx(v64, rel=1e-4)
    assert np.linalg.norm(g32 - g64) <= 1e-3 * np.linalg.norm(g64)


def test_gradient_hand_computed_single_pixel():
    # 1 x 1 SLM, no mask, k = 1: y = s, I = |s|^2; the target is normalised to the
    # power of a unit field (T = 1); L = 1/2 (|s|^2 - 1)^2, g = 2 dL/d(conj s)
    # = 2 (|s|^2 - 1) s.  s = 2: L = 4.5, g = 12.  s = 1 + i: L = 0.5, g = 2 + 2i.
    d = ScatteringDisplay((1, 1), 1, mask="clear")
    loss = IntensityLoss.l2(match_mean=False)
    val, g = loss_and_gradient(d, np.array([[2.0 + 0j]]), np.array([[5.0]]), loss, double=True)
    assert val == pytest.approx(4.5) and g[0, 0] == pytest.approx(12.0)
    val, g = loss_and_gradient(d, np.array([[1 + 1j]]), np.array([[0.3]]), loss, double=True)
    assert val == pytest.approx(0.5) and g[0, 0] == pytest.approx(2 + 2j)


def test_mean_matching_makes_the_loss_blind_to_brightness():
    rng = np.random.default_rng(4)
    d = ScatteringDisplay((6, 6), 2, mask_seed=5)
    target = rng.random(d.grid_shape)
    s = _rand_c(rng, d.slm_shape)
    v1, g1 = loss_and_gradient(d, s, target, IntensityLoss.frequency(), double=True)
    v2, _ = loss_and_gradient(d, 3.0 * s, target, IntensityLoss.frequency(), double=True)
    assert v2 == pytest.approx(v1, rel=1e-10)
    assert np.vdot(g1, s).real == pytest.approx(0.0, abs=1e-9 * np.linalg.norm(g1) *
                                                np.linalg.norm(s))


def test_bad_loss_inputs():
    d = ScatteringDisplay((4, 4), 2)
    s = np.ones(d.slm_shape, complex)
    with pytest.raises(ReconInputError, match="shape"):
        loss_and_gradient(d, s, np.ones((4, 4)))
    with pytest.raises(ReconInputError, match=">= 0"):
        loss_and_gradient(d, s, -np.ones(d.grid_shape))
    with pytest.raises(ReconInputError, match="all zero"):
        loss_and_gradient(d, s, np.zeros(d.grid_shape))
    with pytest.raises(ReconInputError, match="weights"):
        loss_and_gradient(d, s, np.ones(d.grid_shape), IntensityLoss.spatial(np.ones((3, 3))))
    with pytest.raises(ReconInputError):
        IntensityLoss.spatial(None)
    with pytest.raises(ReconInputError):
        foveation_map((10, 10), floor=2.0)

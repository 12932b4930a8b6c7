"""The numerics of the SLM phase-LUT calibration on synthetic data: the zero-order
fraction model and its inverse, unfolding past pi and 2 pi, the two-pass
combination, the monotone LUT fit and the order geometry."""

from __future__ import annotations

import numpy as np
import pytest

from calibration_routines import slm_lut_analysis as ana
from instrument.acquisition.plan import PlanError

GRAY = np.round(np.linspace(0, 255, 32))
TRUTH = 2.3 * np.pi * ((GRAY / 255) ** 1.5 * 0.7 + 0.3 * GRAY / 255)


def _fraction(dphi, beta):
    c = np.cos(dphi / 2) ** 2
    return c / (c + beta * (1 - c))


def _fold(x):
    return np.abs((np.asarray(x) + np.pi) % (2 * np.pi) - np.pi)


def test_folded_phase_inverts_the_fraction_model():
    dphi = np.linspace(0, np.pi, 50)
    np.testing.assert_allclose(ana.folded_phase(_fraction(dphi, 0.8), 0.8), dphi, atol=1e-7)
    np.testing.assert_allclose(ana.folded_phase(_fraction(dphi + np.pi, 0.9), 0.9),
                               np.pi - dphi, atol=1e-7)


def test_unfold_monotone_recovers_a_response_past_two_pi():
    np.testing.assert_allclose(ana.unfold_monotone(GRAY, _fold(TRUTH)), TRUTH, atol=1e-9)


def test_two_passes_beat_one_near_the_folds():
    rng = np.random.default_rng(0)
    sigma = 0.01  # noise of the measured fraction

    def measure(dphi):
        c = np.clip(_fraction(dphi, 0.85) + rng.normal(0, sigma, dphi.shape), 0, 1)
        return ana.folded_phase(c, 0.85)

    ref = int(np.argmin(np.abs(TRUTH - np.pi / 2)))
    m1, m2 = measure(TRUTH), measure(TRUTH - TRUTH[ref])
    one, _, _ = ana.combine_passes(GRAY, m1)
    two, weight, detail = ana.combine_passes(GRAY, m1, m2, ref)
    err1, err2 = np.abs(one - TRUTH), np.abs(two - TRUTH)
    assert err2.max() < 0.06 < err1.max()
    assert np.sqrt(np.mean(err2**2)) < 0.5 * np.sqrt(np.mean(err1**2))
    assert two[0] == 0 and detail["rms_rad"] < 0.05 and weight.shape == GRAY.shape


def test_fit_lut_is_monotone_and_interpolates():
    noisy = TRUTH + np.where(np.arange(GRAY.size) == 10, -0.3, 0.0)  # one dip
    lut = ana.fit_lut(GRAY, noisy, np.ones_like(GRAY))
    assert lut.shape == (256,) and np.all(np.diff(lut) >= 0)
    exact = 2.3 * np.pi * ((np.arange(256) / 255) ** 1.5 * 0.7 + 0.3 * np.arange(256) / 255)
    keep = np.abs(np.arange(256) - GRAY[10]) > 16
    assert np.abs(lut - exact)[keep].max() < 0.02
    with pytest.raises(PlanError, match="from 0 to 255"):
        ana.fit_lut(GRAY[1:], TRUTH[1:], np.ones(GRAY.size - 1))
    with pytest.raises(PlanError, match="does not rise"):
        ana.fit_lut(GRAY, np.zeros_like(GRAY), np.ones_like(GRAY))


def test_orders_are_found_and_measured_on_a_synthetic_frame():
    frame = np.full((64, 96), 100.0)
    zero, d = (40.3, 30.0), (12.0, 1.0)
    for m, e in ((0, 500.0), (1, 300.0), (-1, 310.0), (3, 30.0), (-3, 33.0)):
        x, y = zero[0] + m * d[0], zero[1] + m * d[1]
        frame[round(y), round(x)] += e
    xy, snr = ana.spot_centroid(frame, 5)
    assert xy == pytest.approx((40, 30)) and snr > 1e6
    offset = ana.find_order_offset(frame, (40.0, 30.0), 5, 3)
    assert offset == pytest.approx((-12.0, -1.0)) or offset == pytest.approx((12.0, 1.0))
    orders = ana.visible_orders(frame.shape, zero, d, 3, 5)
    assert orders == [-2, -1, 1, 2, 3]  # -3 at x = 4.3: its ring would leave the frame
    e = ana.order_energies(frame, zero, d, [0, -1, 1], 5, 3)
    np.testing.assert_allclose(e, [500, 310, 300])
    lopsided = np.full((64, 96), 100.0)
    lopsided[30, 40] += 500.0
    lopsided[31, 52] += 300.0  # a +1 order without its -1 twin
    with pytest.raises(PlanError, match="symmetric"):
        ana.find_order_offset(lopsided, (40.0, 30.0), 5, 3)
    with pytest.raises(PlanError, match="closer than a window"):
        ana.find_order_offset(frame, (40.0, 30.0), 11, 6)
    with pytest.raises(PlanError, match="diffracted any light"):
        ana.diffracted_share(np.ones(3), np.zeros(3), np.ones(3))
    assert ana.diffracted_share(np.zeros(3), 0.8 * np.ones(3), np.ones(3)) == pytest.approx(0.8)

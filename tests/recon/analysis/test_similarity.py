"""Tests of recon.analysis.similarity: cross-correlation and PSF similarity across a stack."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage, signal

from recon.analysis.psf import inner_product
from recon.analysis.similarity import cross_correlation, inner_products_with, stack_similarity
from recon.errors import ReconInputError


def pattern(seed: int = 0, shape: tuple[int, int] = (40, 48)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return ndimage.gaussian_filter(rng.random(shape), 1.0) ** 4


def test_cross_correlation_matches_direct_correlation_and_normalisation():
    a, b = pattern(0), pattern(1)
    cc = cross_correlation(a, b)
    assert cc.shape == (79, 95) and cc.dtype == np.float64
    # c[t] = sum_u a[u] b[u + t]  ==  correlate(b, a) in scipy's convention
    direct = signal.correlate(b, a, mode="full", method="direct")
    np.testing.assert_allclose(cc, direct / (np.linalg.norm(a) * np.linalg.norm(b)), atol=1e-12)
    assert np.all(np.abs(cc) <= 1 + 1e-12)


def test_autocorrelation_peak_is_one_at_centre_and_symmetric():
    a = pattern(2)
    ac = cross_correlation(a, a)
    rows, cols = a.shape
    assert ac[rows - 1, cols - 1] == pytest.approx(1.0, abs=1e-12)
    assert np.unravel_index(np.argmax(ac), ac.shape) == (rows - 1, cols - 1)
    np.testing.assert_allclose(ac, ac[::-1, ::-1], atol=1e-12)


def test_cross_correlation_peak_at_the_shift_and_equals_inner_product():
    a = np.zeros((40, 48))
    a[10:30, 12:36] = pattern(3, (20, 24))
    b = np.roll(a, (3, -5), axis=(0, 1))  # nothing leaves the frame
    cc = cross_correlation(a, b)
    peak = np.unravel_index(np.argmax(cc), cc.shape)
    assert (peak[0] - 39, peak[1] - 47) == (3, -5)
    assert cc[peak] == pytest.approx(1.0)
    # zero lag is the normalised inner product
    assert cc[39, 47] == pytest.approx(inner_product(a, b))


def test_inner_products_with_hand_values():
    base = np.zeros((8, 8))
    base[2, 2] = 1.0
    other = np.zeros((8, 8))
    other[5, 5] = 1.0
    both = base + other  # <base, both> / (1 * sqrt 2) = 1/sqrt(2)
    stack = np.stack([base, other, both])
    ip = inner_products_with(stack, 0)
    np.testing.assert_allclose(ip, [1.0, 0.0, 1 / np.sqrt(2)])
    np.testing.assert_allclose(inner_products_with(stack, -1), [1 / np.sqrt(2)] * 2 + [1.0])


def test_stack_similarity_contents():
    stack = np.stack([pattern(s) for s in range(4)])
    depths = np.array([30.0, 10.0, 20.0, 40.0])
    out = stack_similarity(stack, depths)
    assert out["nearest"] == 1 and out["farthest"] == 3 and out["index"] == 2
    assert out["autocorrelation_x"].shape == (4, 95)
    assert out["autocorrelation_y"].shape == (4, 79)
    assert out["lags_x_px"][47] == 0 and out["lags_y_px"][0] == -39
    # the central lines are the 2D autocorrelation's central row / column
    for k in range(4):
        ac = cross_correlation(stack[k], stack[k])
        np.testing.assert_allclose(out["autocorrelation_x"][k], ac[39], atol=1e-12)
        np.testing.assert_allclose(out["autocorrelation_y"][k], ac[:, 47], atol=1e-12)
    cc = cross_correlation(stack[1], stack[3])
    assert out["cross_correlation_max"] == pytest.approx(cc.max())
    dy, dx = out["cross_correlation_argmax_px"]
    assert cc[dy + 39, dx + 47] == pytest.approx(cc.max())
    np.testing.assert_allclose(out["cross_correlation_x"], cc[39])
    np.testing.assert_allclose(out["inner_products"], inner_products_with(stack, 2))
    # without depths: first and last
    plain = stack_similarity(stack, index=0)
    assert (plain["nearest"], plain["farthest"], plain["index"]) == (0, 3, 0)
    assert plain["depths_mm"] is None


def test_refusals():
    a = pattern(0)
    with pytest.raises(ReconInputError, match="same shape"):
        cross_correlation(a, a[:-1])
    with pytest.raises(ReconInputError, match="all zero"):
        cross_correlation(a, np.zeros_like(a))
    stack = np.stack([a, a])
    with pytest.raises(ReconInputError, match="outside the stack"):
        inner_products_with(stack, 2)
    with pytest.raises(ReconInputError, match="integer"):
        inner_products_with(stack, 1.0)
    with pytest.raises(ReconInputError, match="one depth per PSF"):
        stack_similarity(stack, [1.0])
    with pytest.raises(ReconInputError, match="distinct"):
        stack_similarity(stack, [1.0, 1.0])
    with pytest.raises(ReconInputError, match=r"stack\[1\] is all zero"):
        stack_similarity(np.stack([a, np.zeros_like(a)]))
    with pytest.raises(ReconInputError, match="3D"):
        stack_similarity(a)

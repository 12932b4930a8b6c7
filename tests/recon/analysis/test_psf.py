"""Tests of recon.analysis.psf: DCT background removal, similarity, registration, border."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.fft
from scipy import ndimage

from recon.analysis import (
    border_energy_fraction,
    inner_product,
    normalized_correlation,
    register_shift,
    remove_background_dct,
)
from recon.errors import ReconInputError


def speckle_psf(n: int = 96, radius: float = 20.0, seed: int = 0) -> np.ndarray:
    """PSF-like image: fully developed speckle (|field|^2) inside a disc, dark outside."""
    rng = np.random.default_rng(seed)
    field = ndimage.gaussian_filter(rng.standard_normal((n, n)), 1.5) + 1j * (
        ndimage.gaussian_filter(rng.standard_normal((n, n)), 1.5)
    )
    yy, xx = np.mgrid[:n, :n] - (n - 1) / 2.0
    return np.abs(field) ** 2 * (yy**2 + xx**2 <= radius**2)


def dct_basis(shape: tuple[int, int], ky: int, kx: int) -> np.ndarray:
    coeffs = np.zeros(shape)
    coeffs[ky, kx] = 1.0
    return scipy.fft.idctn(coeffs, norm="ortho")


# ----------------------------------------------------------------------------- DCT background


def test_dct_n_low_1_removes_exactly_the_mean():
    rng = np.random.default_rng(1)
    img = rng.random((20, 31)) * 100
    out = remove_background_dct(img, 1, clip_negative=False)
    np.testing.assert_allclose(out, img - img.mean(), atol=1e-10)
    assert out.dtype == np.float64 and out.shape == img.shape


def test_dct_removes_low_block_and_keeps_the_rest():
    shape = (40, 50)
    background = (
        30 * dct_basis(shape, 0, 0) + 7 * dct_basis(shape, 4, 2) - 5 * dct_basis(shape, 1, 4)
    )
    kept = 3 * dct_basis(shape, 5, 0) + 2 * dct_basis(shape, 0, 5)
    out = remove_background_dct(background + kept, 5, clip_negative=False)
    np.testing.assert_allclose(out, kept, atol=1e-12)


def test_dct_rectangular_block():
    shape = (32, 32)
    a = dct_basis(shape, 0, 6)  # inside (1, 7), outside (7, 1)
    np.testing.assert_allclose(remove_background_dct(a, (1, 7), clip_negative=False), 0, atol=1e-12)
    np.testing.assert_allclose(remove_background_dct(a, (7, 1), clip_negative=False), a, atol=1e-12)


def test_dct_recovers_spots_on_smooth_background_and_clips():
    n = 64
    spots = np.zeros((n, n))
    spots[20, 30] = spots[40, 12] = 50.0
    yy, xx = np.mgrid[:n, :n] / n
    background = 200 + 40 * np.cos(np.pi * yy) + 25 * xx**2
    out = remove_background_dct(spots + background, 10)
    assert out.min() >= 0.0
    # the spots survive nearly unchanged; the background far from them is gone
    assert out[20, 30] == pytest.approx(50.0, rel=0.05)
    assert out[40, 12] == pytest.approx(50.0, rel=0.05)
    assert np.median(out) < 0.5
    unclipped = remove_background_dct(spots + background, 10, clip_negative=False)
    assert unclipped.min() < 0.0


def test_dct_stack_is_per_frame():
    rng = np.random.default_rng(2)
    stack = rng.random((3, 16, 24))
    out = remove_background_dct(stack, 3)
    assert out.shape == stack.shape
    for k in range(3):
        np.testing.assert_allclose(out[k], remove_background_dct(stack[k], 3), atol=1e-12)


@pytest.mark.parametrize(
    ("image", "n_low", "match"),
    [
        (np.full((8, 8), np.nan), 2, "NaN"),
        (np.ones((8, 8)), 0, ">= 1"),
        (np.ones((8, 8)), 9, "larger than the image"),
        (np.ones((8, 8)), (2, 9), "larger than the image"),
        (np.ones((8, 8)), (2, 2, 2), "pair"),
        (np.ones((8, 8)), True, "integer"),
        (np.ones(8), 2, "2D or 3D"),
        (np.ones((2, 2, 8, 8)), 2, "2D or 3D"),
    ],
)
def test_dct_refuses_bad_input(image, n_low, match):
    with pytest.raises(ReconInputError, match=match):
        remove_background_dct(image, n_low)


# ----------------------------------------------------------------------------- similarity


def test_inner_product_hand_values():
    assert inner_product([1.0, 0.0], [1.0, 1.0]) == pytest.approx(1 / math.sqrt(2))
    # not mean-subtracted: <(1,2),(2,1)> / 5 = 0.8 while the Pearson r is -1
    assert inner_product([1.0, 2.0], [2.0, 1.0]) == pytest.approx(0.8)
    assert normalized_correlation([1.0, 2.0], [2.0, 1.0]) == pytest.approx(-1.0)
    assert inner_product(np.eye(3), 5 * np.eye(3)) == pytest.approx(1.0)
    assert inner_product([[1, 0], [0, 0]], [[0, 0], [0, 1]]) == 0.0


def test_normalized_correlation_is_pearson_and_ignores_pedestal_and_gain():
    rng = np.random.default_rng(3)
    a = rng.random((10, 12))
    b = a + 0.3 * rng.random((10, 12))
    r = np.corrcoef(a.ravel(), b.ravel())[0, 1]
    assert normalized_correlation(a, b) == pytest.approx(r, abs=1e-12)
    assert normalized_correlation(a, 4 * b + 100) == pytest.approx(r, abs=1e-12)
    # the inner product, in contrast, tends to 1 when both share a bright pedestal
    c = rng.random((10, 12))
    assert abs(normalized_correlation(a + 100, c + 100)) < 0.5
    assert inner_product(a + 100, c + 100) > 0.999


@pytest.mark.parametrize("func", [inner_product, normalized_correlation])
def test_similarity_refusals(func):
    with pytest.raises(ReconInputError, match="shape"):
        func(np.ones((3, 3)), np.ones((3, 4)))
    with pytest.raises(ReconInputError, match="NaN"):
        func(np.ones(3), [1.0, np.inf, 1.0])
    with pytest.raises(ReconInputError, match="all zero|constant"):
        func(np.zeros((3, 3)), np.ones((3, 3)))
    with pytest.raises(ReconInputError, match="non-numeric"):
        func(np.array(["a", "b"]), np.ones(2))


def test_normalized_correlation_refuses_constant_image():
    with pytest.raises(ReconInputError, match="constant"):
        normalized_correlation(np.full((4, 4), 3.0), np.arange(16.0).reshape(4, 4))


# ----------------------------------------------------------------------------- registration


@pytest.mark.parametrize("shift", [(5, -7), (-12, 3), (0, 20)])
def test_register_integer_roll(shift):
    ref = speckle_psf()
    moved = np.roll(ref, shift, axis=(0, 1))
    assert register_shift(ref, moved) == pytest.approx(shift, abs=1e-9)
    # swapping the roles flips the sign
    assert register_shift(moved, ref) == pytest.approx((-shift[0], -shift[1]), abs=1e-9)


@pytest.mark.parametrize("shift", [(3.3, -5.6), (-7.25, 2.55), (-0.4, -0.85), (25.3, -22.65)])
def test_register_subpixel_shift_both_signs(shift):
    ref = speckle_psf(seed=4)
    moved = ndimage.shift(ref, shift, order=3, mode="constant")
    dy, dx = register_shift(ref, moved, upsample=20)
    assert dy == pytest.approx(shift[0], abs=0.06)
    assert dx == pytest.approx(shift[1], abs=0.06)
    # the convention of the docstring: image[r, c] ~ reference[r - dy, c - dx]
    back = ndimage.shift(moved, (-dy, -dx), order=3, mode="constant")
    assert normalized_correlation(back[30:66, 30:66], ref[30:66, 30:66]) > 0.98


def test_register_large_shift_does_not_wrap():
    # a shift of more than half the image would alias without the zero-padding
    ref = np.zeros((64, 64))
    ref[5:15, 5:15] = speckle_psf(10, 6.0, seed=5)
    moved = np.roll(ref, (40, 44), axis=(0, 1))
    assert register_shift(ref, moved) == pytest.approx((40.0, 44.0), abs=1e-9)
    assert register_shift(moved, ref) == pytest.approx((-40.0, -44.0), abs=1e-9)


def test_register_self_is_zero_and_refusals():
    ref = speckle_psf(48, 10.0)
    assert register_shift(ref, ref) == (0.0, 0.0)
    with pytest.raises(ReconInputError, match="shape"):
        register_shift(ref, ref[:-1])
    with pytest.raises(ReconInputError, match="all zero"):
        register_shift(ref, np.zeros_like(ref))
    with pytest.raises(ReconInputError, match="upsample"):
        register_shift(ref, ref, upsample=0)
    with pytest.raises(ReconInputError, match="2D"):
        register_shift(ref[None], ref[None])


# ----------------------------------------------------------------------------- border


def gaussian_blob(shape, center, sigma):
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    return np.exp(-((yy - center[0]) ** 2 + (xx - center[1]) ** 2) / (2 * sigma**2))


def test_border_fraction_hand_values():
    flat = np.ones((10, 10))
    assert border_energy_fraction(flat, 0) == 0.0
    assert border_energy_fraction(flat, 1) == pytest.approx(36 / 100)
    assert border_energy_fraction(flat, 2) == pytest.approx(64 / 100)
    assert border_energy_fraction(flat, 5) == 1.0


def test_border_fraction_centred_vs_edge_blob():
    centred = gaussian_blob((64, 64), (31.5, 31.5), 3.0)
    assert border_energy_fraction(centred, 8) < 1e-9
    edge = gaussian_blob((64, 64), (2.0, 31.5), 3.0)
    assert border_energy_fraction(edge, 8) > 0.95
    corner = gaussian_blob((64, 64), (60.0, 60.0), 3.0)
    assert border_energy_fraction(corner, 4) > 0.5


def test_border_fraction_refusals():
    with pytest.raises(ReconInputError, match="negative"):
        border_energy_fraction(np.array([[1.0, -0.1], [0.0, 1.0]]), 0)
    with pytest.raises(ReconInputError, match="all zero"):
        border_energy_fraction(np.zeros((4, 4)), 1)
    with pytest.raises(ReconInputError, match="border_px"):
        border_energy_fraction(np.ones((4, 4)), -1)
    with pytest.raises(ReconInputError, match="border_px"):
        border_energy_fraction(np.ones((4, 4)), 1.5)

"""Tests of recon.analysis.conditioning: local condition number (Sec. 4.4, Fig. 4.5),
laterally and across depth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from recon.analysis.conditioning import (
    axial_layout,
    condition_vs_k,
    condition_vs_k_axial,
    local_condition_number,
    point_source_columns,
    stack_source_columns,
)
from recon.errors import ReconInputError


def caustic(n: int = 80, seed: int = 0, blur: float = 0.0) -> np.ndarray:
    """Bright thin lines along the zero set of a smooth random field, in a disc."""
    rng = np.random.default_rng(seed)
    f = ndimage.gaussian_filter(rng.standard_normal((n, n)), 4.0)
    f /= f.std()
    yy, xx = np.mgrid[:n, :n] - (n - 1) / 2.0
    h = np.exp(-((f / 0.3) ** 2)) * (yy**2 + xx**2 <= (0.3 * n) ** 2)
    return ndimage.gaussian_filter(h, blur) if blur else h


@pytest.mark.parametrize("c", [0.0, 0.6, 0.8, -0.5, 0.99])
def test_two_unit_columns_with_inner_product_c(c):
    # Gram matrix [[1, c], [c, 1]] has eigenvalues 1 +- c: cond = sqrt((1 + |c|) / (1 - |c|))
    a = np.zeros(10)
    a[0] = 1.0
    b = np.zeros(10)
    b[0], b[3] = c, math.sqrt(1 - c * c)
    cond = local_condition_number(np.stack([a, b], axis=1))
    assert cond == pytest.approx(math.sqrt((1 + abs(c)) / (1 - abs(c))), rel=1e-10)
    assert c != 0.8 or cond == pytest.approx(3.0)
    assert local_condition_number(np.stack([a, b], axis=1) * 7.0) == pytest.approx(cond)


def test_hand_values():
    assert local_condition_number(np.stack([[1.0, 0], [0, 1], [0, 0]])) == 1.0
    assert local_condition_number(np.array([[1.0, 0.8], [0.0, 0.6]])) == pytest.approx(3.0)


def test_constructed_svd():
    rng = np.random.default_rng(0)
    u, _ = np.linalg.qr(rng.standard_normal((200, 5)))
    v, _ = np.linalg.qr(rng.standard_normal((5, 5)))
    sv = np.array([10.0, 7.0, 3.0, 1.0, 0.25])
    cond = local_condition_number(u @ np.diag(sv) @ v.T)
    assert cond == pytest.approx(40.0, rel=1e-9)
    # a stack of images is flattened into columns
    images = (u @ np.diag(sv) @ v.T).T.reshape(5, 10, 20)
    assert local_condition_number(images) == pytest.approx(40.0, rel=1e-9)


def test_rank_deficient_is_inf():
    a = np.arange(1.0, 7.0)
    assert local_condition_number(np.stack([a, 2 * a], axis=1)) == math.inf


def test_point_source_columns_are_shifted_cropped_psfs():
    h = caustic(32)
    cols = point_source_columns(h, [(0, 0), (2, -3), (0.5, 0)])
    assert cols.shape == (32 * 32, 3) and cols.dtype == np.float64
    np.testing.assert_array_equal(cols[:, 0], h.ravel())
    expected = np.zeros_like(h)
    expected[2:, :-3] = h[:-2, 3:]  # down 2, left 3, zeros shifted in
    np.testing.assert_array_equal(cols[:, 1], expected.ravel())
    np.testing.assert_allclose(
        cols[:, 2], ndimage.shift(h, (0.5, 0.0), order=3, mode="constant").ravel()
    )
    single = point_source_columns(h, (1, 1))
    assert single.shape == (32 * 32, 1)
    # a shift beyond the frame leaves nothing
    assert not np.any(point_source_columns(h, (40, 0)))


def test_two_sources_match_the_inner_product_formula():
    h = caustic(64)
    cols = point_source_columns(h, [(0, 0), (0, 1)])
    a, b = cols[:, 0], cols[:, 1]
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    c = a @ b / (na * nb)
    # equal norms (nothing leaves the frame): cond = sqrt((1 + c) / (1 - c))
    assert na == pytest.approx(nb)
    assert condition_vs_k(h, 1, ks=[2]) == pytest.approx(math.sqrt((1 + c) / (1 - c)))


def test_condition_grows_with_k_towards_a_limit_and_with_closeness():
    h = caustic(80)
    ks = list(range(1, 17))
    near = condition_vs_k(h, 1, ks)
    far = condition_vs_k(h, 3, ks)
    assert near.shape == (16,) and near.dtype == np.float64
    assert near[0] == 1.0
    # nested sources: never decreases with k (interlacing)
    assert np.all(np.diff(near) >= -1e-9) and np.all(np.diff(far) >= -1e-9)
    # closer sources are worse conditioned
    assert np.all(near[1:] > far[1:])
    # approaching a limit: the increments shrink (last step much smaller than the first)
    steps = np.diff(near)
    assert steps[-1] < 0.3 * steps[0]
    assert steps[-1] < 0.05 * near[-1]
    # a blurrier PSF is worse conditioned
    assert condition_vs_k(caustic(80, blur=2.0), 1, [16])[0] > near[-1]


def test_grid_layout():
    h = caustic(80)
    grid = condition_vs_k(h, 2, ks=[4, 9, 16], layout="grid")
    assert grid.shape == (3,) and np.all(np.diff(grid) >= -1e-9)
    line_y = condition_vs_k(h, 2, ks=[4], axis="y")
    assert line_y[0] >= 1.0


def test_refusals():
    h = caustic(32)
    with pytest.raises(ReconInputError, match="more columns"):
        local_condition_number(np.ones((2, 3)))
    with pytest.raises(ReconInputError, match="all zero"):
        local_condition_number(np.zeros((4, 2)))
    with pytest.raises(ReconInputError, match="2D or 3D"):
        local_condition_number(np.ones(4))
    with pytest.raises(ReconInputError, match=r"\(k, 2\)"):
        point_source_columns(h, [(1, 2, 3)])
    with pytest.raises(ReconInputError, match="order"):
        point_source_columns(h, [(0.5, 0)], order=7)
    with pytest.raises(ReconInputError, match="separation_px"):
        condition_vs_k(h, 0)
    with pytest.raises(ReconInputError, match="ks"):
        condition_vs_k(h, 1, ks=[])
    with pytest.raises(ReconInputError, match="ks"):
        condition_vs_k(h, 1, ks=[0, 2])
    with pytest.raises(ReconInputError, match="layout"):
        condition_vs_k(h, 1, layout="ring")
    with pytest.raises(ReconInputError, match="axis"):
        condition_vs_k(h, 1, axis="z")


# ----------------------------------------------------------------------------- across depth


def _unit(n: int, i: int) -> np.ndarray:
    e = np.zeros(n)
    e[i] = 1.0
    return e


def known_stack(c: float = 0.6) -> np.ndarray:
    """Four 4 x 4 planes with hand-computable inner products: plane 0 = e0, plane 1 =
    c e0 + s e1 (so <p0, p1> = c), plane 2 = e5, plane 3 = e10 (unit vectors)."""
    s = math.sqrt(1 - c * c)
    planes = [_unit(16, 0), c * _unit(16, 0) + s * _unit(16, 1), _unit(16, 5), _unit(16, 10)]
    return np.stack(planes).reshape(4, 4, 4)


def test_axial_condition_on_a_known_matrix():
    c = 0.6
    st = known_stack(c)
    two = math.sqrt((1 + c) / (1 - c))  # Gram [[1, c], [c, 1]]: eigenvalues 1 +- c; = 2
    # k sources at consecutive planes from plane 0: {0, 1}, {0, 1, 2}, {0, 1, 2, 3}; the
    # Gram matrix is block diagonal with that 2 x 2 block and ones: same extremes
    got = condition_vs_k_axial(st, 1, ks=[1, 2, 3, 4], start_plane=0)
    np.testing.assert_allclose(got, [1.0, two, two, two], rtol=1e-12)
    assert two == pytest.approx(2.0)
    # two planes apart: planes 0, 2 (and 0, 2 only fit): orthogonal unit columns
    assert condition_vs_k_axial(st, 2, ks=[2], start_plane=0)[0] == pytest.approx(1.0)
    # starting at plane 1: planes 1, 2, 3 are orthonormal
    assert condition_vs_k_axial(st, 1, ks=[3], start_plane=1)[0] == pytest.approx(1.0)
    # the same source twice is rank deficient
    cols = stack_source_columns(st, [(0, 0, 0), (0, 0, 0)])
    assert local_condition_number(cols) == math.inf


def test_stack_source_columns_shift_each_plane():
    rng = np.random.default_rng(0)
    st = rng.random((3, 12, 14))
    cols = stack_source_columns(st, [(2, 0, 0), (0, 1, -2), (1, 0.5, 0)])
    assert cols.shape == (12 * 14, 3) and cols.dtype == np.float64
    np.testing.assert_array_equal(cols[:, 0], st[2].ravel())
    np.testing.assert_array_equal(cols[:, 1], point_source_columns(st[0], (1, -2))[:, 0])
    np.testing.assert_allclose(cols[:, 2], point_source_columns(st[1], (0.5, 0))[:, 0])


def test_axial_layout_line_and_xz_grid():
    line = axial_layout(10, 4, 2)
    # centred: span 6 planes in a 10-plane stack starts at plane 1
    np.testing.assert_array_equal(line, [[1, 0, 0], [3, 0, 0], [5, 0, 0], [7, 0, 0]])
    grid = axial_layout(8, 16, 1, separation_px=3.0, start_plane=2)
    assert grid.shape == (16, 3)
    np.testing.assert_array_equal(grid[:4], [[2, 0, -3], [2, 0, 0], [2, 0, 3], [2, 0, 6]])
    np.testing.assert_array_equal(grid[:, 0], np.repeat([2, 3, 4, 5], 4))
    assert np.all(axial_layout(8, 4, 1, separation_px=2.0, axis="y")[:, 2] == 0)


def test_axial_condition_of_a_scaled_caustic_stack():
    # PSF support growing with 1/z (Sec. 3.2): closer depths are worse conditioned,
    # and the condition number never decreases with k
    h = caustic(64)
    centre = np.array([31.5, 31.5])
    stack = np.stack([ndimage.affine_transform(h, np.eye(2) / s, centre - centre / s, order=1)
                      for s in 1.0 + 0.03 * np.arange(12)])
    near = condition_vs_k_axial(stack, 1, ks=range(2, 7))
    far = condition_vs_k_axial(stack, 2, ks=range(2, 7))
    assert np.all(np.diff(near) >= -1e-9) and np.all(near > far)
    xz = condition_vs_k_axial(stack, 1, ks=[4, 9], separation_px=2.0)
    assert xz.shape == (2,) and np.all(xz >= 1.0)


def test_axial_refusals():
    st = known_stack()
    with pytest.raises(ReconInputError, match="need 5 planes from plane 0, the stack has 4"):
        condition_vs_k_axial(st, 1, ks=[5])  # 5 sources, 4 planes
    with pytest.raises(ReconInputError, match="separation_planes"):
        condition_vs_k_axial(st, 0)
    with pytest.raises(ReconInputError, match="separation_px"):
        condition_vs_k_axial(st, 1, ks=[2], separation_px=-1.0)
    with pytest.raises(ReconInputError, match="start_plane"):
        condition_vs_k_axial(st, 1, ks=[2], start_plane=4)
    with pytest.raises(ReconInputError, match="integers in 0..3"):
        stack_source_columns(st, [(1.5, 0, 0)])
    with pytest.raises(ReconInputError, match=r"\(k, 3\)"):
        stack_source_columns(st, [(1, 0)])
    with pytest.raises(ReconInputError, match="all zero"):
        condition_vs_k_axial(np.zeros((3, 4, 4)), 1, ks=[2])
    with pytest.raises(ReconInputError, match="axis"):
        axial_layout(4, 2, 1, axis="z")

"""Tests for recon.volume.operator: the 3D forward model b = C sum_z h_z * v_z (Eq. 4.4).

Adjoint and dense checks as for the 2D operator, and the sum over depth checked
against independent 2D convolutions (the published Python peers lack the sum or
crop it wrongly; these tests catch either).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import convolve2d

from recon.errors import ReconInputError
from recon.operators import ConvolutionOperator, LinearOperator, PixelErasure
from recon.preprocess import box_bin
from recon.volume import (
    VolumeConvolutionOperator,
    _kernels3d,
    bin_stack,
    estimate_memory_bytes,
    fft_floor_seconds,
    normalize_psf_stack,
)


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def _stack(n_z, shape, seed=0) -> np.ndarray:
    return _rng(seed).random((n_z, *shape)).astype(np.float32)


def _adjoint_gap(op: LinearOperator, seed: int = 1) -> float:
    rng = _rng(seed)
    x = rng.standard_normal(op.shape_in).astype(np.float32)
    y = rng.standard_normal(op.shape_out).astype(np.float32)
    ax = op.forward(x).astype(np.float64)
    aty = op.adjoint(y).astype(np.float64)
    assert ax.shape == tuple(op.shape_out) and aty.shape == tuple(op.shape_in)
    lhs = np.vdot(ax, y.astype(np.float64))
    rhs = np.vdot(x.astype(np.float64), aty)
    return abs(lhs - rhs) / (np.linalg.norm(ax) * np.linalg.norm(y))


def _dense(shape_in, apply) -> np.ndarray:
    n_in = int(np.prod(shape_in))
    cols = []
    for k in range(n_in):
        e = np.zeros(n_in, np.float32)
        e[k] = 1.0
        cols.append(np.asarray(apply(e.reshape(shape_in)), np.float64).ravel())
    return np.stack(cols, axis=1)


# --------------------------------------------------------------------------- adjoint


@pytest.mark.parametrize("n_z,shape", [(1, (7, 9)), (3, (16, 12)), (5, (5, 6))])
@pytest.mark.parametrize("weighted", [False, True])
def test_adjoint(n_z, shape, weighted):
    weights = None
    if weighted:
        weights = _rng(5).random(shape).astype(np.float32)
        weights[weights < 0.2] = 0.0
    op = VolumeConvolutionOperator(_stack(n_z, shape), sensor_weights=weights)
    assert op.shape_in == (n_z, *op.padded_shape)
    assert all(p >= 2 * s for p, s in zip(op.padded_shape, shape, strict=True))
    assert op.ffts_per_apply == n_z + 1
    assert _adjoint_gap(op) < 1e-5


def test_outputs_are_float32_with_declared_shapes():
    op = VolumeConvolutionOperator(_stack(3, (7, 9)))
    x = _rng(2).random(op.shape_in)  # float64 in
    y = op.forward(x)
    assert y.dtype == np.float32 and y.shape == (7, 9)
    v = op.adjoint(y)
    assert v.dtype == np.float32 and v.shape == op.shape_in
    assert op.spectra.dtype == np.complex64
    assert op.spectra.shape == (3, op.padded_shape[0], op.padded_shape[1] // 2 + 1)


# --------------------------------------------------------------------------- sum over depth


@pytest.mark.parametrize("weighted", [False, True])
def test_forward_is_sum_of_independent_2d_convolutions(weighted):
    """A v == sum_z ConvolutionOperator(h_z) v_z, each 2D operator built on its own."""
    shape, n_z = (16, 12), 5
    stack = _stack(n_z, shape, seed=3)
    weights = _rng(4).random(shape).astype(np.float32) if weighted else None
    op = VolumeConvolutionOperator(stack, sensor_weights=weights)
    v = _rng(6).standard_normal(op.shape_in).astype(np.float32)
    planes = [ConvolutionOperator(stack[k], weights, op.padded_shape) for k in range(n_z)]
    expected = sum(p.forward(v[k]).astype(np.float64) for k, p in enumerate(planes))
    got = op.forward(v)
    scale = float(np.abs(expected).max())
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-5 * scale)
    # the sum matters: any single plane alone, or the mean, is far off
    for k, p in enumerate(planes):
        assert np.abs(got - p.forward(v[k])).max() > 0.1 * scale
    assert np.abs(got - expected / n_z).max() > 0.1 * scale
    # the adjoint of the sum is the stack of the 2D adjoints
    y = _rng(7).standard_normal(shape).astype(np.float32)
    back = op.adjoint(y)
    for k, p in enumerate(planes):
        np.testing.assert_allclose(back[k], p.adjoint(y), rtol=0,
                                   atol=1e-5 * float(np.abs(back).max()))
        np.testing.assert_allclose(op.plane_operator(k).forward(v[k]), p.forward(v[k]),
                                   rtol=0, atol=1e-5 * scale)


def test_centred_points_image_to_their_psfs_summed():
    stack = _stack(4, (9, 11), seed=8)
    op = VolumeConvolutionOperator(stack)
    c0, c1 = op.padded_shape[0] // 2, op.padded_shape[1] // 2
    v = np.zeros(op.shape_in, np.float32)
    v[1, c0, c1] = 1.0
    np.testing.assert_allclose(op.forward(v), stack[1], rtol=0, atol=1e-6)
    v[3, c0, c1] = 2.0
    np.testing.assert_allclose(op.forward(v), stack[1] + 2 * stack[3], rtol=0, atol=1e-5)


def test_dense_matches_summed_linear_convolutions():
    """Dense A column by column against scipy's full convolution, per-plane shifted crop
    (x on the padded grid: forward(x)[s] = sum_z full(x_z, h_z)[s + P // 2])."""
    n_z, shape = 2, (4, 5)
    stack = _stack(n_z, shape, seed=9)
    op = VolumeConvolutionOperator(stack)
    p0, p1 = op.padded_shape
    s0, s1 = shape
    dense = _dense(op.shape_in, op.forward)
    assert dense.shape == (s0 * s1, n_z * p0 * p1)
    ref = np.empty_like(dense)
    for k in range(dense.shape[1]):
        e = np.zeros(op.shape_in)
        e.flat[k] = 1.0
        ref[:, k] = sum(convolve2d(e[z], stack[z].astype(np.float64))
                        [p0 // 2:p0 // 2 + s0, p1 // 2:p1 // 2 + s1] for z in range(n_z)).ravel()
    np.testing.assert_allclose(dense, ref, rtol=0, atol=1e-6)
    dense_t = _dense(op.shape_out, op.adjoint)
    np.testing.assert_allclose(dense_t, dense.T, rtol=0, atol=1e-6)
    # lipschitz against the exact top eigenvalue
    lam = float(np.linalg.eigvalsh(dense.T @ dense)[-1])
    assert lam * (1 - 1e-3) <= op.lipschitz() <= 1.05 * lam
    assert op.lipschitz_bound() >= lam * (1 - 1e-5)


def test_chunked_planes_match_one_chunk():
    stack = _stack(5, (12, 10), seed=10)
    whole = VolumeConvolutionOperator(stack)
    one = VolumeConvolutionOperator(stack, chunk_bytes=1)
    assert whole.planes_per_chunk == 5 and one.planes_per_chunk == 1
    v = _rng(11).standard_normal(whole.shape_in).astype(np.float32)
    b = _rng(12).standard_normal(whole.shape_out).astype(np.float32)
    np.testing.assert_allclose(one.forward(v), whole.forward(v), rtol=0, atol=1e-5)
    l1, g1 = one.data_term(v, b)
    l5, g5 = whole.data_term(v, b)
    assert l1 == pytest.approx(l5, rel=1e-5)
    np.testing.assert_allclose(g1, g5, rtol=0, atol=1e-5 * float(np.abs(g5).max()))


# --------------------------------------------------------------------------- data term


def test_fused_data_term_and_normal_match_generic():
    rng = _rng(13)
    shape = (9, 8)
    weights = rng.random(shape).astype(np.float32)
    op = VolumeConvolutionOperator(_stack(3, shape, seed=14), sensor_weights=weights)
    x = rng.standard_normal(op.shape_in).astype(np.float32)
    b = rng.standard_normal(shape).astype(np.float32)
    x0, b0 = x.copy(), b.copy()
    out = np.full(op.shape_in, np.nan, np.float32)
    loss, grad = op.data_term(x, b, out=out)
    assert grad is out
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(b, b0)
    r = op.forward(x).astype(np.float64) - b
    assert loss == pytest.approx(0.5 * float(np.vdot(r, r)), rel=1e-5)
    ref = op.adjoint(r.astype(np.float32))
    scale = float(np.abs(ref).max())
    np.testing.assert_allclose(grad, ref, rtol=0, atol=1e-5 * scale)
    np.testing.assert_allclose(op.normal(x), op.adjoint(op.forward(x)), rtol=0,
                               atol=1e-5 * float(np.abs(op.normal(x)).max()))


def test_lipschitz_bounds_random_rayleigh_quotients():
    op = VolumeConvolutionOperator(_stack(4, (16, 16), seed=15))
    lip = op.lipschitz()
    rng = _rng(16)
    quotients = []
    for _ in range(8):
        x = rng.standard_normal(op.shape_in).astype(np.float32)
        x[:, op.crop[0], op.crop[1]] += 3.0 * rng.random((4, 16, 16)).astype(np.float32)
        quotients.append(float(np.vdot(x, op.normal(x)) / np.vdot(x, x)))
    assert max(quotients) <= lip
    assert lip <= 1.02 * op.lipschitz_bound()


def test_normalized_stack_bounds_lipschitz_by_one():
    stack = 37.0 * _stack(6, (10, 12), seed=17)
    normed, scale = normalize_psf_stack(stack)
    sums = stack.sum(axis=(1, 2), dtype=np.float64)
    assert scale == pytest.approx(float(np.sqrt(np.sum(sums**2))), rel=1e-6)
    assert normed.dtype == np.float32
    op = VolumeConvolutionOperator(normed)
    assert op.lipschitz_bound() == pytest.approx(1.0, rel=1e-4)  # the DC term
    assert op.lipschitz() <= 1.0
    with pytest.raises(ReconInputError, match="power"):
        normalize_psf_stack(np.zeros((2, 4, 4)))


# --------------------------------------------------------------------------- kernels


def test_accumulate_and_conj_products_match_numpy():
    rng = _rng(18)

    def c(*shape):
        return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(
            np.complex64)

    h, spec, acc = c(3, 5, 4), c(3, 5, 4), c(5, 4)
    acc0 = acc.astype(np.complex128)
    ref = np.sum(h.astype(np.complex128) * spec, axis=0)
    _kernels3d.accumulate_products(acc, spec, h, False)
    np.testing.assert_allclose(acc, acc0 + ref, rtol=0, atol=1e-5)
    acc[...] = np.nan
    _kernels3d.accumulate_products(acc, spec, h, True)
    np.testing.assert_allclose(acc, ref, rtol=0, atol=1e-5)
    r = c(5, 4)
    out = np.empty_like(h)
    _kernels3d.conj_products(out, r, h)
    np.testing.assert_allclose(out, np.conj(h) * r, rtol=0, atol=1e-5)


# --------------------------------------------------------------------------- helpers


def test_bin_stack_reuses_box_bin_per_plane():
    stack = _stack(3, (12, 16), seed=19)
    binned = bin_stack(stack, 4)
    assert binned.shape == (3, 3, 4) and binned.dtype == np.float32
    for k in range(3):
        np.testing.assert_allclose(binned[k], box_bin(stack[k], 4), rtol=1e-6)
    with pytest.raises(ReconInputError):
        bin_stack(stack[0], 2)


def test_erasure_folds_into_volume_operator():
    stack = _stack(3, (8, 9), seed=20)
    op = VolumeConvolutionOperator(stack)
    mask = PixelErasure.random((8, 9), 0.5, seed=21)
    folded = mask @ op
    assert type(folded) is VolumeConvolutionOperator and folded.spectra is op.spectra
    v = _rng(22).standard_normal(op.shape_in).astype(np.float32)
    np.testing.assert_allclose(folded.forward(v), mask.mask * op.forward(v), rtol=0, atol=1e-5)
    assert _adjoint_gap(folded) < 1e-5


def test_memory_estimate_for_512_cube_is_under_4gb():
    est = estimate_memory_bytes((512, 512), 64)
    assert est["psf_spectra"] == 64 * 1024 * 513 * 8
    assert est["volumes"] == 5 * 64 * 1024 * 1024 * 4
    assert est["total"] < 4e9
    op = VolumeConvolutionOperator(_stack(4, (16, 16)))
    small = estimate_memory_bytes((16, 16), 4, volumes=0)
    assert op.memory_bytes() <= small["total"]


def test_fft_floor_runs():
    assert fft_floor_seconds((32, 30), 3, repeats=2) > 0.0
    with pytest.raises(ReconInputError):
        fft_floor_seconds((32, 30), 0)


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("stack", [
    np.ones((5, 6)), np.ones((0, 4, 4)), np.ones((2, 1, 4)),
    np.array([[[1.0, np.nan], [0.0, 1.0]]]), np.stack([np.ones((4, 4)), np.zeros((4, 4))]),
], ids=["2d", "no-planes", "thin", "nan", "zero-plane"])
def test_rejects_bad_stack(stack):
    with pytest.raises(ReconInputError):
        VolumeConvolutionOperator(stack)


def test_rejects_bad_weights_padding_depths_and_shapes():
    stack = _stack(2, (7, 9))
    with pytest.raises(ReconInputError, match="weights"):
        VolumeConvolutionOperator(stack, sensor_weights=np.ones((9, 7)))
    with pytest.raises(ReconInputError, match="padded"):
        VolumeConvolutionOperator(stack, padded_shape=(12, 18))
    with pytest.raises(ReconInputError, match="depths"):
        VolumeConvolutionOperator(stack, depths=[1.0])
    with pytest.raises(ReconInputError, match="monotonic"):
        VolumeConvolutionOperator(stack, depths=[2.0, 2.0])
    op = VolumeConvolutionOperator(stack, depths=[1 / 0.5, 1 / 0.25])  # uniform in 1/z
    np.testing.assert_array_equal(op.depths, [2.0, 4.0])
    with pytest.raises(ReconInputError, match="volume"):
        op.forward(np.zeros(op.padded_shape, np.float32))  # one plane, not a volume
    with pytest.raises(ReconInputError, match="sensor"):
        op.adjoint(np.zeros((7, 8), np.float32))
    with pytest.raises(ReconInputError, match="measurement"):
        op.data_term(np.zeros(op.shape_in, np.float32), np.ones((8, 10), np.float32))

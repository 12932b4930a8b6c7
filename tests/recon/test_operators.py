"""Tests for recon.operators (Kuo 2020, Eq. 3.4, 3.8, 3.10) and recon._kernels.

The kernels are checked against plain numpy versions of the formulas in their
docstrings and in App. A.1 (Haar-shift TV) / App. A.3 (ADMM), written out here.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import convolve2d

from recon import _kernels
from recon.errors import ReconInputError
from recon.operators import Composition, ConvolutionOperator, LinearOperator, PixelErasure

PSF_SHAPES = [(7, 9), (16, 12), (33, 40), (5, 6)]


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def _random_psf(shape, seed=0) -> np.ndarray:
    return _rng(seed).random(shape).astype(np.float32)


def _adjoint_gap(op: LinearOperator, seed: int = 1) -> float:
    """|<A x, y> - <x, A^T y>| / (||A x|| ||y||), accumulated in float64."""
    rng = _rng(seed)
    x = rng.standard_normal(op.shape_in).astype(np.float32)
    y = rng.standard_normal(op.shape_out).astype(np.float32)
    ax = op.forward(x).astype(np.float64)
    aty = op.adjoint(y).astype(np.float64)
    assert ax.shape == tuple(op.shape_out) and aty.shape == tuple(op.shape_in)
    lhs = np.vdot(ax, y.astype(np.float64))
    rhs = np.vdot(x.astype(np.float64), aty)
    return abs(lhs - rhs) / (np.linalg.norm(ax) * np.linalg.norm(y))


def _dense(op: LinearOperator, apply=None) -> np.ndarray:
    """Dense matrix of ``apply`` (default op.forward), built column by column."""
    apply = apply or op.forward
    n_in = int(np.prod(op.shape_in))
    cols = []
    for k in range(n_in):
        e = np.zeros(n_in, np.float32)
        e[k] = 1.0
        cols.append(np.asarray(apply(e.reshape(op.shape_in)), np.float64).ravel())
    return np.stack(cols, axis=1)


# --------------------------------------------------------------------------- adjoints


@pytest.mark.parametrize("shape", PSF_SHAPES)
@pytest.mark.parametrize("weighted", [False, True])
def test_convolution_adjoint(shape, weighted):
    weights = None
    if weighted:
        weights = _rng(5).random(shape).astype(np.float32)
        weights[weights < 0.2] = 0.0
    op = ConvolutionOperator(_random_psf(shape), weights)
    assert all(p >= 2 * s for p, s in zip(op.padded_shape, shape, strict=True))
    assert _adjoint_gap(op) < 1e-5


def test_convolution_outputs_are_float32_with_declared_shapes():
    op = ConvolutionOperator(_random_psf((7, 9)))
    x = _rng(2).random(op.shape_in)  # float64 in
    assert op.forward(x).dtype == np.float32
    assert op.forward(x).shape == (7, 9)
    assert op.adjoint(op.forward(x)).dtype == np.float32
    assert op.adjoint(op.forward(x)).shape == op.padded_shape


def test_pixel_erasure_adjoint_and_action():
    mask = PixelErasure.random((11, 13), 0.4, seed=3)
    assert _adjoint_gap(mask) < 1e-6
    y = _rng(4).standard_normal((11, 13)).astype(np.float32)
    np.testing.assert_array_equal(mask.forward(y), mask.mask * y)


@pytest.mark.parametrize("weighted", [False, True])
def test_erasure_folds_into_convolution(weighted):
    shape = (16, 12)
    weights = _rng(6).random(shape).astype(np.float32) if weighted else None
    conv = ConvolutionOperator(_random_psf(shape), weights)
    mask = PixelErasure.random(shape, 0.5, seed=8)
    folded = mask @ conv
    assert type(folded) is ConvolutionOperator
    assert folded.spectrum is conv.spectrum  # shares the PSF spectrum
    np.testing.assert_array_equal(folded.sensor_weights, conv.sensor_weights * mask.mask)
    x = _rng(9).standard_normal(conv.shape_in).astype(np.float32)
    np.testing.assert_allclose(folded.forward(x), mask.mask * conv.forward(x),
                               rtol=1e-6, atol=1e-6)
    assert _adjoint_gap(folded) < 1e-5


def test_generic_composition_adjoint():
    conv = ConvolutionOperator(_random_psf((7, 9)))
    window = PixelErasure.random(conv.shape_in, 0.3, seed=10)  # on the object grid
    comp = conv @ window
    assert type(comp) is Composition
    assert comp.shape_in == conv.shape_in and comp.shape_out == conv.shape_out
    assert comp.ffts_per_apply == conv.ffts_per_apply
    x = _rng(11).standard_normal(conv.shape_in).astype(np.float32)
    np.testing.assert_allclose(comp.forward(x), conv.forward(window.mask * x),
                               rtol=1e-6, atol=1e-6)
    assert _adjoint_gap(comp) < 1e-5
    # a second mask after the fold gives a Composition of two diagonals
    sensor = PixelErasure.random(conv.shape_out, 0.3, seed=12)
    assert _adjoint_gap(sensor @ PixelErasure(np.ones(conv.shape_out))) < 1e-6


def test_composition_shape_mismatch():
    conv = ConvolutionOperator(_random_psf((7, 9)))
    with pytest.raises(ReconInputError, match="compose"):
        conv @ PixelErasure(np.ones((7, 9)))  # sensor-sized mask on the object side


def test_erasure_fold_shape_mismatch():
    conv = ConvolutionOperator(_random_psf((7, 9)))
    with pytest.raises(ReconInputError, match="mask shape"):
        PixelErasure(np.ones((7, 8))) @ conv


# --------------------------------------------------------------------------- dense checks


@pytest.mark.parametrize("shape", [(5, 6), (7, 5)])  # padded (10, 12) and (15, 10)
def test_dense_forward_matches_linear_convolution(shape):
    """forward(x)[s] == full_conv(x, psf)[s + P // 2] per axis (x on the padded grid)."""
    psf = _random_psf(shape, seed=13)
    op = ConvolutionOperator(psf)
    p0, p1 = op.padded_shape
    s0, s1 = psf.shape
    dense = _dense(op)
    assert dense.shape == (s0 * s1, p0 * p1)
    ref = np.empty_like(dense)
    for k in range(p0 * p1):
        e = np.zeros(op.padded_shape)
        e.flat[k] = 1.0
        full = convolve2d(e, psf.astype(np.float64))
        ref[:, k] = full[p0 // 2:p0 // 2 + s0, p1 // 2:p1 // 2 + s1].ravel()
    np.testing.assert_allclose(dense, ref, rtol=0, atol=1e-6)
    # and the same on a random object
    x = _rng(14).random(op.padded_shape)
    full = convolve2d(x, psf.astype(np.float64))
    np.testing.assert_allclose(op.forward(x), full[p0 // 2:p0 // 2 + s0, p1 // 2:p1 // 2 + s1],
                               rtol=1e-5, atol=1e-5)
    # the adjoint is the transpose
    np.testing.assert_allclose(_dense(_Transposed(op)), dense.T, rtol=0, atol=1e-6)


@pytest.mark.parametrize("shape", [(5, 6), (7, 9), (16, 12)])
def test_delta_at_padded_centre_images_to_psf(shape):
    psf = _random_psf(shape, seed=15)
    op = ConvolutionOperator(psf)
    delta = np.zeros(op.padded_shape, np.float32)
    delta[op.padded_shape[0] // 2, op.padded_shape[1] // 2] = 1.0
    np.testing.assert_allclose(op.forward(delta), psf, rtol=0, atol=1e-6)


class _Transposed(LinearOperator):
    """A^T as an operator (for building the dense adjoint)."""

    def __init__(self, op):
        self.op = op
        self.shape_in, self.shape_out = op.shape_out, op.shape_in

    def forward(self, x):
        return self.op.adjoint(x)

    def adjoint(self, y):
        return self.op.forward(y)


# --------------------------------------------------------------------------- data term


@pytest.mark.parametrize("shape", [(7, 9), (16, 12)])
def test_fused_data_term_matches_generic(shape):
    rng = _rng(16)
    weights = rng.random(shape).astype(np.float32)
    weights[weights < 0.3] = 0.0
    op = ConvolutionOperator(_random_psf(shape), weights)
    x = rng.standard_normal(op.shape_in).astype(np.float32)
    b = rng.standard_normal(shape).astype(np.float32)
    x0, b0 = x.copy(), b.copy()
    loss, grad = op.data_term(x, b)
    loss_g, grad_g = LinearOperator.data_term(op, x, b)
    r = op.forward(x).astype(np.float64) - b
    np.testing.assert_array_equal(x, x0)  # inputs untouched
    np.testing.assert_array_equal(b, b0)
    assert loss == pytest.approx(0.5 * float(np.vdot(r, r)), rel=1e-5)
    assert loss == pytest.approx(loss_g, rel=1e-5)
    assert grad.shape == op.shape_in
    scale = float(np.abs(grad_g).max())
    np.testing.assert_allclose(grad, grad_g, rtol=0, atol=1e-5 * scale)
    np.testing.assert_allclose(grad, op.adjoint(r.astype(np.float32)), rtol=0,
                               atol=1e-5 * scale)


def _wrong_shape_case(which):
    op = ConvolutionOperator(_random_psf((7, 9)))
    x = np.zeros(op.shape_in, np.float32)
    b = np.ones((7, 9), np.float32)
    if which == "x":
        x = x[:-1]
    else:
        b = b[:-1]
    # the generic path refuses a wrong x with ReconInputError (forward's check) and a
    # wrong b at least with numpy's broadcasting ValueError (its base class)
    expected = ReconInputError if which == "x" else ValueError
    return op, x, b, expected


@pytest.mark.parametrize("which", ["x", "b"])
def test_generic_data_term_rejects_wrong_shapes(which):
    op, x, b, expected = _wrong_shape_case(which)
    with pytest.raises(expected):
        LinearOperator.data_term(op, x, b)


# The fused data_term validates shapes like forward(), with ReconInputError for both (a
# larger b would otherwise make the numba kernel read past the weights array).
@pytest.mark.parametrize("which", ["x", "b", "b-larger"])
def test_fused_data_term_rejects_wrong_shapes(which):
    op, x, b, _ = _wrong_shape_case(which[0])
    if which == "b-larger":
        b = np.ones((8, 10), np.float32)
    with pytest.raises(ReconInputError, match="shape"):
        op.data_term(x, b)


# --------------------------------------------------------------------------- lipschitz


@pytest.mark.parametrize("weighted", [False, True])
def test_lipschitz_close_to_top_eigenvalue(weighted):
    shape = (5, 6)
    weights = PixelErasure.random(shape, 0.3, seed=17).mask if weighted else None
    op = ConvolutionOperator(_random_psf(shape, seed=18), weights)
    dense = _dense(op)
    lam = float(np.linalg.eigvalsh(dense.T @ dense)[-1])
    est = op.lipschitz()
    assert abs(est - lam) <= 0.05 * lam
    assert est >= lam * (1 - 1e-3)  # the margin keeps 1/L a safe step


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("psf", [
    np.ones(5), np.ones((2, 3, 4)), np.array([[1.0, np.nan], [0.0, 1.0]]),
    np.array([[1.0, np.inf], [0.0, 1.0]]),
], ids=["1d", "3d", "nan", "inf"])
def test_convolution_rejects_bad_psf(psf):
    with pytest.raises(ReconInputError):
        ConvolutionOperator(psf)


def test_convolution_rejects_bad_weights_and_padding():
    psf = _random_psf((7, 9))
    with pytest.raises(ReconInputError, match="weights"):
        ConvolutionOperator(psf, np.ones((9, 7)))
    with pytest.raises(ReconInputError, match="padded"):
        ConvolutionOperator(psf, padded_shape=(12, 18))


@pytest.mark.parametrize("side", ["forward", "adjoint"])
def test_convolution_rejects_wrong_shape(side):
    op = ConvolutionOperator(_random_psf((7, 9)))
    if side == "forward":
        bad = np.zeros((op.shape_in[0], op.shape_in[1] + 1), np.float32)
        with pytest.raises(ReconInputError, match="object"):
            op.forward(bad)
        with pytest.raises(ReconInputError):
            op.forward(np.zeros((7, 9), np.float32))  # sensor-sized, not padded
    else:
        with pytest.raises(ReconInputError, match="sensor"):
            op.adjoint(np.zeros(op.shape_in, np.float32))


@pytest.mark.parametrize("mask", [
    np.array([[1.0, -0.5], [1.0, 1.0]]), np.zeros((4, 4)), np.ones(6), np.ones((2, 2, 2)),
    np.array([[1.0, np.nan], [1.0, 1.0]]),
], ids=["negative", "all-zero", "1d", "3d", "nan"])
def test_pixel_erasure_rejects_bad_mask(mask):
    with pytest.raises(ReconInputError, match="mask"):
        PixelErasure(mask)


@pytest.mark.parametrize("fraction", [-0.1, 1.0, 1.5, float("nan")])
def test_random_erasure_rejects_bad_fraction(fraction):
    with pytest.raises(ReconInputError, match="fraction"):
        PixelErasure.random((8, 8), fraction)


def test_random_erasure_reproducible_and_fraction():
    a = PixelErasure.random((100, 120), 0.8, seed=5)
    b = PixelErasure.random((100, 120), 0.8, seed=5)
    c = PixelErasure.random((100, 120), 0.8, seed=6)
    np.testing.assert_array_equal(a.mask, b.mask)
    assert not np.array_equal(a.mask, c.mask)
    assert set(np.unique(a.mask)) <= {0.0, 1.0}
    assert a.mask.dtype == np.float32 and a.mask.shape == (100, 120)
    erased = float(np.mean(a.mask == 0))
    assert abs(erased - 0.8) < 0.02  # 12000 pixels: sd of the fraction is 0.004
    assert np.all(PixelErasure.random((10, 10), 0.0).mask == 1.0)


# --------------------------------------------------------------------------- kernels


def _soft(d, t):
    return np.sign(d) * np.maximum(np.abs(d) - t, 0.0)


def _haar_tv_prox(z, thr):
    """App. A.1: per axis Haar split, soft-threshold the half-differences, recombine
    (Eq. A.2), then average the axes."""
    out = np.zeros_like(z)
    for axis in range(z.ndim):
        shifted = np.roll(z, -1, axis=axis)
        d = 0.5 * (shifted - z)
        s = 0.5 * (shifted + z)
        t = _soft(d, thr)
        out += 0.5 * (s - t) + 0.5 * np.roll(s + t, 1, axis=axis)
    return out / z.ndim


def _tv(x):
    return sum(np.abs(np.roll(x, -1, axis=a) - x).sum() for a in range(x.ndim))


@pytest.mark.parametrize("nonneg", [False, True])
@pytest.mark.parametrize("beta", [0.0, 0.7])
@pytest.mark.parametrize("thr", [0.0, 0.05, 0.3])
def test_proximal_step_matches_haar_reference(nonneg, beta, thr):
    rng = _rng(20)
    shape = (9, 13)
    y = rng.standard_normal(shape).astype(np.float32)
    grad = rng.standard_normal(shape).astype(np.float32)
    x_old = rng.standard_normal(shape).astype(np.float32)
    step = 0.37
    x = x_old.copy()
    y_next = np.empty_like(y)
    y0, g0 = y.copy(), grad.copy()
    tv_y, dot = _kernels.proximal_step_2d(y, grad, x, y_next, step, thr, beta, nonneg)

    y64, x_old64 = y.astype(np.float64), x_old.astype(np.float64)
    z = y64 - step * grad.astype(np.float64)
    x_new = _haar_tv_prox(z, thr)
    if nonneg:
        x_new = np.maximum(x_new, 0.0)
    np.testing.assert_array_equal(y, y0)
    np.testing.assert_array_equal(grad, g0)
    np.testing.assert_allclose(x, x_new, rtol=0, atol=1e-5)
    np.testing.assert_allclose(y_next, x_new + beta * (x_new - x_old64), rtol=0, atol=1e-5)
    assert tv_y == pytest.approx(_tv(y64), rel=1e-5)
    assert dot == pytest.approx(float(np.sum((y64 - x_new) * (x_new - x_old64))),
                                rel=1e-4, abs=1e-4)
    if thr == 0.0 and not nonneg:
        np.testing.assert_allclose(x, z, rtol=0, atol=1e-5)  # no TV: plain gradient step


def test_proximal_step_shrinks_tv():
    rng = _rng(21)
    z = rng.standard_normal((16, 16)).astype(np.float32)
    tvs = [_tv(z)]
    for thr in (0.1, 0.3, 1.0):
        x = np.zeros_like(z)
        _kernels.proximal_step_2d(z, np.zeros_like(z), x, np.empty_like(z), 1.0, thr, 0.0,
                                  False)
        tvs.append(_tv(x))
        assert float(x.sum()) == pytest.approx(float(z.sum()), abs=1e-3)  # mean kept
    assert all(a > b for a, b in zip(tvs, tvs[1:], strict=False))
    assert tvs[-1] < 0.8 * tvs[0]


def _admm_split_reference(x, mx, qv, qux, quy, qw, bp, wp, mu1, mu2, tau, use_tv, mode,
                          av, aux, auy, aw):
    """numpy version of the admm_split_updates_2d docstring (float64, returns copies)."""
    out = np.zeros(14)
    thr = tau / mu2 if use_tv else 0.0
    gx = np.roll(x, -1, axis=1) - x
    gy = np.roll(x, -1, axis=0) - x
    out[0] = np.sum((wp * mx - bp) ** 2)
    out[1] = np.abs(gx).sum() + np.abs(gy).sum()
    # (G x, q, a, prox, index of r^2 / s^2, index of max(|Gx|^2,|z|^2) / |a|^2)
    splits = {
        "v": (mx, qv, av, lambda t: (wp * bp + mu1 * t) / (wp * wp + mu1), 2, 8),
        "w": (x, qw, aw, lambda t: np.maximum(t, 0.0), 6, 12),
    }
    if use_tv:
        splits["ux"] = (gx, qux, aux, lambda t: _soft(t, thr), 4, 10)
        splits["uy"] = (gy, quy, auy, lambda t: _soft(t, thr), 4, 10)
    new_q, new_a = {}, {}
    for name, (g, q_old, a_old, prox, k, n) in splits.items():
        a_new = g - q_old
        z_new = prox(g + a_new)
        if mode == 2:
            out[k] += np.sum((a_new - a_old) ** 2)
            out[k + 1] += np.sum((z_new - (q_old + a_old)) ** 2)
            out[n] += np.sum(np.maximum(g * g, z_new * z_new))
            out[n + 1] += np.sum(a_new**2)
        new_q[name] = z_new - a_new
        new_a[name] = a_new if mode != 0 else a_old
    return out, new_q, new_a


@pytest.mark.parametrize("mode", [0, 1, 2])
@pytest.mark.parametrize("use_tv", [True, False])
def test_admm_split_updates_match_reference(mode, use_tv):
    rng = _rng(22 + mode)
    shape = (10, 14)

    def r():
        return rng.standard_normal(shape).astype(np.float32)

    x, mx, qv, qux, quy, qw = r(), r(), r(), r(), r(), r()
    av, aux, auy, aw = r(), r(), r(), r()
    wp = np.zeros(shape, np.float32)
    bp = np.zeros(shape, np.float32)
    wp[2:8, 3:11] = rng.random((6, 8)).astype(np.float32)  # weights zero off the sensor
    bp[2:8, 3:11] = rng.random((6, 8)).astype(np.float32)
    mu1, mu2, mu3, tau = 0.7, 1.3, 0.4, 0.5
    f64 = [a.astype(np.float64) for a in (x, mx, qv, qux, quy, qw, bp, wp)]
    a64 = [a.astype(np.float64) for a in (av, aux, auy, aw)]
    ref, new_q, new_a = _admm_split_reference(*f64, mu1, mu2, tau, use_tv, mode, *a64)
    out = _kernels.admm_split_updates_2d(x, mx, qv, qux, quy, qw, bp, wp, mu1, mu2, mu3,
                                         tau, use_tv, mode, av, aux, auy, aw)
    assert out.shape == (14,)
    np.testing.assert_allclose(out, ref, rtol=1e-5, atol=1e-4)
    tol = dict(rtol=0, atol=2e-5)
    np.testing.assert_allclose(qv, new_q["v"], **tol)
    np.testing.assert_allclose(qw, new_q["w"], **tol)
    np.testing.assert_allclose(av, new_a["v"], **tol)
    np.testing.assert_allclose(aw, new_a["w"], **tol)
    if use_tv:
        for got, name in ((qux, "ux"), (quy, "uy")):
            np.testing.assert_allclose(got, new_q[name], **tol)
        for got, name in ((aux, "ux"), (auy, "uy")):
            np.testing.assert_allclose(got, new_a[name], **tol)
    else:  # the TV split is left alone
        np.testing.assert_array_equal(qux, f64[3].astype(np.float32))
        np.testing.assert_array_equal(quy, f64[4].astype(np.float32))
        np.testing.assert_array_equal(aux, a64[1].astype(np.float32))
        np.testing.assert_array_equal(auy, a64[2].astype(np.float32))
        assert out[4] == 0.0 and out[5] == 0.0


@pytest.mark.parametrize("rows", [10, 40])  # fewer rows than blocks, and several per block
@pytest.mark.parametrize("mode", [0, 1])
@pytest.mark.parametrize("use_tv", [True, False])
def test_admm_split_writes_the_rhs_of_its_new_q(rows, mode, use_tv):
    """The split pass's optional right-hand side equals admm_rhs_2d run on its output."""
    rng = _rng(40 + rows + mode)
    shape = (rows, 14)

    def r():
        return rng.standard_normal(shape).astype(np.float32)

    x, mx, qv, qux, quy, qw = r(), r(), r(), r(), r(), r()
    av, aux, auy, aw = r(), r(), r(), r()
    wp, bp = rng.random(shape).astype(np.float32), rng.random(shape).astype(np.float32)
    mu1, mu2, mu3, tau = 0.7, 1.3, 0.4, 0.5
    state = [a.copy() for a in (x, mx, qv, qux, quy, qw, bp, wp)]
    duals = [a.copy() for a in (av, aux, auy, aw)]
    plain = _kernels.admm_split_updates_2d(*state, mu1, mu2, mu3, tau, use_tv, mode, *duals,
                                           0.1)
    want = np.full(shape, np.nan, np.float32)
    _kernels.admm_rhs_2d(state[3], state[4], state[5], want, mu2, mu3, use_tv)
    rhs = np.full(shape, np.nan, np.float32)
    fused = _kernels.admm_split_updates_2d(x, mx, qv, qux, quy, qw, bp, wp, mu1, mu2, mu3, tau,
                                           use_tv, mode, av, aux, auy, aw, 0.1, rhs)
    np.testing.assert_array_equal(rhs, want)
    for got, ref in zip((qv, qux, quy, qw, av, aux, auy, aw), state[2:6] + duals,
                        strict=True):
        np.testing.assert_array_equal(got, ref)
    np.testing.assert_allclose(fused, plain, rtol=1e-6, atol=1e-6)


def _psi_t(qux, quy):
    """Adjoint of the circular forward differences (ux along axis 1, uy along axis 0)."""
    return (np.roll(qux, 1, axis=1) - qux) + (np.roll(quy, 1, axis=0) - quy)


@pytest.mark.parametrize("use_tv", [True, False])
def test_admm_rhs_matches_reference(use_tv):
    rng = _rng(30)
    shape = (9, 12)
    qux, quy, qw = (rng.standard_normal(shape).astype(np.float32) for _ in range(3))
    out = np.full(shape, np.nan, np.float32)
    mu2, mu3 = 0.8, 1.7
    _kernels.admm_rhs_2d(qux, quy, qw, out, mu2, mu3, use_tv)
    ref = mu3 * qw.astype(np.float64)
    if use_tv:
        ref = ref + mu2 * _psi_t(qux.astype(np.float64), quy.astype(np.float64))
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-5)


def test_admm_rhs_is_adjoint_of_split_differences():
    """<Psi x, q> == <x, Psi^T q> with Psi as used in admm_split_updates_2d's TV."""
    rng = _rng(31)
    shape = (8, 11)
    x = rng.standard_normal(shape)
    qux, quy = rng.standard_normal(shape), rng.standard_normal(shape)
    out = np.zeros(shape, np.float32)
    _kernels.admm_rhs_2d(qux.astype(np.float32), quy.astype(np.float32),
                         np.zeros(shape, np.float32), out, 1.0, 0.0, True)
    lhs = np.vdot(np.roll(x, -1, 1) - x, qux) + np.vdot(np.roll(x, -1, 0) - x, quy)
    assert np.vdot(x, out.astype(np.float64)) == pytest.approx(lhs, rel=1e-5)


def test_admm_fourier_matches_reference():
    rng = _rng(32)
    shape = (10, 6)

    def c():
        return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(
            np.complex64)

    qv_hat, rhs_hat, spec = c(), c(), c()
    inv_den = (1.0 / (1.0 + rng.random(shape))).astype(np.float32)
    mu1 = 0.6
    q0, r0 = qv_hat.astype(np.complex128), rhs_hat.astype(np.complex128)
    _kernels.admm_fourier_2d(qv_hat, rhs_hat, spec, inv_den, mu1)
    xh = (mu1 * np.conj(spec.astype(np.complex128)) * q0 + r0) * inv_den
    np.testing.assert_allclose(rhs_hat, xh, rtol=0, atol=1e-5)
    np.testing.assert_allclose(qv_hat, spec * xh, rtol=0, atol=1e-5)


@pytest.mark.parametrize("top,left", [(0, 0), (3, 5), (6, 2)])
def test_crop_residual_matches_numpy(top, left):
    rng = _rng(33)
    full = rng.standard_normal((14, 16)).astype(np.float32)
    b = rng.standard_normal((7, 9)).astype(np.float32)
    w = rng.random((7, 9)).astype(np.float32)
    crop = (slice(top, top + 7), slice(left, left + 9))
    f64 = full.astype(np.float64)
    r = w * f64[crop] - b
    expected = np.zeros_like(f64)
    expected[crop] = w * r
    loss = _kernels.crop_residual(full, b, w, top, left)
    assert loss == pytest.approx(float(np.sum(r * r)), rel=1e-5)
    np.testing.assert_allclose(full, expected, rtol=0, atol=1e-5)

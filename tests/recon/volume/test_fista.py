"""Tests for recon.volume.fista: 3D FISTA with Haar-shift TV (App. A.1 in 3D), l1 and
non-negativity on a small synthetic volume problem with a known answer.

The PSF stack is caustic-like: smoothed random noise thresholded at its 85th
percentile inside a round aperture, magnified per depth about the centre (the
depth scaling of Sec. 3.2 / Fig. 4.2), 5 planes on a 64 x 64 sensor.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter, map_coordinates

from recon.errors import DivergenceError, ReconInputError
from recon.operators import ConvolutionOperator, LinearOperator
from recon.volume import VolumeConvolutionOperator, fista3d, normalize_psf_stack, volume_tv
from recon.volume._kernels3d import proximal_step_3d

SENSOR = (64, 64)
SCALES = (1.0, 0.9, 0.8, 0.7, 0.6)  # caustic magnification per plane
BEADS = [(0, 50, 60), (1, 70, 45), (2, 60, 80), (3, 85, 70), (4, 45, 85), (2, 75, 58),
         (4, 60, 40)]  # (plane, row, col) on the 128 x 128 padded grid


def caustic_stack(scales=SCALES, n=SENSOR[0], seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    g = gaussian_filter(rng.standard_normal((2 * n, 2 * n)), 3.0)
    base = np.maximum(g - np.quantile(g, 0.85), 0.0)
    c = (n - 1) / 2
    ii, jj = np.mgrid[0:n, 0:n].astype(np.float64)
    stack = []
    for s in scales:
        h = map_coordinates(base, [(ii - c) / s + n, (jj - c) / s + n], order=1)
        stack.append(h * (np.hypot(ii - c, jj - c) < 0.45 * n * s))
    return normalize_psf_stack(np.array(stack))[0]


@pytest.fixture(scope="module")
def bead_problem():
    op = VolumeConvolutionOperator(caustic_stack(), depths=1.0 / np.linspace(0.5, 0.1, 5))
    truth = np.zeros(op.shape_in, np.float32)
    for z, i, j in BEADS:
        truth[z, i, j] = 1.0
    b = op.forward(truth)
    rng = np.random.default_rng(1)
    b = b + 0.02 * float(b.max()) * rng.standard_normal(b.shape)
    b = (b / b.max()).astype(np.float32)
    return op, b, op.lipschitz()


def _bead_planes(x):
    """Plane of the maximum along z of the 3x3 neighbourhood of each bead."""
    return [int(np.argmax(x[:, i - 1:i + 2, j - 1:j + 2].max(axis=(1, 2))))
            for _, i, j in BEADS]


# --------------------------------------------------------------------------- prox kernel


def _soft(d, t):
    return np.sign(d) * np.maximum(np.abs(d) - t, 0.0)


def _haar_tv_prox_3d(z, thr):
    """App. A.1 (Eq. A.1-A.2) along each axis, averaged; lateral axes circular, the
    depth axis without its wrap pair (kept unthresholded, i.e. not coupled)."""
    out = np.zeros_like(z)
    for axis in range(3):
        shifted = np.roll(z, -1, axis=axis)
        d = 0.5 * (shifted - z)
        s = 0.5 * (shifted + z)
        t = _soft(d, thr)
        if axis == 0:
            t[-1] = d[-1]  # the (last, first) plane pair does not exist
        out += 0.5 * (s - t) + 0.5 * np.roll(s + t, 1, axis=axis)
    return out / 3


@pytest.mark.parametrize("nonneg", [False, True])
@pytest.mark.parametrize("beta", [0.0, 0.6])
@pytest.mark.parametrize("thr,l1thr", [(0.0, 0.0), (0.05, 0.0), (0.3, 0.0), (0.0, 0.2),
                                       (0.1, 0.1)])
def test_proximal_step_matches_haar_reference(nonneg, beta, thr, l1thr):
    rng = np.random.default_rng(2)
    shape = (4, 7, 9)
    y, grad, x_old = (rng.standard_normal(shape).astype(np.float32) for _ in range(3))
    step = 0.37
    x, y_next = x_old.copy(), np.empty_like(y)
    y0, g0 = y.copy(), grad.copy()
    tv_y, l1_y, dot = proximal_step_3d(y, grad, x, y_next, step, thr, l1thr, beta, nonneg)
    y64, x_old64 = y.astype(np.float64), x_old.astype(np.float64)
    x_new = _soft(_haar_tv_prox_3d(y64 - step * grad.astype(np.float64), thr), l1thr)
    if nonneg:
        x_new = np.maximum(x_new, 0.0)
    np.testing.assert_array_equal(y, y0)
    np.testing.assert_array_equal(grad, g0)
    np.testing.assert_allclose(x, x_new, rtol=0, atol=1e-5)
    np.testing.assert_allclose(y_next, x_new + beta * (x_new - x_old64), rtol=0, atol=1e-5)
    assert tv_y == pytest.approx(volume_tv(y), rel=1e-5)
    assert l1_y == pytest.approx(float(np.abs(y64).sum()), rel=1e-5)
    assert dot == pytest.approx(float(np.sum((y64 - x_new) * (x_new - x_old64))),
                                rel=1e-4, abs=1e-4)


def test_volume_tv_does_not_wrap_in_depth():
    v = np.zeros((3, 4, 5), np.float32)
    v[0] = 1.0  # a constant first plane: only the (0, 1) depth pair differs
    assert volume_tv(v) == pytest.approx(20.0)
    v[:] = np.arange(3, dtype=np.float32)[:, None, None]
    assert volume_tv(v) == pytest.approx(40.0)  # not 40 + 2 * 20 with a wrap


# --------------------------------------------------------------------------- solver


@pytest.mark.parametrize("kwargs", [{}, {"l1": 1e-3}, {"tv": 1e-4, "l1": 1e-3}],
                         ids=["plain", "l1", "tv+l1"])
def test_beads_recovered_at_their_planes(bead_problem, kwargs):
    op, b, lip = bead_problem
    res = fista3d(op, b, iterations=200, lipschitz=lip, **kwargs)
    assert res.x.dtype == np.float32 and res.x.shape == op.shape_in
    planes = _bead_planes(res.x)
    truth = [z for z, _, _ in BEADS]
    assert all(abs(p - t) <= 1 for p, t in zip(planes, truth, strict=True)), planes
    assert sum(p == t for p, t in zip(planes, truth, strict=True)) >= len(BEADS) - 1, planes
    # the beads are the brightest voxels: the 7 largest sit at (or next to) the beads
    top = np.argsort(res.x.ravel())[::-1][:len(BEADS)]
    for z, i, j in zip(*np.unravel_index(top, res.x.shape), strict=True):
        assert any(abs(z - bz) <= 1 and abs(i - bi) <= 1 and abs(j - bj) <= 1
                   for bz, bi, bj in BEADS)
    assert res.final_relative_residual < 0.2  # the noise alone is 0.10 of ||b||; 0.15 seen


def test_objective_decreases_with_tv_and_l1(bead_problem):
    op, b, lip = bead_problem
    res = fista3d(op, b, iterations=60, tv=1e-3, l1=1e-2, lipschitz=lip)
    obj = np.array(res.history.objective)
    assert len(obj) == 60 == len(res.history.seconds) == len(res.history.data_residual)
    assert obj[-1] < 0.3 * obj[0]  # 0.22 seen (the weights are strong on purpose)
    rises = np.diff(obj) > 1e-3 * obj[:-1]
    assert rises.sum() <= 6  # monotone-ish (restarts remove FISTA's ripples)
    assert np.all(obj[10:] <= 1.05 * np.minimum.accumulate(obj)[10:])
    assert res.final_objective <= 1.05 * obj[-1]
    assert res.params["tv"] == 1e-3 and res.params["l1"] == 1e-2
    # stronger l1 gives a sparser volume
    sparse = fista3d(op, b, iterations=60, l1=0.3, lipschitz=lip)
    assert np.count_nonzero(sparse.x) < np.count_nonzero(res.x)


def test_over_large_step_raises_divergence(bead_problem):
    op, b, lip = bead_problem
    with pytest.raises(DivergenceError, match="step") as info:
        fista3d(op, b, iterations=100, step=5.0 / lip)
    assert info.value.last_good is not None and info.value.last_good.shape == op.shape_in
    with pytest.raises(DivergenceError, match="step"):
        fista3d(op, b, iterations=100, step_scale=3.0, lipschitz=lip)


def test_without_nonneg_goes_negative(bead_problem):
    op, b, lip = bead_problem
    res = fista3d(op, b, iterations=20, nonneg=False, lipschitz=lip)
    assert res.x.min() < 0


class _Generic(LinearOperator):
    """The volume operator behind the generic interface (no fused ``out=``)."""

    def __init__(self, op):
        self.op, self.shape_in, self.shape_out = op, op.shape_in, op.shape_out

    def forward(self, x):
        return self.op.forward(x)

    def adjoint(self, y):
        return self.op.adjoint(y)


def test_generic_operator_path_matches_fused(bead_problem):
    op, b, lip = bead_problem
    fused = fista3d(op, b, iterations=15, tv=1e-4, lipschitz=lip)
    generic = fista3d(_Generic(op), b, iterations=15, tv=1e-4, lipschitz=lip)
    np.testing.assert_allclose(generic.x, fused.x, rtol=0, atol=1e-4 * float(fused.x.max()))


@pytest.mark.parametrize("kwargs,fragment", [
    ({"iterations": 0}, "iterations"), ({"tv": -1.0}, "TV"), ({"l1": float("nan")}, "l1"),
    ({"step": -1.0}, "step"), ({"step_scale": 0.0}, "step_scale"),
])
def test_invalid_parameters_are_refused(bead_problem, kwargs, fragment):
    op, b, lip = bead_problem
    with pytest.raises(ReconInputError, match=fragment):
        fista3d(op, b, **({"iterations": 5, "lipschitz": lip} | kwargs))


def test_2d_operator_and_bad_measurement_are_refused(bead_problem):
    op, b, _ = bead_problem
    with pytest.raises(ReconInputError, match="volume"):
        fista3d(ConvolutionOperator(op.psf_stack[0]), b, iterations=2)
    with pytest.raises(ReconInputError, match="shape"):
        fista3d(op, b[:-1], iterations=2)
    with pytest.raises(ReconInputError, match="zero"):
        fista3d(op, np.zeros_like(b), iterations=2)

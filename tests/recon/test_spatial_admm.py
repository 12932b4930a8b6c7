"""ADMM for the spatially varying models (recon.spatial.admm): the linearized x-update."""

from __future__ import annotations

import numpy as np
import pytest

from recon.errors import ReconInputError
from recon.operators import ConvolutionOperator
from recon.solvers import admm, fista
from recon.solvers.common import anisotropic_tv
from recon.spatial import (
    PsfGrid,
    SpatialAdmmPlan,
    local_convolution_operator,
    pca_operator,
    spatial_admm,
)

SENSOR = (32, 40)
SHIFTS = [(dy, dx) for dy in (-8, 0, 8) for dx in (-10, 0, 10)]


def _grid(rng, spread=0.3):
    """Nine PSFs: one random caustic, each node's a different mix with its own
    (``spread``: how much the PSFs differ across the field)."""
    base = rng.random(SENSOR) ** 6
    psfs = [(1 - spread) * base + spread * rng.random(SENSOR) ** 6 for _ in SHIFTS]
    return PsfGrid(np.stack(psfs).astype(np.float32), SHIFTS, (3, 3))


def _scene(op, rng):
    """Piecewise-constant blocks inside the sensor's field of view."""
    x = np.zeros(op.shape_in, np.float32)
    r0, c0 = op.crop[0].start, op.crop[1].start
    for _ in range(6):
        r, c = rng.integers(0, SENSOR[0] - 8), rng.integers(0, SENSOR[1] - 8)
        x[r0 + r:r0 + r + 8, c0 + c:c0 + c + 8] += rng.random()
    return x


def _objective(op, x, b, tv):
    r = op.forward(x) - b
    return 0.5 * float(np.vdot(r, r)) + tv * anisotropic_tv(x)


def test_circular_apply_and_its_adjoint():
    rng = np.random.default_rng(0)
    op = local_convolution_operator(_grid(rng))
    x = rng.standard_normal(op.shape_in).astype(np.float32)
    v = rng.standard_normal(op.padded_shape).astype(np.float32)
    mx = op.convolve_full(x)
    assert mx.shape == op.padded_shape and mx.dtype == np.float32
    lhs, rhs = float(np.vdot(mx, v)), float(np.vdot(x, op.correlate_full(v)))
    assert abs(lhs - rhs) < 1e-5 * abs(lhs)
    np.testing.assert_allclose(mx[op.crop], op.forward(x), atol=1e-5)


def test_one_node_model_gives_the_convolution_admm_iterates():
    """With one kernel the preconditioner is the x-subproblem's own system, so the
    linearized step is the exact x-update of recon.solvers.admm."""
    rng = np.random.default_rng(1)
    psf = _grid(rng).psfs[4]
    one = PsfGrid(psf[None], [(0.0, 0.0)], (1, 1))
    op1 = local_convolution_operator(one)
    conv = ConvolutionOperator(psf / psf.sum())
    b = conv.forward(_scene(conv, rng))
    for tv, l1 in ((3e-3, 0.0), (0.0, 1e-3)):
        got = spatial_admm(op1, b, iterations=40, tv=tv, l1=l1)
        want = admm(conv, b, iterations=40, tv=tv, l1=l1)
        np.testing.assert_allclose(got.x, want.x, atol=1e-4 * float(want.x.max()))
        assert got.params["mu_final"] == want.params["mu_final"]


@pytest.mark.parametrize("spread", [0.1, 0.3])
def test_minimises_the_tv_objective_and_recovers_the_scene(spread):
    """On a 3 x 3 local model with TV it reaches (and, with the exact anisotropic TV
    where FISTA proxes the Haar-shift approximation, passes) the objective of FISTA run
    to convergence, and its objective settles. Its advantage in iterations shows at
    scale, in the benchmark (``spatial_admm``), not on this small problem."""
    rng = np.random.default_rng(2)
    op = local_convolution_operator(_grid(rng, spread))
    truth = _scene(op, rng)
    b = op.forward(truth)
    b = (b + 0.01 * float(b.max()) * rng.standard_normal(b.shape)).astype(np.float32)
    tv = 1e-4
    f_fista = _objective(op, fista(op, b, iterations=4000, tv=tv).x, b, tv)
    res = spatial_admm(op, b, iterations=1000, tv=tv)
    assert _objective(op, res.x, b, tv) < f_fista
    obj = np.asarray(res.history.objective)
    assert obj[-100:].max() < 1.01 * obj[-100:].min()
    err = res.x[op.crop] - truth[op.crop]
    # 34.6 / 32.9 dB when written (FISTA after 4000 iterations: 34.4 / 32.7 dB)
    assert 10 * np.log10(float(truth.max()) ** 2 / float(np.mean(err ** 2))) > 30.0


def test_preconditioner_is_the_largest_node_psf_power():
    """rho = max over nodes of |F h_i|^2: the node kernels for the local model, the
    rank-k node PSFs for PCA (all components: the local model's)."""
    rng = np.random.default_rng(3)
    grid = _grid(rng)
    local = local_convolution_operator(grid)
    want = np.max(np.abs(local.spectra) ** 2, axis=0)
    np.testing.assert_allclose(SpatialAdmmPlan.of(local).h_pow, want, rtol=1e-5)
    full = pca_operator(grid, k=9)
    np.testing.assert_allclose(SpatialAdmmPlan.of(full).h_pow, want, rtol=1e-3,
                               atol=1e-6 * float(want.max()))
    small = SpatialAdmmPlan.of(pca_operator(grid, k=2)).h_pow
    assert small.shape == want.shape and np.all(np.isfinite(small))


def test_refuses_what_it_cannot_solve():
    rng = np.random.default_rng(4)
    grid = _grid(rng)
    conv = ConvolutionOperator(grid.psfs[4])
    with pytest.raises(ReconInputError, match="2D SpatialConvolutionOperator"):
        SpatialAdmmPlan.of(conv)
    volume = local_convolution_operator([PsfGrid(grid.psfs, SHIFTS, (3, 3), z_mm=z)
                                         for z in (10.0, 20.0)])
    with pytest.raises(ReconInputError, match="2D SpatialConvolutionOperator"):
        SpatialAdmmPlan.of(volume)
    op = local_convolution_operator(grid)
    b = op.forward(_scene(op, rng))
    with pytest.raises(ReconInputError, match="recon.spatial.spatial_admm"):
        admm(op, b, iterations=2)
    with pytest.raises(ReconInputError, match="another operator"):
        admm(op, b, iterations=2, plan=SpatialAdmmPlan.of(local_convolution_operator(grid)))

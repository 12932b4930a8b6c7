"""Spatially varying forward models (Kuo 2020, Ch. 5): local convolution and PCA."""

import numpy as np
import pytest

from recon.errors import ReconInputError
from recon.operators import ConvolutionOperator, PixelErasure
from recon.solvers import fista
from recon.spatial import (
    PsfGrid,
    local_convolution_operator,
    pca_components,
    pca_operator,
    register_psfs,
    scale_psf,
    synthesize_grid,
)
from recon.volume import fista3d

SENSOR = (14, 16)
SHIFTS = [(dy, dx) for dy in (-4, 0, 4) for dx in (-5, 0, 5)]  # 3 x 3 grid, px


def _grid(rng, identical=False, z_mm=None, d_mm=None):
    base = rng.random(SENSOR).astype(np.float32) ** 4
    psfs = []
    for k in range(len(SHIFTS)):
        fall = np.exp(-0.05 * k * np.linspace(0, 1, SENSOR[1]))[None, :]
        psfs.append(base if identical else base * fall + 0.05 * rng.random(SENSOR))
    return PsfGrid(np.stack(psfs), SHIFTS, (3, 3), z_mm, d_mm)


def _adjoint_gap(op, rng):
    x = rng.standard_normal(op.shape_in).astype(np.float32)
    y = rng.standard_normal(op.shape_out).astype(np.float32)
    lhs, rhs = float(np.vdot(op.forward(x), y)), float(np.vdot(x, op.adjoint(y)))
    return abs(lhs - rhs) / abs(lhs)


def _reference_column(grid, padded, r, c):
    """Eq. 5.3 written out: the PSF of a point at (r, c) of the padded grid is
    sum_i alpha_i h~_i moved to the point, alpha_i bilinear in the node offsets."""
    p0, p1 = padded
    ys = np.array(sorted({s[0] for s in SHIFTS}), float)
    xs = np.array(sorted({s[1] for s in SHIFTS}), float)
    ay = np.interp(r - p0 // 2, ys, [1, 0, 0]), np.interp(r - p0 // 2, ys, [0, 1, 0]), \
        np.interp(r - p0 // 2, ys, [0, 0, 1])
    ax = np.interp(c - p1 // 2, xs, [1, 0, 0]), np.interp(c - p1 // 2, xs, [0, 1, 0]), \
        np.interp(c - p1 // 2, xs, [0, 0, 1])
    full = np.zeros(padded)
    top, left = (p0 - SENSOR[0]) // 2, (p1 - SENSOR[1]) // 2
    for i in range(9):
        a = ay[i // 3] * ax[i % 3]
        if a:
            placed = np.zeros(padded)
            placed[top:top + SENSOR[0], left:left + SENSOR[1]] = grid.psfs[i]
            full += a * np.roll(placed, (r - p0 // 2, c - p1 // 2), axis=(0, 1))
    return full[top:top + SENSOR[0], left:left + SENSOR[1]]


def test_local_model_adjoint_and_dense_matrix_match_eq_5_3():
    rng = np.random.default_rng(0)
    grid = _grid(rng)
    op = local_convolution_operator(grid, normalize=False)
    assert op.n_kernels == 9 and op.ffts_per_apply == 10
    assert _adjoint_gap(op, rng) < 1e-5
    p0, p1 = op.shape_in
    dense = np.zeros((SENSOR[0] * SENSOR[1], p0 * p1))
    for q in range(p0 * p1):
        e = np.zeros(op.shape_in, np.float32)
        e.flat[q] = 1
        dense[:, q] = op.forward(e).ravel()
    for r, c in [(p0 // 2, p1 // 2), (p0 // 2 - 4, p1 // 2 + 5), (p0 // 2 + 2, p1 // 2 - 3),
                 (3, 5), (p0 - 2, p1 - 1)]:
        ref = _reference_column(grid, (p0, p1), r, c)
        np.testing.assert_allclose(dense[:, r * p1 + c].reshape(SENSOR), ref, atol=1e-5)
    y = rng.standard_normal(SENSOR).astype(np.float32)
    np.testing.assert_allclose(op.adjoint(y).ravel(), dense.T @ y.ravel(), atol=1e-4)


def test_local_model_with_identical_psfs_is_the_convolution_model():
    rng = np.random.default_rng(1)
    grid = _grid(rng, identical=True)
    op = local_convolution_operator(grid, normalize=False)
    conv = ConvolutionOperator(grid.psfs[0])
    x = rng.random(op.shape_in).astype(np.float32)
    np.testing.assert_allclose(op.forward(x), conv.forward(x), rtol=1e-4, atol=1e-4)
    y = rng.random(op.shape_out).astype(np.float32)
    np.testing.assert_allclose(op.adjoint(y), conv.adjoint(y), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(op.weight_sum(), 1.0, atol=1e-6)


def test_pca_with_all_components_equals_local_model_and_fewer_cost_less():
    rng = np.random.default_rng(2)
    grid = _grid(rng)
    local = local_convolution_operator(grid)
    full = pca_operator(grid, k=9)
    x = rng.random(local.shape_in).astype(np.float32)
    ref = local.forward(x)
    np.testing.assert_allclose(full.forward(x), ref, rtol=1e-3, atol=1e-4 * ref.max())
    assert _adjoint_gap(full, rng) < 1e-5
    two = pca_operator(grid, k=2)
    assert two.n_kernels == 2 and two.ffts_per_apply == 3
    err2 = np.linalg.norm(two.forward(x) - ref) / np.linalg.norm(ref)
    _, _, explained = pca_components(grid)
    assert err2 < 0.2 and explained[1] > 0.9
    auto = pca_operator(grid, energy=explained[2] - 1e-6)
    assert auto.components == [3]
    with pytest.raises(ReconInputError, match="principal PSFs"):
        pca_operator(grid, k=10)


def test_point_at_a_node_images_to_its_measured_psf_after_registration():
    rng = np.random.default_rng(3)
    base = np.zeros(SENSOR, np.float32)
    base[rng.integers(5, 10, 6), rng.integers(6, 11, 6)] = 1.0
    raw, positions = [], []
    for dy, dx in SHIFTS:
        fall = np.exp(-0.02 * ((np.arange(SENSOR[1]) - 8 - dx) ** 2))[None, :]
        raw.append(np.roll(base, (dy, dx), axis=(0, 1)) * (0.5 + fall))
        positions.append((-dx * 0.1, -dy * 0.1))  # m = d/z: sources move against the PSF
    order = rng.permutation(9)
    grid = PsfGrid.from_positions(np.stack(raw)[order], np.array(positions)[order])
    assert grid.grid_shape == (3, 3)
    np.testing.assert_allclose(np.sort(grid.node_coordinates()[0]), [-4, 0, 4], atol=0.05)
    op = local_convolution_operator(grid, normalize=False)
    p0, p1 = op.shape_in
    for k in range(9):
        dy, dx = np.round(grid.shifts_px[k]).astype(int)
        i = SHIFTS.index((dy, dx))
        e = np.zeros(op.shape_in, np.float32)
        e[p0 // 2 + dy, p1 // 2 + dx] = 1
        np.testing.assert_allclose(op.forward(e), raw[i], atol=1e-4)


def test_support_drops_psfs_that_do_not_reach_it_and_keeps_the_model_there():
    rng = np.random.default_rng(4)
    grid = _grid(rng)
    full = local_convolution_operator(grid)
    p0, p1 = full.shape_in
    support = np.zeros(full.shape_in, bool)
    support[p0 // 2 - 4:p0 // 2 + 1, p1 // 2 - 5:p1 // 2 + 1] = True  # nodes 0, 1, 3, 4
    op = local_convolution_operator(grid, support=support)
    assert op.n_kernels == 4 and sorted(op.kept.tolist()) == [0, 1, 3, 4]
    x = rng.random(full.shape_in).astype(np.float32) * support
    np.testing.assert_allclose(op.forward(x), full.forward(x), rtol=1e-4, atol=1e-5)
    assert _adjoint_gap(op, rng) < 1e-5
    with pytest.raises(ReconInputError, match="support"):
        local_convolution_operator(grid, support=np.zeros(full.shape_in, bool))


def test_3d_models_adjoint_erasure_and_per_depth_blocks():
    rng = np.random.default_rng(5)
    grids = [_grid(rng, z_mm=z, d_mm=3.8) for z in (2.0, 2.4)]
    op = local_convolution_operator(grids)
    assert op.shape_in[0] == 2 and op.n_kernels == 18
    assert _adjoint_gap(op, rng) < 1e-5
    pca = pca_operator(grids, k=3)
    assert pca.n_kernels == 6 and _adjoint_gap(pca, rng) < 1e-5
    x = np.zeros(op.shape_in, np.float32)
    x[1] = rng.random(op.shape_in[1:])
    one = local_convolution_operator(grids[1])
    np.testing.assert_allclose(op.forward(x) * op.scale, one.forward(x[1]) * one.scale,
                               rtol=1e-4, atol=1e-4)
    mask = PixelErasure.random(SENSOR, 0.5, seed=1)
    erased = mask @ op
    np.testing.assert_allclose(erased.forward(x), mask.mask * op.forward(x), atol=1e-6)


def test_synthesised_depth_follows_the_eq_5_2_scaling():
    rng = np.random.default_rng(6)
    d, z0 = 3.8, 2.4
    base = np.zeros((64, 64), np.float32)
    base[rng.integers(4, 60, 40), rng.integers(4, 60, 40)] = 1.0
    from scipy.ndimage import gaussian_filter
    base = gaussian_filter(base, 0.8)

    def truth(z):  # the paraxial pattern at depth z, registered (Eq. 5.2)
        return scale_psf(base, z * (d + z0) / (z0 * (d + z)))

    shifts = [(0.0, 0.0)]
    grids = [PsfGrid(truth(z)[None], shifts, (1, 1), z, d) for z in (1.7, 3.0)]
    got = synthesize_grid(grids, 2.4).psfs[0]
    want = truth(2.4)
    naive = 0.5 * (grids[0].psfs[0] + grids[1].psfs[0])

    def corr(a, b):
        return float(np.vdot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))

    assert corr(got, want) > 0.9  # measured 0.96
    assert corr(naive, want) < 0.5  # averaging unscaled PSFs blurs the caustics: 0.30
    assert synthesize_grid(grids, 3.0) is grids[1]
    op = local_convolution_operator(grids, depths_mm=[1.7, 2.2, 2.6, 3.0])
    assert op.shape_in[0] == 4 and list(op.depths) == pytest.approx([1.7, 2.2, 2.6, 3.0])


def test_fista_2d_and_3d_recover_points_with_the_local_model():
    rng = np.random.default_rng(7)
    grid = _grid(rng)
    op = local_convolution_operator(grid)
    p0, p1 = op.shape_in
    x = np.zeros(op.shape_in, np.float32)
    x[p0 // 2 - 3, p1 // 2 + 4] = 1.0
    x[p0 // 2 + 2, p1 // 2 - 2] = 0.7
    b = op.forward(x)
    res = fista(op, b / b.max(), iterations=300)
    assert res.final_relative_residual < 0.05
    est = res.x * b.max()
    assert np.unravel_index(np.argmax(est), est.shape) == (p0 // 2 - 3, p1 // 2 + 4)
    grids = [_grid(rng, z_mm=z, d_mm=3.8) for z in (2.0, 2.4)]
    op3 = local_convolution_operator(grids)
    v = np.zeros(op3.shape_in, np.float32)
    v[1, p0 // 2, p1 // 2] = 1.0
    b3 = op3.forward(v)
    res3 = fista3d(op3, b3 / b3.max(), iterations=100, l1=1e-4)
    assert res3.history.objective[-1] < 0.1 * res3.history.objective[0]


def test_bad_grids_are_refused_with_the_fix():
    rng = np.random.default_rng(8)
    h = rng.random((4, *SENSOR)).astype(np.float32)
    with pytest.raises(ReconInputError, match="does not hold"):
        PsfGrid(h, SHIFTS[:4], (3, 3))
    with pytest.raises(ReconInputError, match="not a grid"):
        PsfGrid(h, [(0, 0), (0, 5), (4, 0), (4, -5)], (2, 2))
    with pytest.raises(ReconInputError, match="rectangular raster"):
        PsfGrid.from_positions(h[:3], [(0, 0), (1, 0), (0, 1)])
    with pytest.raises(ReconInputError, match="all zero"):
        PsfGrid(np.zeros((1, *SENSOR)), [(0, 0)], (1, 1))
    reg, shifts, ref = register_psfs(h)
    assert reg.shape == h.shape and shifts.shape == (4, 2) and 0 <= ref < 4


def test_model_choice_takes_the_cheapest_model_that_suffices():
    from recon.spatial.choice import build_operator, choose_model, predicted_errors

    rng = np.random.default_rng(9)
    same = _grid(rng, identical=True)
    choice = choose_model(same)
    assert choice.label() == "convolution" and choice.convolutions == 1
    assert choice.predicted_error["convolution"] < 1e-6
    p1, p2 = rng.random((2, *SENSOR)).astype(np.float32) ** 4
    two = PsfGrid(np.stack([(1 - t) * p1 + t * p2 for t in np.linspace(0, 1, 9)]), SHIFTS,
                  (3, 3))
    choice = choose_model(two)
    assert choice.label() == "pca:2", choice.reason
    assert choice.predicted_error["pca:2"] < 1e-3 < choice.predicted_error["pca:1"]
    wild = PsfGrid(rng.random((9, *SENSOR)) ** 8, SHIFTS, (3, 3))
    choice = choose_model(wild)
    assert choice.model == "local" and choice.convolutions == 9
    errs = predicted_errors(wild)
    assert errs["convolution"] > 0.5 and errs["pca:8"] < errs["pca:1"]
    op = build_operator(same, "convolution")
    assert op.n_kernels == 1
    np.testing.assert_allclose(op.kernels[0] * op.scale, same.psfs[same.central], rtol=1e-6)
    measured = choose_model(same, measure=True, max_side=16, iterations=60)
    assert set(measured.measured_psnr_db) >= {"convolution", "local", "pca:1"}
    assert measured.label() == "convolution"
    assert abs(measured.measured_psnr_db["convolution"]
               - measured.measured_psnr_db["local"]) < 0.5
    measured = choose_model(wild, measure=True, max_side=16, iterations=60)
    assert measured.measured_psnr_db["local"] > measured.measured_psnr_db["convolution"] + 1


def test_two_point_resolution_follows_the_psf_across_the_field():
    from scipy.ndimage import gaussian_filter

    from recon.spatial.resolution import two_point_resolution

    rng = np.random.default_rng(10)
    shape = (40, 48)
    base = np.zeros(shape, np.float32)
    base[rng.integers(6, 34, 12), rng.integers(6, 42, 12)] = 1
    shifts = [((a - 1) * 10, (c - 1) * 12) for a in range(3) for c in range(3)]
    # sharp spots at the centre node, blurred ones (sigma 2.5 px) at the others
    psfs = [gaussian_filter(base, 0.5 if (a, c) == (1, 1) else 2.5)
            for a in range(3) for c in range(3)]
    op = local_convolution_operator(PsfGrid(np.stack(psfs), shifts, (3, 3)))
    res = two_point_resolution(op, [(0, 0), (10, 12)], [1, 2, 3, 4, 6, 8], iterations=150)
    centre, corner = (r["resolution_px"] for r in res)
    assert centre is not None and centre <= 3  # measured 2
    assert corner is None or corner >= 2 * centre  # measured 6
    with pytest.raises(ReconInputError, match="leaves the object grid"):
        two_point_resolution(op, [(0, 60)], [2])

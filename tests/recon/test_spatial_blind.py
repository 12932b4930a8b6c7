"""Compressive calibration by blind deconvolution (Sec. 5.4, Eq. 5.11-5.13)."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter, shift

from recon.analysis import register_shift
from recon.errors import ReconInputError
from recon.spatial import PsfGrid, local_convolution_operator
from recon.spatial.blind import _PsfModel, blind_calibration

SENSOR = (40, 48)
SPACING = (10, 12)
SHIFTS = [((a - 1) * SPACING[0], (c - 1) * SPACING[1]) for a in range(3) for c in range(3)]


def _truth(rng):
    """Nine PSFs of one diffuser pattern under a fall-off that moves across the field
    (the two-part model, Eq. 5.1)."""
    base = np.zeros(SENSOR, np.float32)
    base[rng.integers(8, 32, 10), rng.integers(8, 40, 10)] = 1
    base = gaussian_filter(base, 0.7)
    yy, xx = np.mgrid[:SENSOR[0], :SENSOR[1]]
    return np.stack([base * np.exp(-((yy - 20 + 1.5 * dy) ** 2 + (xx - 24 + 1.5 * dx) ** 2)
                                   / (2 * 12.0**2)) for dy, dx in SHIFTS]).astype(np.float32)


def _corr(estimate, truth):
    """Normalised inner product after the best shift (blind deconvolution leaves a
    global translation free)."""
    moved = shift(estimate, -np.asarray(register_shift(truth, estimate)), order=1)
    return float(np.vdot(moved, truth) / (np.linalg.norm(moved) * np.linalg.norm(truth)))


def test_psf_gradient_is_the_adjoint_of_the_psf_to_image_map():
    rng = np.random.default_rng(1)
    op = local_convolution_operator(PsfGrid(_truth(rng), SHIFTS, (3, 3)), normalize=False)
    model = _PsfModel(op, rng.random((1, *op.shape_in)).astype(np.float32))
    h = rng.standard_normal((9, *SENSOR)).astype(np.float32)
    r = rng.standard_normal(SENSOR).astype(np.float32)
    lhs = np.vdot(model.residuals(h, [np.zeros(SENSOR, np.float32)])[0], r)
    assert lhs == pytest.approx(np.vdot(h, model.gradient([r])), rel=1e-4)


def test_nine_psfs_from_four_bead_images_beat_the_central_psf():
    rng = np.random.default_rng(0)
    truth = _truth(rng)
    op = local_convolution_operator(PsfGrid(truth, SHIFTS, (3, 3)), normalize=False)
    p0, p1 = op.shape_in
    images = []
    for _ in range(4):  # N = 4 images of 8 beads at unknown positions, 1 % noise
        y = np.zeros(op.shape_in, np.float32)
        y[rng.integers(p0 // 2 - 12, p0 // 2 + 12, 8),
          rng.integers(p1 // 2 - 14, p1 // 2 + 14, 8)] = rng.uniform(0.5, 1, 8)
        b = op.forward(y)
        images.append(b + rng.normal(0, 0.01 * b.max(), SENSOR))
    res = blind_calibration(np.stack(images), (3, 3), SPACING, rounds=6)
    assert res.grid.n == 9 and res.objects.shape == (4, p0, p1)
    assert res.history["misfit_psfs"][-1] < 0.1 * res.history["misfit_objects"][0]
    got = np.array([_corr(res.grid.psfs[j], truth[j]) for j in range(9)])
    central = np.array([_corr(truth[4], truth[j]) for j in range(9)])
    off = np.arange(9) != 4
    assert got.min() > 0.75, got  # measured 0.81-0.97
    assert got[off].mean() > central[off].mean() + 0.05  # measured 0.93 against 0.80


def test_blind_calibration_refuses_bad_input():
    with pytest.raises(ReconInputError, match="N, rows, cols"):
        blind_calibration(np.zeros((4, 4)), (3, 3), 5)
    with pytest.raises(ReconInputError, match="all zero"):
        blind_calibration(np.zeros((2, 16, 16)), (3, 3), 5)
    with pytest.raises(ReconInputError, match="node_spacing_px"):
        blind_calibration(np.ones((2, 16, 16)), (3, 3), -1)
    with pytest.raises(ReconInputError, match="initial_psf"):
        blind_calibration(np.ones((2, 16, 16)), (3, 3), 5, initial_psf=np.ones((8, 8)))
    with pytest.raises(ReconInputError, match="max_rank"):
        blind_calibration(np.ones((2, 16, 16)), (3, 3), 5, max_rank=0)


def test_blind_calibration_starts_from_a_given_psf_and_keeps_the_rank_cap():
    """With the true central PSF as the start and rank <= 1 every node's PSF stays a
    multiple of one pattern (the central PSF refined)."""
    rng = np.random.default_rng(2)
    truth = _truth(rng)
    op = local_convolution_operator(PsfGrid(truth, SHIFTS, (3, 3)), normalize=False)
    y = np.zeros(op.shape_in, np.float32)
    y[op.shape_in[0] // 2 + rng.integers(-10, 10, 6), op.shape_in[1] // 2
      + rng.integers(-12, 12, 6)] = 1
    b = op.forward(y)[None]
    res = blind_calibration(b, (3, 3), SPACING, rounds=3, max_rank=1, initial_psf=truth[4],
                            object_iterations=40, psf_iterations=20)
    assert res.history["rank"] == [1, 1, 1]
    flat = res.grid.psfs.reshape(9, -1)
    s = np.linalg.svd(flat, compute_uv=False)
    assert s[1] < 1e-3 * s[0]
    assert _corr(res.grid.psfs[4], truth[4]) > 0.9

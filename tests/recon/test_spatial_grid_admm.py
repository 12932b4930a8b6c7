"""``reconstruct_grid(method="admm", two_part=...)``: a far scene through a PSF grid."""

from __future__ import annotations

import numpy as np
import pytest

from recon import reconstruct_grid
from recon.errors import ReconInputError
from recon.operators import ConvolutionOperator, padded_grid
from recon.spatial import PsfGrid

SHAPE = (64, 80)
STEP = (16, 20)


def _falloff(dy, dx):
    """Relative brightness of a point at offset (dy, dx) px from the axis."""
    return 1.0 - 2e-4 * (dy ** 2 + dx ** 2)


def _pattern(rng):
    h = np.zeros(SHAPE, np.float32)
    h[16:48, 20:60] = rng.random((32, 40)) ** 8
    return h / h.sum()


def _grid(pattern):
    """Two-part PSFs (Eq. 5.1): the pattern at every node times the brightness there,
    registered, zero where the light fell past the sensor."""
    shifts = [(dy, dx) for dy in (-STEP[0], 0, STEP[0]) for dx in (-STEP[1], 0, STEP[1])]
    psfs = np.stack([pattern * np.float32(_falloff(dy, dx)) for dy, dx in shifts])
    grid = PsfGrid(psfs, np.array(shifts, float), (3, 3))
    return PsfGrid(grid.psfs * grid.valid_masks(), grid.shifts_px, (3, 3))


def _object_offsets():
    padded, (top, left), _ = padded_grid(SHAPE)
    dy = np.arange(padded[0]) - padded[0] // 2
    dx = np.arange(padded[1]) - padded[1] // 2
    return padded, dy[:, None], dx[None, :]


def test_two_part_model_divides_the_brightness_out_of_a_far_scene():
    """A flat patch seen through a camera whose brightness falls off: the two-part
    model returns the patch flat; the same model without the division (the PSFs with
    their brightness, one convolution) shows the fall-off."""
    rng = np.random.default_rng(0)
    pattern = _pattern(rng)
    padded, dy, dx = _object_offsets()
    x = np.zeros(padded, np.float32)
    sl = (slice(padded[0] // 2 - 20, padded[0] // 2 + 20),
          slice(padded[1] // 2 - 26, padded[1] // 2 + 26))
    x[sl] = 1000.0
    seen = (_falloff(dy, dx) * x).astype(np.float32)  # what a far scene sends (Eq. 5.1)
    raw = ConvolutionOperator(pattern, padded_shape=padded).forward(seen)
    grid = _grid(pattern)
    rec = reconstruct_grid(grid, raw, method="admm", background="none", two_part=True,
                           model="convolution", iterations=300, tv=1e-4)
    assert rec.info["two_part"] and rec.info["tv"] == 1e-4
    _, (top, left), _ = padded_grid(SHAPE)
    inner = (slice(sl[0].start - top + 4, sl[0].stop - top - 4),
             slice(sl[1].start - left + 4, sl[1].stop - left - 4))
    patch = rec.image[inner]
    assert np.std(patch) < 0.03 * np.mean(patch), np.std(patch) / np.mean(patch)
    plain = reconstruct_grid(grid, raw, method="admm", background="none",
                             model="convolution", iterations=300, tv=1e-4)
    corner, centre = plain.image[inner][:4, :4].mean(), plain.image[inner][14:18, 22:26].mean()
    want = _falloff(-16, -22) / _falloff(0, 0)  # about what the corner keeps
    assert corner / centre == pytest.approx(want, abs=0.04)
    assert patch[:4, :4].mean() / patch[14:18, 22:26].mean() == pytest.approx(1.0, abs=0.03)


def test_automatic_weight_is_chosen_and_recorded():
    rng = np.random.default_rng(1)
    pattern = _pattern(rng)
    padded, dy, dx = _object_offsets()
    x = np.zeros(padded, np.float32)
    inner = x[padded[0] // 2 - 24:padded[0] // 2 + 24, padded[1] // 2 - 30:padded[1] // 2 + 30]
    inner[...] = np.kron(rng.random((6, 6)), np.ones((8, 10))) * 1000.0
    raw = ConvolutionOperator(pattern, padded_shape=padded).forward(_falloff(dy, dx) * x)
    raw = rng.poisson(np.maximum(raw, 0) * 50.0).astype(np.float32) / 50.0
    rec = reconstruct_grid(_grid(pattern), raw, method="admm", background="none",
                           two_part=True, iterations=150)
    auto = rec.info.auto[0]
    assert auto["weight"]["criterion"] == "holdout" and auto["weight"]["regulariser"] == "tv"
    assert rec.info["tv"] == auto["weight"]["weight"] > 0
    assert auto["method"]["method"] == "admm" and auto["snr_db"] > 10
    # the automatic weight's budget: 3.5x the fixed run's 150 iterations, all recorded
    assert 1 <= rec.info["iterations_used"] <= 525
    assert auto["weight"]["stop_reason"] and all("converged" in p
                                                 for p in auto["weight"]["path"])
    assert rec.image.shape == SHAPE and np.all(np.isfinite(rec.image))


def test_what_admm_cannot_do_is_refused_with_the_fix():
    rng = np.random.default_rng(2)
    grid = _grid(_pattern(rng))
    raw = rng.random(SHAPE).astype(np.float32)
    with pytest.raises(ReconInputError, match="background 'none'"):
        reconstruct_grid(grid, raw, method="admm")
    with pytest.raises(ReconInputError, match="unknown method 'wiener'"):
        reconstruct_grid(grid, raw, method="wiener")
    grids = [PsfGrid(grid.psfs, grid.shifts_px, (3, 3), z_mm=z) for z in (10.0, 20.0)]
    with pytest.raises(ReconInputError, match="one far plane"):
        reconstruct_grid(grids, raw, two_part=True)
    with pytest.raises(ReconInputError, match="reconstruct a volume with method 'fista'"):
        reconstruct_grid(grids, raw, method="admm", background="none", tv=1e-3)
    with pytest.raises(ReconInputError, match="(?i)tv weight"):
        reconstruct_grid(grid, raw, method="admm", background="none", tv="lots")

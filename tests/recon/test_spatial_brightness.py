"""Field brightness from a PSF grid (recon.spatial.brightness, Eq. 5.1)."""

from __future__ import annotations

import numpy as np
import pytest

from recon.errors import ReconInputError
from recon.operators import padded_grid
from recon.spatial import PsfGrid
from recon.spatial.brightness import (
    brightness_map,
    caustic_grid,
    correct_brightness,
    node_brightness,
)

SHAPE = (96, 128)


def _falloff(dy, dx):
    """A known brightness: 1 on axis, quadratic fall-off (cos^4-like at small angles)."""
    return 1.0 - 1.5e-5 * (dy ** 2 + 0.5 * dx ** 2) + 1e-3 * dx


def _grid(step=24):
    """Two-part-model PSFs (Eq. 5.1): one caustic pattern shifted to each node, times
    the brightness there, registered."""
    rng = np.random.default_rng(1)
    pattern = np.zeros(SHAPE, np.float32)
    pattern[24:72, 32:96] = rng.random((48, 64)) ** 8
    shifts = [(dy, dx) for dy in (-step, 0, step) for dx in (-step, 0, step)]
    # registered: each PSF shifted back onto the pattern, zero where the shifted light
    # fell past the sensor's edge
    registered = [pattern * np.float32(_falloff(dy, dx)) for dy, dx in shifts]
    grid = PsfGrid(np.stack(registered), np.array(shifts, float), (3, 3))
    return PsfGrid(grid.psfs * grid.valid_masks(), grid.shifts_px, (3, 3))


@pytest.mark.parametrize("step", [24, 40])
def test_node_brightness_is_each_psf_s_light_over_the_central_one(step):
    """At 40 px a third of the pattern falls past the sensor at the outer nodes: the
    light the sensor did not see is not counted as darkness."""
    grid = _grid(step)
    lost = 1 - grid.psfs[0].sum() / (_falloff(-step, -step) * grid.psfs[4].sum())
    assert (lost > 0.3) == (step == 40), lost
    want = [_falloff(dy, dx) for dy, dx in grid.shifts_px]
    assert node_brightness(grid) == pytest.approx(want, rel=1e-5)


def test_brightness_map_is_the_quadratic_through_the_nodes_on_the_object_grid():
    grid = _grid()
    m = brightness_map(grid)
    padded, (top, left), _ = padded_grid(SHAPE)
    dy = np.arange(SHAPE[0]) + top - padded[0] // 2
    dx = np.arange(SHAPE[1]) + left - padded[1] // 2
    want = _falloff(dy[:, None], dx[None, :])
    assert m.shape == SHAPE and m.dtype == np.float32
    np.testing.assert_allclose(m, want, rtol=1e-4)
    image = np.full(SHAPE, 2.0, np.float32) * want  # a flat scene as the model shows it
    np.testing.assert_allclose(correct_brightness(image, grid), 2.0, rtol=1e-4)
    rgb = np.repeat(image[:, :, None], 3, axis=2)
    np.testing.assert_allclose(correct_brightness(rgb, grid), 2.0, rtol=1e-4)


def test_bad_grids_and_images_are_refused_with_the_fix():
    grid = _grid()
    with pytest.raises(ReconInputError, match="at least 2 x 2"):
        brightness_map(grid.restrict(slice(1, 2), slice(1, 2)))
    with pytest.raises(ReconInputError, match="reconstruct at the grid's binning"):
        correct_brightness(np.ones((48, 64), np.float32), grid)
    # a 2 x 2 grid fits a plane (too few nodes for the quadratic)
    small = brightness_map(grid.restrict(slice(0, 2), slice(0, 2)))
    assert np.all(np.isfinite(small)) and small.min() > 0


def test_caustic_grid_divides_out_the_brightness_and_fills_unseen_pixels():
    """Each node's caustic is its PSF over its brightness; where the sensor did not see
    a node's registered PSF, the nearest node that saw the pixel gives it. Nodes carry
    the pattern plus their own tag here, so where a pixel came from shows."""
    rng = np.random.default_rng(2)
    pattern = np.zeros(SHAPE, np.float32)
    pattern[24:72, 32:96] = rng.random((48, 64)) ** 8
    step = 40
    shifts = np.array([(dy, dx) for dy in (-step, 0, step) for dx in (-step, 0, step)], float)
    tags = np.arange(1, 10, dtype=np.float32) * 1e-3
    bright = np.array([_falloff(dy, dx) for dy, dx in shifts], np.float32)
    psfs = np.stack([(pattern + tags[i]) * bright[i] for i in range(9)])
    seen = PsfGrid(psfs, shifts, (3, 3)).valid_masks()
    grid = PsfGrid(psfs * seen, shifts, (3, 3))
    out = caustic_grid(grid)
    assert out.grid_shape == (3, 3) and np.array_equal(out.shifts_px, grid.shifts_px)
    measured = node_brightness(grid)  # of pattern + tag: the tags shift it a little
    for i in range(9):
        np.testing.assert_allclose(out.psfs[i][seen[i]],
                                   ((pattern + tags[i]) * bright[i] / measured[i])[seen[i]],
                                   rtol=1e-5, atol=1e-7)
    # the corner node (-40, -40): pixels its sensor missed come from (-40, 0) -- the
    # nearest, before (0, -40) at the same distance (row-major) -- then the centre
    corner = out.psfs[0]
    from_edge = ~seen[0] & seen[1]
    from_side = ~seen[0] & ~seen[1] & seen[3]
    from_centre = ~seen[0] & ~seen[1] & ~seen[3]
    assert from_edge.any() and from_side.any() and from_centre.any()
    for where, node in ((from_edge, 1), (from_side, 3), (from_centre, 4)):
        want = (pattern + tags[node]) * bright[node] / measured[node]
        np.testing.assert_allclose(corner[where], want[where], rtol=1e-5, atol=1e-7)
    # and no kernel keeps a hole (the tags are > 0 everywhere the central node saw,
    # which is everywhere)
    assert seen[4].all() and out.psfs.min() > 0

"""A planar scene on the object grid of Eq. 3.3 (recon.optics.lensless.plane_on_object_grid):
the known scene of a PSF calibrated from displayed images and the truth reconstructions
are scored against, centred as the convolution model centres its PSF."""

from __future__ import annotations

import numpy as np
import pytest

from recon.errors import ReconInputError
from recon.optics.lensless import plane_on_object_grid

#: The small simulated bench of tests/calibration_routines/test_psf_from_scenes.py: a
#: 4.8 mm display at 20 mm, 8.9 mm from a 64 x 80 sensor of 39 um pixels.
Z_MM, WIDTH_MM, D_MM, PITCH_UM, SENSOR = 20.0, 4.8, 8.9, 39.0, (64, 80)


def _centre_of_mass(a: np.ndarray) -> tuple[float, float]:
    rows, cols = np.indices(a.shape)
    return float((rows * a).sum() / a.sum()), float((cols * a).sum() / a.sum())


@pytest.mark.parametrize("shape", [(96, 120), (95, 121), (64, 80), (7, 9)])
def test_a_scene_centred_on_the_axis_is_centred_on_the_psf_pixel(shape):
    """The axis is the centre of cell (rows // 2, cols // 2), the point the convolution
    model images to the on-axis PSF, for scenes spanning an even or odd number of
    cells alike (the 96 x 120 display spans 43.8 x 54.8 cells at 20 mm: rounded to 44
    rows and placed by whole cells, it sat half a cell off the axis)."""
    scene = np.ones(shape)
    out = plane_on_object_grid(scene, Z_MM, WIDTH_MM, D_MM, PITCH_UM, SENSOR)
    assert _centre_of_mass(out) == pytest.approx((SENSOR[0] // 2, SENSOR[1] // 2), abs=1e-9)
    # a scene lit on one side only moves its centre that way (inverted: u = -m x)
    left = scene.copy()
    left[:, shape[1] // 2:] = 0.0
    lit = plane_on_object_grid(left, Z_MM, WIDTH_MM, D_MM, PITCH_UM, SENSOR)
    assert _centre_of_mass(lit)[1] > SENSOR[1] // 2


def test_each_cell_holds_the_mean_radiance_over_it():
    """Radiance times area is conserved (no rounding of the scene's extent to whole
    cells), cells inside the scene hold its radiance, and partly covered edge cells
    their covered share."""
    q = PITCH_UM * 1e-3 * Z_MM / D_MM  # object cell, mm
    out = plane_on_object_grid(np.full((96, 120), 0.5), Z_MM, WIDTH_MM, D_MM, PITCH_UM,
                               SENSOR)
    assert out.sum() * q * q == pytest.approx(0.5 * WIDTH_MM * WIDTH_MM * 96 / 120, rel=1e-9)
    assert out[SENSOR[0] // 2, SENSOR[1] // 2] == pytest.approx(0.5)
    assert out.max() == pytest.approx(0.5) and out.min() == 0.0
    edge = out[SENSOR[0] // 2]
    partial = edge[(edge > 0) & (edge < 0.5 - 1e-12)]
    assert partial.size == 2  # one partly covered cell at each end of the row


def test_refuses_what_is_not_a_scene():
    with pytest.raises(ReconInputError, match="2D image"):
        plane_on_object_grid(np.ones(8), Z_MM, WIDTH_MM, D_MM, PITCH_UM, SENSOR)
    with pytest.raises(ReconInputError, match="z_mm"):
        plane_on_object_grid(np.ones((8, 8)), 0.0, WIDTH_MM, D_MM, PITCH_UM, SENSOR)

"""Two-point resolution with ray-traced measurements (Sec. 6.4, Fig. 6.4a)."""

import numpy as np
import pytest

from recon.errors import ReconInputError
from recon.optics.lensless import LenslessModel, microscope_geometry
from recon.spatial import PsfGrid, local_convolution_operator, ray_traced_pair
from recon.spatial.resolution import two_point_resolution


@pytest.fixture(scope="module")
def microscope():
    """The virtual microscope on a 34 x 60 sensor (92.8 um pixels), a 3 x 3 grid of
    ray-traced PSFs at z = 2.4 mm, 6 px apart, and its local model."""
    geo = microscope_geometry(seed=0, sensor_shape=(34, 60), sensor_pitch_um=92.8)
    model = LenslessModel(geo)
    z = 2.4
    q = geo.sensor_pitch_um * 1e-3 * z / geo.d_mm  # object-plane pixel, mm
    xy = [(c * 6 * q, r * 6 * q) for r in (-1, 0, 1) for c in (-1, 0, 1)]
    grid = PsfGrid.from_positions(np.stack([model.psf((x, y, z)) for x, y in xy]), xy, z_mm=z,
                                  d_mm=geo.d_mm)
    return model, z, local_convolution_operator(grid)


def test_ray_traced_points_land_where_the_local_model_puts_them(microscope):
    model, z, op = microscope
    images = ray_traced_pair(model, z, op.shape_in)
    c0, c1 = op.shape_in[0] // 2, op.shape_in[1] // 2
    for dr, dc in ((0, 0), (-6, 6), (6, -6)):  # grid nodes: exact pixels
        e = np.zeros(op.shape_in, np.float32)
        e[c0 + dr, c1 + dc] = 1
        a, b = op.forward(e), images([(c0 + dr, c1 + dc)])
        assert np.vdot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)) > 0.9
    moved = images([(c0 + 6, c1)])  # one node further down is not the same image
    e = np.zeros(op.shape_in, np.float32)
    e[c0, c1] = 1
    a = op.forward(e)
    assert np.vdot(a, moved) / (np.linalg.norm(a) * np.linalg.norm(moved)) < 0.8


def test_two_point_resolution_on_ray_traced_pairs(microscope):
    model, z, op = microscope
    res = two_point_resolution(op, [(0, 0), (5, 5)], [0.5, 2, 4], iterations=80,
                               truth_images=ray_traced_pair(model, z, op.shape_in))
    for r in res:  # half a pixel is never resolved; 4 px always (measured: 2 px)
        assert r["dips"][0.5] < 0.2 and r["dips"][4.0] >= 0.2
        assert r["resolution_px"] in (2.0, 4.0)
    with pytest.raises(ReconInputError, match="truth_images gave"):
        two_point_resolution(op, [(0, 0)], [2], iterations=5,
                             truth_images=lambda points: np.zeros((3, 3)))

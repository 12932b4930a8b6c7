"""Physics of the ray-traced lensless model (recon.optics.diffuser, recon.optics.lensless).

Kuo 2020: lateral shift -dx d/z (Eq. 3.1), axial scaling by (z + d)/z (Fig. 4.2),
brightness (inverse square, obliquity) and sensor fall-off (Eq. 5.1), mild spatial
variance after registration (Sec. 5.1, Fig. 5.1), the PSF filling the sensor at the
minimum distance (App. A.2), the diffuser statistics (Sec. 4.3, App. A.2, Sec. 6.3),
and the local convolution model (Eq. 5.4-5.5).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import ndimage, optimize

from recon.errors import ReconInputError
from recon.optics.diffuser import DiffuserSurface
from recon.optics.lensless import LenslessGeometry, LenslessModel, default_geometry
from recon.scenes import usaf_target


# ----------------------------------------------------------------------------- helpers
@pytest.fixture(scope="module")
def smooth():
    return LenslessModel(default_geometry("smooth"))


@pytest.fixture(scope="module")
def smooth_nofall(smooth):
    return LenslessModel(dataclasses.replace(smooth.geometry, falloff_sigma_deg=None))


@pytest.fixture(scope="module")
def microlens():
    return LenslessModel(default_geometry("microlens"))


def _ncc(a, b) -> float:
    """Normalised inner product <a, b> / (|a| |b|) (Eq. 3.11 for normalised PSFs)."""
    return float(np.vdot(a, b) / math.sqrt(np.vdot(a, a) * np.vdot(b, b)))


def _shift(ref, img) -> tuple[float, float]:
    """(rows, cols) translation of ``img`` relative to ``ref`` from the circular
    cross-correlation peak, refined by a parabola through the neighbours."""
    c = np.fft.irfft2(np.fft.rfft2(img) * np.conj(np.fft.rfft2(ref)), ref.shape)
    peak = np.unravel_index(int(np.argmax(c)), c.shape)
    out = []
    for ax in range(2):
        n, k = c.shape[ax], peak[ax]
        lo, hi = list(peak), list(peak)
        lo[ax], hi[ax] = (k - 1) % n, (k + 1) % n
        y0, y1, y2 = c[tuple(lo)], c[peak], c[tuple(hi)]
        s = k + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
        out.append(s - n if s > n / 2 else s)
    return out[0], out[1]


def _zoom(img, s):
    """``img`` magnified by ``s`` about the array centre (bilinear)."""
    c = (np.array(img.shape) - 1) / 2
    return ndimage.affine_transform(img, np.array([1 / s, 1 / s]), offset=c - c / s, order=1)


def _best_scale(near, far, lo=1.0, hi=1.5):
    """Magnification of ``far`` that best matches ``near`` (grid then bounded search)."""
    a, b = ndimage.gaussian_filter(near, 1.0), ndimage.gaussian_filter(far, 1.0)
    grid = np.arange(lo, hi, 0.01)
    k = int(np.argmax([_ncc(a, _zoom(b, s)) for s in grid]))
    res = optimize.minimize_scalar(lambda s: -_ncc(a, _zoom(b, s)),
                                   bounds=(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]),
                                   method="bounded", options={"xatol": 1e-5})
    return float(res.x), -float(res.fun)


def _solid_angle_fraction(aperture, z):
    """Omega / (4 pi) of a centred w x h rectangle seen from distance z on its axis."""
    a, b = aperture[0] / 2, aperture[1] / 2
    return 4 * math.atan(a * b / (z * math.sqrt(z * z + a * a + b * b))) / (4 * math.pi)


# ----------------------------------------------------------------------------- diffusers
def test_smooth_diffuser_slope_statistics():
    for slope in (0.7, 1.5):
        s = DiffuserSurface.smooth_random(3.0, slope_deg=slope, seed=1)
        gx, gy = s.slopes()
        mean_deg = float(np.degrees(np.mean(np.arctan(np.hypot(gx, gy)))))
        assert abs(mean_deg / slope - 1) < 0.10
        # Gaussian (isotropic) slope: |g| is Rayleigh, mean |g| / rms(g_x) = sqrt(pi / 2)
        ratio = np.mean(np.hypot(gx, gy)) / math.sqrt(0.5 * np.mean(gx**2 + gy**2))
        assert abs(ratio / math.sqrt(math.pi / 2) - 1) < 0.05
    np.testing.assert_allclose(s.deflection_rad(), (1.58 - 1) * s.slopes(), rtol=1e-12)


def test_smooth_diffuser_feature_size_is_the_correlation_length():
    s = DiffuserSurface.smooth_random(6.0, pitch_um=5.0, feature_um=140.0, seed=2)
    h = s.height_um - s.height_um.mean()
    shape = (2 * h.shape[0], 2 * h.shape[1])
    ac = np.fft.irfft2(np.abs(np.fft.rfft2(h, shape)) ** 2, shape)
    count = np.fft.irfft2(np.abs(np.fft.rfft2(np.ones_like(h), shape)) ** 2, shape)
    ac = ac / np.maximum(count, 1)
    ac /= ac[0, 0]
    lag = np.arange(80) * s.pitch_um
    cut = 0.5 * (ac[0, :80] + ac[:80, 0])
    one_over_e = float(np.interp(-math.exp(-1), -cut, lag))
    assert abs(one_over_e / 140.0 - 1) < 0.10


def test_slopes_of_a_tilted_plane():
    y, x = np.mgrid[0:20, 0:30].astype(float)
    s = DiffuserSurface(0.02 * x * 4.0 - 0.01 * y * 4.0, 4.0, 1.5)
    np.testing.assert_allclose(s.slopes()[0], 0.02, atol=1e-12)
    np.testing.assert_allclose(s.slopes()[1], -0.01, atol=1e-12)


def test_microlens_spacing_and_focal_length():
    s = DiffuserSurface.random_microlens(3.0, 2.5, lenslet_um=250.0, focal_mm=1.5,
                                         refractive_index=1.5, seed=3)
    from scipy.spatial import cKDTree

    c = s.centres_um
    nn = cKDTree(c).query(c, k=2)[0][:, 1]
    assert abs(np.mean(nn) / 250.0 - 1) < 0.05
    assert nn.min() > 0.7 * 250.0  # Poisson disc: no two lenslets nearly coincide
    # focal length from the cap curvature of the most central lenslet: h = h0 - r^2 / 2R
    x, y = s.coordinates_mm()
    k = int(np.argmin(np.hypot(c[:, 0], c[:, 1])))
    xx, yy = np.meshgrid(x * 1e3 - c[k, 0], y * 1e3 - c[k, 1])
    r2 = xx**2 + yy**2
    sel = r2 < 60.0**2  # inside the cell (neighbours are >= ~200 um away)
    coef = np.linalg.lstsq(np.column_stack([np.ones(sel.sum()), r2[sel]]),
                           s.height_um[sel], rcond=None)[0]
    focal_mm = -1.0 / (2.0 * coef[1]) / (1.5 - 1.0) * 1e-3
    assert abs(focal_mm / 1.5 - 1) < 0.02


def test_surfaces_are_deterministic_per_seed():
    a = DiffuserSurface.smooth_random(1.0, seed=5)
    b = DiffuserSurface.smooth_random(1.0, seed=5)
    c = DiffuserSurface.smooth_random(1.0, seed=6)
    assert np.array_equal(a.height_um, b.height_um)
    assert not np.allclose(a.height_um, c.height_um)
    m1 = DiffuserSurface.random_microlens(1.0, 5.0, seed=5)
    m2 = DiffuserSurface.random_microlens(1.0, 5.0, seed=5)
    m3 = DiffuserSurface.random_microlens(1.0, 5.0, seed=6)
    assert np.array_equal(m1.height_um, m2.height_um)
    assert not np.array_equal(m1.height_um, m3.height_um)


# ----------------------------------------------------------------------------- PSF physics
def test_psf_is_deterministic(smooth):
    a = smooth.psf((0.3, -0.2, 30.0))
    b = smooth.psf((0.3, -0.2, 30.0))
    assert a.dtype == np.float64 and a.shape == smooth.geometry.sensor_shape
    assert np.array_equal(a, b)


def test_a_converging_lenslet_obeys_the_thin_lens_law():
    """One spherical cap (f = 5 mm, n = 1.5): paraxially a ray through aperture point
    x lands at x (1 + d/z - d/f), so a uniformly lit square aperture of side a gives
    a uniform square of side a |1 + d/z - d/f| (before and after the focus)."""
    f, n, z, a = 5.0, 1.5, 20.0, 0.4
    radius = f * (n - 1) * 1e3
    y, x = (np.mgrid[0:301, 0:301] - 150) * 2.0
    cap = DiffuserSurface(np.sqrt(radius**2 - x * x - y * y) - radius, 2.0, n)
    for d in (3.0, 12.0):
        geo = LenslessGeometry(cap, d, (a, a), (96, 96), 5.0, None)
        h = LenslessModel(geo).psf((0.0, 0.0, z))
        cols = np.arange(96) - 47.5
        side = math.sqrt(12 * np.sum(h.sum(0) * cols**2) / h.sum()) * 5e-3  # uniform square
        assert abs(side / (a * abs(1 + d / z - d / f)) - 1) < 0.03


@pytest.mark.parametrize("z", [20.0, 60.0])
def test_lateral_shift_is_minus_dx_d_over_z(smooth, z):
    geo = smooth.geometry
    h0 = smooth.psf((0.0, 0.0, z))
    pitch = geo.sensor_pitch_um * 1e-3
    expected = -1.0 * geo.d_mm / z / pitch  # px, Eq. 3.1: m = d / z
    dr, dc = _shift(h0, smooth.psf((1.0, 0.0, z)))
    assert abs(dc - expected) < 0.15 and abs(dr) < 0.15
    dr, dc = _shift(h0, smooth.psf((0.0, 1.0, z)))
    assert abs(dr - expected) < 0.15 and abs(dc) < 0.15


def test_axial_move_scales_the_caustics_by_z_plus_d_over_z(smooth):
    d = smooth.geometry.d_mm
    near, far = smooth.psf((0.0, 0.0, 20.0)), smooth.psf((0.0, 0.0, 60.0))
    expected = ((20.0 + d) / 20.0) / ((60.0 + d) / 60.0)  # = 1.258: closer is larger
    scale, similarity = _best_scale(near, far)
    assert abs(scale / expected - 1) < 0.005
    assert similarity > 0.9
    blurred = ndimage.gaussian_filter(near, 1.0), ndimage.gaussian_filter(far, 1.0)
    assert _ncc(*blurred) < 0.6  # without the rescaling the patterns differ


def test_energy_is_the_aperture_solid_angle(smooth_nofall):
    geo = smooth_nofall.geometry
    for z in (25.0, 60.0):
        total = smooth_nofall.psf((0.0, 0.0, z)).sum()
        assert abs(total / _solid_angle_fraction(geo.aperture_mm, z) - 1) < 1e-5


def test_oblique_brightness_and_sensor_falloff(smooth, smooth_nofall):
    z = 30.0
    on_axis = smooth_nofall.psf((0.0, 0.0, z)).sum()
    for deg in (10.0, 20.0, 30.0):
        x = z * math.tan(math.radians(deg))
        geometric = smooth_nofall.psf((x, 0.0, z), registered=True).sum()
        assert abs(geometric / on_axis / math.cos(math.radians(deg)) ** 3 - 1) < 0.005
        with_f = smooth.psf((x, 0.0, z), registered=True).sum()
        f = math.exp(-(deg**2) / (2 * smooth.geometry.falloff_sigma_deg**2))
        assert abs(with_f / geometric / f - 1) < 0.01


def test_off_axis_psf_is_similar_but_not_identical(smooth):
    z = 30.0
    h0 = smooth.psf((0.0, 0.0, z))
    sims = {}
    for deg in (5.0, 15.0, 25.0):
        h = smooth.psf((z * math.tan(math.radians(deg)), 0.0, z), registered=True)
        dr, dc = _shift(h0, h)
        assert abs(dr) < 0.5 and abs(dc) < 0.5  # the paraxial registration holds
        sims[deg] = _ncc(h0, h)
    assert 0.7 < sims[15.0] < 0.999
    assert sims[5.0] > sims[15.0] > sims[25.0]


def test_min_z_psf_just_fits(smooth_nofall):
    geo = smooth_nofall.geometry

    def lost(z):  # fraction of the light through the aperture that misses the sensor
        return 1 - smooth_nofall.psf((0.0, 0.0, z)).sum() / _solid_angle_fraction(
            geo.aperture_mm, z)

    zmin = smooth_nofall.min_z_mm()
    assert 15.0 < zmin <= 20.0  # default_geometry sizes the aperture for 20 mm
    assert abs(lost(1.2 * zmin)) < 1e-6
    assert lost(zmin) < 1e-4  # just fits (bilinear splats at the very edge)
    assert lost(0.8 * zmin) > 0.01  # closer: the caustics spill over the edge
    small = dataclasses.replace(geo, aperture_mm=(geo.sensor_size_mm[0] * 0.999, 1.0))
    assert small.min_z_mm() == math.inf  # aperture + deflection wider than the sensor


def test_microlens_psf_is_sharp_spots_that_shift(microlens, smooth):
    z = 24.0
    h = microlens.psf((0.0, 0.0, z))
    contrast = h.max() / h.mean()
    assert contrast > 5 * (smooth.psf((0.0, 0.0, z)).max() / smooth.psf((0.0, 0.0, z)).mean())
    geo = microlens.geometry
    expected = -0.5 * geo.d_mm / z / (geo.sensor_pitch_um * 1e-3)
    dr, dc = _shift(h, microlens.psf((0.5, 0.0, z)))
    assert abs(dc - expected) < 0.25 and abs(dr) < 0.25


# ----------------------------------------------------------------------------- rendering
def test_render_points_is_the_sum_of_psfs(smooth):
    pts = [(0.5, 0.2, 30.0), (-1.0, 0.4, 45.0)]
    img = smooth.render_points(pts, [2.0, 3.0])
    ref = 2.0 * smooth.psf(pts[0]) + 3.0 * smooth.psf(pts[1])
    np.testing.assert_allclose(img, ref, rtol=1e-6, atol=1e-6 * ref.max())


def _aligned_scene(model, z, ov, size):
    """A field of view whose scene pixels coincide with the fine object cells."""
    q = model.geometry.sensor_pitch_um * 1e-3 / ov * z / model.geometry.d_mm
    return q, size * q


def test_render_of_one_pixel_is_its_psf_and_flips(smooth):
    z, ov, size = 30.0, 2, 401
    q, fov = _aligned_scene(smooth, z, ov, size)
    scene = np.zeros((size, size))
    scene[200, 200] = 1.0  # on the axis
    img = smooth.render(scene, z, fov, oversample=ov, patches=1)
    ref = 4 * math.pi * q * q * smooth.psf((0.0, 0.0, z), oversample=ov)  # Lambertian
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5 * ref.max())
    scene[200, 200], scene[200, 260] = 0.0, 1.0  # +60 cells in x
    shifted = smooth.render(scene, z, fov, oversample=ov, patches=1)
    dr, dc = _shift(img, shifted)
    assert abs(dc + 60 / ov) < 0.1 and abs(dr) < 0.1  # -m dx: 30 sensor px to the left


def test_local_convolution_approaches_the_exact_sum(smooth):
    z, ov, size = 30.0, 2, 1201  # field of view 26 mm: +-24 deg
    q, fov = _aligned_scene(smooth, z, ov, size)
    scene = np.zeros((size, size))
    pts, power = [], []
    for i in np.linspace(60, size - 61, 5).astype(int):
        for j in np.linspace(60, size - 61, 5).astype(int):
            scene[i, j] = 1.0
            x, y = (j + 0.5) * q - fov / 2, (i + 0.5) * q - fov / 2
            pts.append((x, y, z))
            power.append(4 * math.pi * q * q * z / math.sqrt(x * x + y * y + z * z))
    truth = smooth.render_points(pts, power, oversample=ov)
    err = {}
    for p in (1, 5):
        img = smooth.render(scene, z, fov, oversample=ov, patches=p)
        err[p] = np.linalg.norm(img - truth) / np.linalg.norm(truth)
        assert abs(img.sum() / truth.sum() - 1) < 0.05  # brightness per point is right
    assert err[5] < 0.08 and err[5] < 0.5 * err[1]


def test_tilted_target_partitions_depth(smooth):
    target = usaf_target((128, 128))
    flat = smooth.render_tilted_target(35.0, 35.0, 12.0, target=target, slices=3)
    direct = smooth.render(target, 35.0, 12.0, patches=1)
    np.testing.assert_allclose(flat, direct, rtol=1e-9, atol=1e-9 * direct.max())
    tilted = smooth.render_tilted_target(25.0, 45.0, 12.0, target=target, slices=3)
    assert np.all(np.isfinite(tilted)) and tilted.min() >= 0
    assert _ncc(tilted, flat) < 0.999  # depth matters


def test_usaf_target_has_shrinking_bars():
    t = usaf_target((256, 256))
    assert set(np.unique(t)) == {0.0, 1.0}
    runs = set()
    for row in t:
        edges = np.flatnonzero(np.diff(np.concatenate([[0], row, [0]])))
        runs.update((edges[1::2] - edges[::2]).tolist())
    assert {1, 2, 4, 8, 16} <= runs


# ----------------------------------------------------------------------------- bad input
def test_bad_inputs_are_refused(smooth):
    geo = smooth.geometry
    bad_geometry = [
        dict(d_mm=0.0), dict(d_mm=-1.0), dict(d_mm=float("nan")),
        dict(aperture_mm=(0.0, 1.0)), dict(aperture_mm=(1.0, -1.0)),
        dict(aperture_mm=(50.0, 1.0)),  # larger than the diffuser
        dict(sensor_shape=(1, 5)), dict(sensor_pitch_um=0.0), dict(falloff_sigma_deg=-2.0),
    ]
    for change in bad_geometry:
        with pytest.raises(ReconInputError):
            dataclasses.replace(geo, **change)
    for source in [(0.0, 0.0, 0.0), (0.0, 0.0, -5.0), (float("nan"), 0.0, 10.0), (1.0, 2.0)]:
        with pytest.raises(ReconInputError):
            smooth.psf(source)
    with pytest.raises(ReconInputError):
        smooth.psf((0.0, 0.0, 30.0), oversample=0)
    with pytest.raises(ReconInputError):
        smooth.render(-np.ones((8, 8)), 30.0, 5.0)
    with pytest.raises(ReconInputError):
        smooth.render(np.ones(8), 30.0, 5.0)
    with pytest.raises(ReconInputError):
        smooth.render(np.ones((8, 8)), 0.0, 5.0)
    with pytest.raises(ReconInputError):
        smooth.render(np.ones((8, 8)), 30.0, (0.0, 5.0))
    with pytest.raises(ReconInputError):
        smooth.render(np.ones((8, 8)), 30.0, 5.0, patches=0)
    with pytest.raises(ReconInputError):
        smooth.render_points([(0.0, 0.0, -1.0)], [1.0])
    with pytest.raises(ReconInputError):
        smooth.render_points([(0.0, 0.0, 10.0)], [1.0, 2.0])
    with pytest.raises(ReconInputError):
        smooth.render_points([(0.0, 0.0, 10.0)], [-1.0])
    with pytest.raises(ReconInputError):
        LenslessGeometry("glass", 8.9, (1.0, 1.0), (64, 64), 13.0)  # not a surface
    with pytest.raises(ReconInputError):
        default_geometry("glass")
    with pytest.raises(ReconInputError):
        usaf_target((8, 8))


def test_bad_surfaces_are_refused():
    with pytest.raises(ReconInputError):
        DiffuserSurface(np.zeros((4, 4)), 5.0, 1.0)  # no refraction
    with pytest.raises(ReconInputError):
        DiffuserSurface(np.zeros((4, 4)), 0.0, 1.5)
    with pytest.raises(ReconInputError):
        DiffuserSurface(np.full((4, 4), np.nan), 5.0, 1.5)
    with pytest.raises(ReconInputError):
        DiffuserSurface.smooth_random(0.0)
    with pytest.raises(ReconInputError):
        DiffuserSurface.smooth_random(1.0, pitch_um=50.0)  # cannot resolve 140 um
    with pytest.raises(ReconInputError):
        DiffuserSurface.random_microlens(1.0, 2.5, focal_mm=0.1)  # caps too curved

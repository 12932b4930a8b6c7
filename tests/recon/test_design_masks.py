"""Mask designs of Sec. 6.3: PSFs of the four designs, the regular array's periodicity,
the inner-product resolution predictor (Sec. 6.4) and the design benchmark."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recon.analysis.design import design_resolution, field_positions_mm
from recon.errors import ReconInputError
from recon.optics.design_masks import DESIGNS, MaskDesign, bin_fine
from recon.optics.diffuser import DiffuserSurface

SMALL = {"sensor_shape": (96, 96), "pitch_um": 23.2}


def _peaks(img: np.ndarray, frac: float = 0.3) -> np.ndarray:
    """(row, col) of local maxima above ``frac`` of the maximum."""
    from scipy.ndimage import maximum_filter

    mx = maximum_filter(img, size=7, mode="constant")
    return np.argwhere((img == mx) & (img > frac * img.max()))


def test_regular_surface_is_a_square_lattice_of_the_lenslets():
    s = DiffuserSurface.regular_microlens(1.0, 2.5, lenslet_um=250.0, focal_mm=1.5)
    c = s.centres_um
    assert np.allclose(np.mod(c + 125.0, 250.0), 0.0)  # (i + 1/2) * 250 um
    # one period along x leaves the height map unchanged (interior)
    k = int(round(250.0 / 2.5))
    h = s.height_um
    assert np.allclose(h[50:-50, 50:-50 - k], h[50:-50, 50 + k:-50], atol=1e-9)
    with pytest.raises(ReconInputError, match="focal length"):
        DiffuserSurface.regular_microlens(1.0, 2.5, lenslet_um=250.0, focal_mm=0.3)


def test_regular_psf_is_periodic_and_random_is_not():
    z = MaskDesign("random", **SMALL).conjugate_z_mm
    period = 250.0 * (1 + 3.8 / z) / 23.2  # spot spacing on the sensor, px
    for kind, periodic in (("regular", True), ("random", False)):
        psf = MaskDesign(kind, **SMALL).psf((0.0, 0.0, z))
        pk = _peaks(psf)
        assert len(pk) >= 6, kind
        # ghost peaks at the lattice pitch: every spot sits a whole number of periods
        # (along rows and columns) from the brightest one
        ref = np.unravel_index(psf.argmax(), psf.shape)
        off = (pk - np.array(ref)) / period
        on_lattice = np.all(np.abs(off - np.round(off)) < 0.08, axis=1)
        if periodic:
            assert on_lattice.all(), (kind, off)
        else:
            assert on_lattice.mean() < 0.5, (kind, off)


def test_four_designs_render_and_objective_focuses_one_plane():
    d = MaskDesign("objective", **SMALL)
    z0 = d.focus_z_mm
    assert d.focal_mm < d.d_mm and math.isclose(z0, 1 / (1 / 1.5 - 1 / 3.8))
    stack = bin_fine(d.psf_stack([z0 - 0.3, z0, z0 + 0.3], 3), 3)
    peak = stack.max(axis=(1, 2)) / stack.sum(axis=(1, 2))
    assert peak[1] > 0.95  # in focus: one pixel, at the model's zero shift
    assert np.unravel_index(stack[1].argmax(), stack[1].shape) == (48, 48)
    assert peak[0] < 0.2 and peak[2] < 0.2  # defocused: a disk
    for kind in DESIGNS[1:]:
        p = MaskDesign(kind, **SMALL).psf((0.0, 0.0, z0))
        assert p.shape == (96, 96) and p.sum() > 0 and np.all(p >= 0)
    with pytest.raises(ReconInputError, match="unknown mask design"):
        MaskDesign("pinhole")
    with pytest.raises(ReconInputError, match="f < d"):
        MaskDesign("random", focal_mm=4.0)


def test_predictor_known_answer_gaussian_spots():
    """With diffraction far above the pixels every spot is a Gaussian of standard
    deviation s = 0.42 lambda d / p; the inner product of shifted Gaussians is
    exp(-t^2 / (4 s^2)), so the 0.8 shift is 2 s sqrt(ln 1.25) (sensor px), and the
    object-space resolution is that times pitch * z / d."""
    lam_nm = 20000.0  # 20 um: s = 0.42 * 20 * 3.8 / 0.25 = 128 um, 11 px of 11.6 um
    d = MaskDesign("regular", (160, 160), 11.6, wavelength_nm=lam_nm, lenslet_um=250.0)
    z = d.conjugate_z_mm
    r = design_resolution(d, [z])
    s_px = 0.42 * lam_nm * 1e-3 * 3.8e3 / 250.0 / 11.6
    expect_px = 2 * s_px * math.sqrt(math.log(1.25))
    pos = r["depths"][0]["positions"]
    assert len(pos) == 12 and len(field_positions_mm(d, z)) == 12
    for p in pos:
        assert p["lateral_px"]["x"] == pytest.approx(expect_px, rel=0.12)
        assert p["lateral_um"]["x"] == pytest.approx(
            p["lateral_px"]["x"] * 11.6 * z / 3.8, rel=1e-9)


def test_predictor_ghosts_separate_regular_from_random():
    z = MaskDesign("random", **SMALL).conjugate_z_mm
    reg = design_resolution(MaskDesign("regular", **SMALL), [z])["depths"][0]["summary"]
    rnd = design_resolution(MaskDesign("random", **SMALL), [z])["depths"][0]["summary"]
    assert reg["ghost_inner_product"]["min"] > 0.8
    assert rnd["ghost_inner_product"]["mean"] < reg["ghost_inner_product"]["mean"] - 0.2
    assert 0 < rnd["lateral_um"]["mean"] < 50 and 0 < rnd["axial_um"]["mean"] < 1000
    with pytest.raises(ReconInputError, match="flat mask"):
        design_resolution(MaskDesign("objective", **SMALL), [z])


def test_design_benchmark_small_run(tmp_path):
    from benchmarks.design import design_table, run_design

    r = run_design(True, tmp_path, settings={"size": 48, "photons": (1e4,), "gaussian": (1.0,),
                                             "iterations": 15, "l1": (0.03,)})
    assert {"settings", "depths_mm", "psnr", "l1_chosen", "psf_peak_fraction", "ghosts",
            "ordering", "seconds", "images"} <= set(r)
    for sweep in ("photons", "gaussian"):
        for case in ("2d", "3d"):
            assert set(r["psnr"][sweep][case]) == set(DESIGNS)
            assert all(np.isfinite(v[0]) for v in r["psnr"][sweep][case].values())
    assert len(r["depths_mm"]["3d"]) == 3
    assert r["ghosts"]["regular"] > r["ghosts"]["random"]
    assert isinstance(r["ordering"]["random_best_flat_3d"], bool)
    assert (tmp_path / "design.png").stat().st_size > 10_000
    assert (tmp_path / "design.json").exists()
    text = design_table(r)
    assert "ordering photons_3d" in text and "random" in text
    with pytest.raises(ReconInputError, match="unknown designs"):
        run_design(True, None, designs=("pinhole",))

"""3D accuracy benchmark: scenes with model mismatch, metrics, and one ``--quick`` run.

The quick run (bin 4, 8 planes, 6 beads, a tilted target; about 20 s) is checked for
what would catch breakage: every bead within one plane at the end for both solvers,
the target's PSNR rising with iterations and beating the zero volume and the
back-projection. No timing thresholds (the machine is shared): speed figures are
only checked to exist.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.signal import fftconvolve

from benchmarks.volume_accuracy import (
    METHODS3D,
    RECON3D_DEFAULT,
    run_volume_accuracy,
    volume_psnr,
    volume_ssim,
)
from benchmarks.volume_scenes import make_bench, target_truth
from recon.errors import ReconInputError
from recon.preprocess import box_bin


@pytest.fixture(scope="module")
def bench():
    return make_bench(bin_factor=4, n_planes=8)


def test_plane_and_depth_mapping(bench):
    z = bench.depths_mm
    np.testing.assert_allclose(1 / z, np.linspace(1 / 24, 1 / 48, 8))
    np.testing.assert_allclose(bench.plane_of(z), np.arange(8), atol=1e-12)
    mid = 1 / (0.5 / z[2] + 0.5 / z[3])  # halfway in 1/z
    assert bench.plane_of(mid) == pytest.approx(2.5)
    assert bench.depth_of(2.5) == pytest.approx(mid)
    np.testing.assert_allclose(bench.voxel_of((0.0, 0.0, z[4]))[0], [4, *bench.centre])
    with pytest.raises(ReconInputError, match="within the planes"):
        bench.plane_of(60.0)


def test_an_off_axis_bead_lands_where_voxel_of_says(bench):
    """The rendered (ray-traced) bead correlates best with the on-axis PSF shifted to
    its voxel: the sign and size of the lateral mapping (m = d/z, image flipped)."""
    z = float(bench.depths_mm[3])
    xyz = (1.1, -0.7, z)  # mm
    image = box_bin(bench.model.render_points([xyz], [1.0]).astype(np.float32),
                    bench.bin_factor)
    psf = bench.op.psf_stack[3]
    corr = fftconvolve(image, psf[::-1, ::-1], mode="full")
    peak = np.array(np.unravel_index(np.argmax(corr), corr.shape), float)
    shift = peak - (np.array(psf.shape) - 1)  # image = psf shifted by this many pixels
    plane, row, col = bench.voxel_of(xyz)[0]
    assert plane == pytest.approx(3.0)
    np.testing.assert_allclose(shift, [row - bench.centre[0], col - bench.centre[1]], atol=0.6)
    assert shift[1] < 0 < shift[0]  # x > 0 moves left, y < 0 moves down


def test_target_truth_conserves_power_and_sits_between_its_depths(bench):
    target = np.ones((32, 32))
    truth = target_truth(bench, target, 26.0, 44.0, 4.0)
    assert truth.shape == (8, *bench.op.sensor_shape) and truth.dtype == np.float32
    # unit radiance over 4 x 4 mm: 4 pi * 16 mm^2, times cos(theta) >= 0.99 here
    assert truth.sum() == pytest.approx(4 * math.pi * 16.0, rel=0.012)
    occupied = np.flatnonzero(truth.sum(axis=(1, 2)) > 0)
    lo, hi = bench.plane_of([26.0 + 18 / 64, 44.0 - 18 / 64])
    assert occupied[0] == math.floor(lo) and occupied[-1] == math.ceil(hi)
    with pytest.raises(ReconInputError, match="non-negative"):
        target_truth(bench, -target, 26.0, 44.0, 4.0)


def test_volume_metrics():
    rng = np.random.default_rng(0)
    t = rng.random((7, 9, 8))
    assert volume_psnr(t, t) == math.inf and volume_ssim(3.0 * t, t) == pytest.approx(1.0)
    noisy = t + 0.05 * rng.standard_normal(t.shape)
    assert volume_psnr(2.0 * noisy, t) == pytest.approx(volume_psnr(noisy, t))
    assert 0 < volume_ssim(noisy, t) < 1
    assert volume_ssim(noisy[:3], t[:3]) < 1  # window shrinks to 3 planes
    with pytest.raises(ReconInputError, match="one shape"):
        volume_psnr(t, t[:2])
    with pytest.raises(ReconInputError, match="3 voxels"):
        volume_ssim(t[:2], t[:2])


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("volume_accuracy")
    return run_volume_accuracy(quick=True, out=out), out


def test_every_bead_within_one_plane_at_the_end(quick):
    result, _ = quick
    for m in METHODS3D:
        b = result["final"]["beads"][m]
        assert b["missed"] == 0 and b["within_one_plane"], (m, b)
        assert b["axial_planes_max_abs"] <= 1.0
        # lateral: well under one grid pixel in object space at the beads' depths
        assert b["lateral_um_mean"] < 0.5 * result["setup"]["pitch_um"] * 48 / 8.9
        assert len(b["per_bead"]) == result["setup"]["beads"]


def test_target_psnr_rises_and_beats_the_baselines(quick):
    result, _ = quick
    bl = result["baselines"]
    assert bl["back_projection"]["psnr"] > bl["zero_volume"]["psnr"] - 1.0
    for m in METHODS3D:
        pts = result["curves"]["target"][m]
        psnr = [p["psnr"] for p in pts]
        assert [p["iterations"] for p in pts] == result["setup"]["checkpoints"]
        assert psnr[-1] > psnr[0] + 0.3, (m, psnr)
        assert psnr[-1] > bl["back_projection"]["psnr"] + 0.5
        assert psnr[-1] > bl["zero_volume"]["psnr"] + 0.5
        assert pts[-1]["ssim"] > bl["back_projection"]["ssim"]
        secs = [p["seconds"] for p in pts]
        assert all(s > 0 for s in secs)  # timed separately: no order on a shared machine


def test_sweep_speed_conditioning_and_files(quick):
    result, out = quick
    for kind in ("beads", "target"):
        for m in METHODS3D:
            weights = {(r["tv"], r["l1"]) for r in result["sweep"][kind][m]}
            assert RECON3D_DEFAULT in weights and (0.0, 0.0) in weights
            w = result["chosen"][kind][m]
            assert (w["tv"], w["l1"]) in weights
    for m in METHODS3D:
        s = result["speed"][m]
        assert s["ratio_median"] > 0 and s["solves"] == 2 * len(result["setup"]["checkpoints"])
    ax = result["conditioning"]["axial"]
    one, two = ax[0]["condition"], ax[1]["condition"]
    assert np.all(np.diff(one) >= -1e-9) and one[0] > two[0] >= 1.0
    data = json.loads((out / "volume_accuracy.json").read_text())
    assert data["setup"]["ffts_per_iteration"] == {"rfft2": 9, "irfft2": 9}
    assert (out / "volume_accuracy.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

"""``recon3d --planes auto``: only the calibrated planes the camera resolves in depth."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile

from instrument.cli import main
from instrument.processing.planes import select_planes
from recon.errors import ReconInputError
from tests.recon.analysis.test_grid import D_MM, PITCH_MM, caustic_psf

#: A sweep four times finer in 1/z than the simulated caustics resolve (the
#: recommendation for the same stack at 5 depths spans 20-100 mm with a few planes).
DENSE = 1.0 / np.linspace(1 / 20.0, 1 / 100.0, 24)


@pytest.fixture(scope="module")
def dense_stack():
    rng = np.random.default_rng(0)
    stack = np.stack([caustic_psf(z) for z in DENSE]).astype(np.float32)
    order = rng.permutation(len(DENSE))  # any order of depths
    return stack[order], DENSE[order]


def test_select_planes_keeps_the_nearest_calibrated_plane_to_each_recommended_one(
        dense_stack):
    stack, z = dense_stack
    raw = stack.sum(axis=0)
    keep, record = select_planes(stack, z, raw, pitch_um=PITCH_MM * 1e3, d_mm=D_MM,
                                 bin_factor=1, dark="none")
    recommended = np.asarray(record["recommendation"]["depths_mm"])
    assert 2 <= len(keep) < len(z) and np.all(np.diff(keep) > 0)
    for depth in recommended:  # each recommended plane's nearest (in 1/z) is kept
        assert int(np.argmin(np.abs(1 / z - 1 / depth))) in keep
    assert record["kept_planes"] == len(keep) and "Nyquist" in record["reason"]
    near, _ = select_planes(stack, z, raw, pitch_um=PITCH_MM * 1e3, d_mm=D_MM, bin_factor=1,
                            dark="none",
                            scene_depth_range_mm=(20.0, 30.0))
    assert len(near) < len(keep) and np.all(z[near] <= 31.0)


def test_select_planes_needs_the_geometry(dense_stack):
    stack, z = dense_stack
    with pytest.raises(ReconInputError, match="--pitch-um.*--d-mm"):
        select_planes(stack, z, stack[0], pitch_um=None, d_mm=D_MM, bin_factor=1)


def test_recon3d_planes_auto_reconstructs_only_the_kept_planes(tmp_path, dense_stack):
    stack, z = dense_stack
    tifffile.imwrite(tmp_path / "stack.tif", stack)
    rng = np.random.default_rng(1)
    objects = np.zeros(stack.shape, np.float32)
    objects[:, 40:56, 40:56] = rng.random((len(z), 16, 16)) > 0.97
    from recon.volume import VolumeConvolutionOperator

    by_depth = np.argsort(z)
    raw = VolumeConvolutionOperator(stack[by_depth] / stack.sum(), depths=list(z[by_depth])
                                    ).forward(np.pad(objects, ((0, 0), (48, 48), (48, 48))))
    tifffile.imwrite(tmp_path / "raw.tif", raw.astype(np.float32))
    out = tmp_path / "vol.tif"
    status = main(["recon3d", "--psf-stack", str(tmp_path / "stack.tif"), "--depths",
                   ",".join(f"{v:.6f}" for v in z), "--raw", str(tmp_path / "raw.tif"),
                   "--tv", "0", "--iterations", "5", "--dark", "none", "--planes", "auto",
                   "--pitch-um", str(PITCH_MM * 1e3), "--d-mm", str(D_MM), "--out", str(out),
                   "--metrics-json", str(tmp_path / "m.json")])
    assert status == 0
    m = json.loads((tmp_path / "m.json").read_text())
    kept = m["planes"]["kept_planes"]
    assert kept < len(z) and tifffile.imread(out).shape[0] == kept == m["n_planes"]
    assert main(["recon3d", "--psf-stack", str(tmp_path / "stack.tif"), "--depths",
                 ",".join(f"{v:.6f}" for v in z), "--raw", str(tmp_path / "raw.tif"),
                 "--planes", "auto", "--out", str(tmp_path / "v2.tif")]) == 2

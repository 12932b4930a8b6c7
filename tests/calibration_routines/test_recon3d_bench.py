"""End-to-end check of 3D reconstruction: `diffuserlab recon3d` on a PSF stack and a bead
measurement both produced on the virtual bench by the calibration routines."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile

from calibration_routines import PsfSweepPlan
from instrument.acquisition.exposure import autoexpose, average_frames
from instrument.acquisition.runner import Runner
from instrument.cli import main
from instrument.devices.virtual_bench import BeadScene, VirtualBench

DEPTHS = [30.0, 40.0, 60.0]


@pytest.mark.parametrize("method", ["fista", "admm"])
def test_recon3d_finds_beads_at_their_planes_from_a_calibrated_stack(tmp_path, method):
    run = tmp_path / "sweep.zarr"
    beads = np.array([[0.6, -0.4, 30.0], [-0.8, 0.5, 60.0]])  # x, y, z in mm
    with VirtualBench(seed=7) as vb:
        plan = PsfSweepPlan.for_bench(vb, z_min_mm=30.0, z_max_mm=60.0, spacing="inverse",
                                      n_depths=3, frames_per_point=2)
        assert Runner(vb).run(plan, run).status == "complete"
        np.testing.assert_allclose(plan.depths_mm, DEPTHS)
        vb.set_scene(BeadScene(beads, np.array([4e11, 4e11])))
        autoexpose(vb.camera, bounds_s=(1e-5, 1.0))
        raw, _ = average_frames(vb.camera, 4)
        vb.set_scene(None)
        dark, _ = average_frames(vb.camera, 4)
    tifffile.imwrite(tmp_path / "raw.tif", (raw - dark).astype(np.float32))
    out = tmp_path / "volume.tif"
    status = main(["recon3d", "--psf-stack", str(run), "--raw", str(tmp_path / "raw.tif"),
                   "--method", method, "--iterations", "150", "--tv", "0", "--l1", "1e-4",
                   "--dark", "none", "--out", str(out),
                   "--metrics-json", str(tmp_path / "m.json")])
    assert status == 0
    volume = tifffile.imread(out)
    assert volume.shape == (3, 256, 320)
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["method"] == method
    # each bead: the brightest plane in a small window around its image position is
    # its own plane (the object grid is inverted and magnified: u = -m x, m = d/z)
    pitch, d = 0.013, 8.9
    for x, y, z in beads:
        m = d / z
        r = int(round(128 - m * y / pitch))
        c = int(round(160 - m * x / pitch))
        window = volume[:, max(r - 6, 0):r + 7, max(c - 6, 0):c + 7]
        assert int(np.argmax(window.reshape(3, -1).max(axis=1))) == DEPTHS.index(z), (x, y, z)

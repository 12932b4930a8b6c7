"""``recon.reconstruct_volume``: the 3D notebook API on a small synthetic bead problem.

The stack is caustic-like and magnified per depth (tests/instrument/cli/test_recon3d.py);
the measurement is the 3D forward model (Eq. 4.4) of three beads plus a little noise
and a dark level. The API must find the beads, keep the depths in ascending order
whatever the stack order, and give the volume ``diffuserlab recon3d`` writes.
"""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

import recon
from instrument.cli import main
from recon.errors import ReconInputError
from tests.instrument.cli.test_recon3d import BEADS, DEPTHS, bead_problem

DARK = 5.0


@pytest.fixture(scope="module")
def beads():
    stack, raw = bead_problem()
    return (100.0 * stack + DARK).astype(np.float32), (100.0 * raw + DARK).astype(np.float32)


@pytest.mark.parametrize("method", ["fista", "admm"])
def test_the_brightest_voxels_are_the_beads(beads, method):
    stack, raw = beads
    rec = recon.reconstruct_volume(stack, DEPTHS, raw, method=method, iterations=60,
                                   dark=DARK)
    assert isinstance(rec, recon.Reconstruction)
    assert rec.volume.shape == stack.shape and rec.volume.dtype == np.float32
    assert rec.depths_mm == sorted(DEPTHS)
    z, i, j = np.unravel_index(np.argmax(rec.volume), rec.volume.shape)
    assert (int(z), int(i), int(j)) in BEADS
    m = rec.metrics(floor_s=1e-3)
    assert m["method"] == method and m["n_planes"] == len(DEPTHS)
    assert m["dark_level"] == DARK and np.isfinite(m["final_relative_residual"])


def test_stack_order_does_not_matter(beads):
    stack, raw = beads
    order = [3, 0, 4, 2, 1]
    a = recon.reconstruct_volume(stack, DEPTHS, raw, method="fista", iterations=10)
    b = recon.reconstruct_volume(stack[order], [DEPTHS[k] for k in order], raw,
                                 method="fista", iterations=10)
    assert b.depths_mm == a.depths_mm
    np.testing.assert_array_equal(a.volume, b.volume)


def test_same_volume_as_recon3d_writes(beads, tmp_path, capsys):
    stack, raw = beads
    np.save(tmp_path / "stack.npy", stack)
    np.save(tmp_path / "raw.npy", raw)
    out = tmp_path / "v.tif"
    assert main(["recon3d", "--psf-stack", str(tmp_path / "stack.npy"), "--depths",
                 ",".join(map(str, DEPTHS)), "--raw", str(tmp_path / "raw.npy"), "--method",
                 "admm", "--iterations", "20", "--bin", "2", "--out", str(out)]) == 0
    capsys.readouterr()
    rec = recon.reconstruct_volume(stack, DEPTHS, raw, method="admm", iterations=20,
                                   bin_factor=2)
    np.testing.assert_array_equal(tifffile.imread(out), rec.volume)


@pytest.mark.parametrize("kwargs, message", [
    ({"method": "gd"}, "unknown method"),
    ({"iterations": 0}, "iterations"),
    ({"tv": -1.0}, "tv=-1.0 is outside its limits"),
    ({"depths": [1.0, 2.0]}, "one depth per plane"),
])
def test_bad_parameters(beads, kwargs, message):
    stack, raw = beads
    depths = kwargs.pop("depths", DEPTHS)
    with pytest.raises(ReconInputError, match=message):
        recon.reconstruct_volume(stack, depths, raw, **kwargs)

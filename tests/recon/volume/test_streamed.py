"""Streamed 3D FISTA over plane slabs (recon.volume.streamed) against the in-memory solver.

The streamed solver must be the in-memory 3D FISTA (recon.volume.fista3d) with the
planes transformed one chunk at a time: on the padded grid it equals fista3d on the
VolumeConvolutionOperator; on the sensor's field of view it equals fista3d on the
same model restricted to the sensor (relative 1e-5 either way), for one slab or
several. ``recon.reconstruct`` picks it when the in-memory plan does not fit the
memory limit, says so, and still finds the beads at their planes.
"""

from __future__ import annotations

import numpy as np
import pytest

import recon
from recon.errors import ReconInputError
from recon.operators import LinearOperator
from recon.volume import VolumeConvolutionOperator, fista3d
from recon.volume.memory_plan import in_memory_bytes, memory_plan
from recon.volume.slab import VolumeSlab
from recon.volume.streamed import (
    peak_rss_bytes,
    plan_slabs,
    streamed_fista3d,
    streamed_memory_bytes,
)
from tests.instrument.cli.test_recon3d import BEADS, DEPTHS, bead_problem, normalized_bead_problem

REL = 1e-5


class SensorSupport(LinearOperator):
    """The volume model with the object zero outside the sensor's field of view."""

    def __init__(self, op: VolumeConvolutionOperator):
        self.op = op
        self.shape_in = (op.n_z, *op.sensor_shape)
        self.shape_out = op.shape_out

    def forward(self, x):
        full = np.zeros(self.op.shape_in, np.float32)
        full[(slice(None), *self.op.crop)] = x
        return self.op.forward(full)

    def adjoint(self, y):
        return np.ascontiguousarray(self.op.adjoint(y)[(slice(None), *self.op.crop)])


@pytest.fixture(scope="module")
def problem():
    return normalized_bead_problem()


def _rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize("slabs", [1, 2, 5])
@pytest.mark.parametrize("tv, l1", [(0.0, 0.0), (1e-3, 1e-4)])
def test_padded_support_equals_fista3d(problem, slabs, tv, l1):
    stack, scale, b, op, lip = problem
    ref = fista3d(op, b, iterations=25, tv=tv, l1=l1, lipschitz=lip)
    got = streamed_fista3d(stack, b, psf_scale=scale, slabs=slabs, support="padded",
                           iterations=25, tv=tv, l1=l1, lipschitz=lip)
    assert got.x.shape == op.shape_in
    assert _rel(got.x, ref.x) < REL
    np.testing.assert_allclose(got.history.objective, ref.history.objective, rtol=REL)
    assert got.history.extra["restarts"] == ref.history.extra["restarts"]
    assert got.final_objective == pytest.approx(ref.final_objective, rel=REL)
    assert got.params["bytes_moved_per_iteration"] == [0.0] * slabs


@pytest.mark.parametrize("slabs", [1, 3])
def test_sensor_support_equals_fista3d_on_the_restricted_model(problem, slabs):
    stack, scale, b, op, lip = problem
    ref = fista3d(SensorSupport(op), b, iterations=25, tv=1e-3, lipschitz=lip)
    got = streamed_fista3d(stack, b, psf_scale=scale, slabs=slabs, support="sensor",
                           iterations=25, tv=1e-3, lipschitz=lip)
    assert got.x.shape == (op.n_z, *op.sensor_shape)
    assert _rel(got.x, ref.x) < REL
    np.testing.assert_allclose(got.history.objective, ref.history.objective, rtol=REL)


def test_default_step_is_the_lipschitz_bound(problem):
    stack, scale, b, op, lip = problem
    got = streamed_fista3d(stack, b, psf_scale=scale, slabs=2, iterations=2)
    assert got.params["lipschitz"] == pytest.approx(lip, rel=1e-6)


def test_plan_slabs_covers_every_plane_once():
    assert plan_slabs(128, 2) == [(0, 64), (64, 128)]
    plan = plan_slabs(7, 3)
    assert plan[0][0] == 0 and plan[-1][1] == 7
    assert all(a < z for a, z in plan)
    assert all(p[1] == q[0] for p, q in zip(plan[:-1], plan[1:], strict=True))
    with pytest.raises(ReconInputError, match="at most one slab per plane"):
        plan_slabs(3, 4)


def test_slab_memory_matches_the_estimate(problem):
    stack, scale, *_ = problem
    slab = VolumeSlab(stack, 0, len(stack), scale)
    est = streamed_memory_bytes(stack.shape[1:], len(stack))
    held = slab.memory_bytes()
    # the estimate adds the FFT temporaries and sensor images the slab does not hold
    assert est["psf_spectra"] == slab.spectra.nbytes
    assert est["iterates"] == slab.x.nbytes * 3
    assert held <= est["total"] <= held + est["chunk_buffers"] + est["plane_buffers"] \
        + est["sensor_images"]


def test_seed_size_estimate_fits_20_gb():
    est = streamed_memory_bytes((2048, 2048), 128)
    assert est["psf_spectra"] == 128 * 4096 * 2049 * 8
    assert est["iterates"] == 3 * 128 * 2048 * 2048 * 4
    assert est["total"] < 17e9
    assert in_memory_bytes("fista", False, (2048, 2048), 128) > 40e9


def test_bad_slabs_are_refused(problem):
    stack, scale, *_ = problem
    with pytest.raises(ReconInputError, match="support"):
        VolumeSlab(stack, 0, 2, scale, support="volume")
    with pytest.raises(ReconInputError, match="non-empty range"):
        VolumeSlab(stack, 3, 3, scale)
    bad = stack.copy()
    bad[2] = 0
    with pytest.raises(ReconInputError, match=r"PSF planes \[2\] are all zero"):
        VolumeSlab(bad, 1, 4, scale)


def test_memory_plan_says_what_fits():
    small = memory_plan("fista", False, (64, 64), 5, None)
    assert not small["streamed"] and small["limit_source"] == "available"
    tight = memory_plan("admm", True, (64, 64), 5, 1_000_000)
    assert tight["streamed"] and "--memory-limit" in tight["reason"]
    assert "streamed 3D FISTA" in tight["reason"]
    with pytest.raises(ReconInputError, match="--memory-limit 16GB"):
        memory_plan("fista", False, (64, 64), 5, 0)


def test_reconstruct_streams_when_the_plan_does_not_fit():
    stack, raw = bead_problem()
    lines = []
    rec = recon.reconstruct_volume(stack, DEPTHS, raw, method="admm", iterations=60,
                                   memory_limit_bytes=1_000_000, announce=lines.append)
    assert rec.info.method == "fista" and "streamed 3D FISTA" in rec.info.method_reason
    assert "automatic weight" in rec.info.method_reason  # tv="auto" became a fixed weight
    assert any("estimated peak memory" in line for line in lines)
    assert rec.volume.shape == stack.shape
    brightest = np.argsort(rec.volume.ravel())[::-1][:3]
    found = {tuple(int(a) for a in np.unravel_index(k, rec.volume.shape)) for k in brightest}
    assert found == set(BEADS)
    m = rec.metrics(floor_s=1.0)
    mem = m["memory"]
    assert mem["peak_rss_bytes"] == peak_rss_bytes() or mem["peak_rss_bytes"] > 0
    assert mem["estimate_bytes"] > mem["arrays"]["total"]
    assert m["memory_plan"]["streamed"] and m["support"] == "sensor"

"""Streamed 3D FISTA over plane slabs (recon.volume.streamed) against the in-memory solver.

The streamed solver must be the in-memory 3D FISTA (recon.volume.fista3d) with the
planes transformed one chunk at a time: on the padded grid it equals fista3d on the
VolumeConvolutionOperator; on the sensor's field of view it equals fista3d on the
same model restricted to the sensor (relative 1e-5 either way), for one slab or
several. ``recon.reconstruct`` picks it when the in-memory plan does not fit the
memory limit, says so, and still finds the beads at their planes.

Its automatic weight (recon.volume.streamed_auto) is the held-out path of
recon.auto.weight.admm_auto over the slabs: it must choose what the same path chooses
with 3D FISTA on the in-memory model (built here from the same pieces: fista3d's
kernels behind admm_auto's plan interface; the in-memory automatic weight is a 3D ADMM
path), with the same held-out blocks and rule -- the same weight, the same candidates
and statuses, the volume to 1e-5 relative -- both where the held-out blocks hide
object pixels (the bead stack's compact caustics: the chosen weight is solved again on
every pixel) and where they do not (a full-field PSF: the result stays on the fit
pixels); and it must hold no more copies of the iterates than the memory estimate
counts.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

import recon
from recon.auto.noise import NoiseModel
from recon.auto.volume import VOLUME_RULES, weighted_variance
from recon.auto.weight import admm_auto
from recon.errors import ReconInputError
from recon.operators import LinearOperator
from recon.solvers.accelerated import fista_momentum
from recon.solvers.common import Monitor, SolveResult
from recon.solvers.gradient import prox_threshold
from recon.volume import VolumeConvolutionOperator, _kernels3d, fista3d, normalize_psf_stack
from recon.volume.fista import final_objective
from recon.volume.memory_plan import in_memory_bytes, memory_plan
from recon.volume.slab import VolumeSlab
from recon.volume.streamed import (
    LocalSlabs,
    peak_rss_bytes,
    plan_slabs,
    slab_fista,
    streamed_fista3d,
    streamed_memory_bytes,
)
from recon.volume.streamed_auto import auto_streamed, path_copies
from tests.instrument.cli.test_recon3d import BEADS, DEPTHS, bead_problem, normalized_bead_problem
from tests.recon.volume.test_memory_plan import BASELINE, bead_limit, fix_baseline

REL = 1e-5
#: A noise model in the units of the scaled measurement (its energy only scales the
#: all-pixel final solve's stopping rule).
NOISE = NoiseModel(1e-4, 1e-6, [])


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


class MemoryFistaState:
    """3D FISTA's state on the in-memory model: x, y on the padded grid and t."""

    mu = ()

    def __init__(self, op: VolumeConvolutionOperator):
        self.op = op
        self.x = np.zeros(op.shape_in, np.float32)
        self.y = np.zeros_like(self.x)
        self.t = 1.0

    @property
    def mx(self) -> np.ndarray:
        """The uncropped, unweighted prediction of x (what admm_auto crops and scores)."""
        return self.op.convolve_full(self.x)


class MemoryFistaPlan:
    """3D FISTA on the in-memory model (fista3d's data term and fused proximal step, its
    momentum and gradient restart) with admm_auto's plan interface: the in-memory
    counterpart of recon.volume.streamed_auto.StreamedFistaPlan, windows continuing
    x, y and t."""

    def __init__(self, op: VolumeConvolutionOperator, power_max: float):
        self.op = op
        self.lipschitz = power_max * float(op.sensor_weights.max()) ** 2

    @classmethod
    def maker(cls, power_max: float):
        return lambda op: cls(op, power_max)

    def zeros(self, mu=None, use_tv=True) -> MemoryFistaState:
        return MemoryFistaState(self.op)

    def warm(self, x, mu=None, use_tv=True) -> MemoryFistaState:
        state = MemoryFistaState(self.op)
        state.x[...] = x
        state.y[...] = x
        return state

    def run(self, b, state, *, iterations, tv, l1=0.0, final=True) -> SolveResult:
        step = 1.0 / self.lipschitz
        thr, l1thr = prox_threshold(step, tv, 3), step * l1
        mon = Monitor(float(np.vdot(b, b)), "in-memory 3D FISTA")
        grad, y_next = np.empty_like(state.x), np.empty_like(state.x)
        for _ in range(iterations):
            mon.start()
            loss, _ = self.op.data_term(state.y, b, out=grad)
            t_next, beta = fista_momentum(state.t)
            tv_y, l1_y, dot = _kernels3d.proximal_step_3d(state.y, grad, state.x, y_next, step,
                                                         thr, l1thr, beta, True)
            if dot > 0.0:
                y_next[...] = state.x
                t_next = 1.0
            state.t = t_next
            state.y, y_next = y_next, state.y
            mon.record(loss + tv * tv_y + l1 * l1_y, 2.0 * loss)
        return SolveResult(state.x, mon.history, mon.history.objective[-1],
                           mon.history.data_residual[-1], {"t": state.t})

    def objective(self, b, x, *, tv, l1, b_norm):
        final, data_sq = final_objective(self.op, x, b, tv, l1)
        return final, math.sqrt(data_sq) / b_norm


def wide_problem(n: int = 64, n_z: int = 5) -> tuple:
    """(stack, scale, b, op, L) as normalized_bead_problem, with a PSF that fills the
    sensor (smoothed noise above its median on every plane): the 8 x 8 held-out blocks
    hide no object pixel (coverage 0.63), so the automatic result stays on the fit
    pixels."""
    rng = np.random.default_rng(0)
    planes = []
    for _ in range(n_z):
        g = gaussian_filter(rng.standard_normal((n, n)), 2.0)
        planes.append(np.maximum(g - np.quantile(g, 0.5), 0.0))
    stack = np.array(planes, np.float32)
    h, scale = normalize_psf_stack(stack)
    op = VolumeConvolutionOperator(h)
    truth = np.zeros(op.shape_in, np.float32)
    top, left = op.offset
    for z, i, j in [(1, 12, 30), (3, 40, 14), (3, 20, 50), (0, 50, 50)]:
        truth[z, top + i - 2:top + i + 2, left + j - 2:left + j + 2] = 1.0
    raw = op.forward(truth)
    raw = raw + 0.02 * raw.max() * rng.standard_normal(raw.shape)
    b = (raw / np.abs(raw).max()).astype(np.float32)
    return stack, scale, b, op, op.lipschitz_bound()


@pytest.fixture(scope="module")
def problem():
    return normalized_bead_problem()


@pytest.fixture(scope="module")
def wide():
    return wide_problem()


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
    small = memory_plan("fista", False, (64, 64), 5, None, bin_factor=1)
    assert not small["streamed"] and small["limit_source"] == "available"
    streamed = small["plans"][1]["estimate_bytes"] - small["baseline_bytes"]
    tight = memory_plan("admm", True, (64, 64), 5, BASELINE + streamed, bin_factor=1,
                        baseline_bytes=BASELINE)
    assert tight["streamed"] and "--memory-limit" in tight["reason"]
    assert "streamed 3D FISTA" in tight["reason"]
    with pytest.raises(ReconInputError, match="--memory-limit 16GB"):
        memory_plan("fista", False, (64, 64), 5, 0, bin_factor=1)


def _found(volume: np.ndarray) -> set:
    brightest = np.argsort(volume.ravel())[::-1][:3]
    return {tuple(int(a) for a in np.unravel_index(k, volume.shape)) for k in brightest}


def test_reconstruct_streams_when_the_plan_does_not_fit(monkeypatch):
    """The default weight (auto) on a problem that streams: the held-out path over the
    slabs chooses it, says so, and records it; its copies are those estimated."""
    fix_baseline(monkeypatch)
    stack, raw = bead_problem()
    lines = []
    limit = bead_limit("streamed", "tv")
    rec = recon.reconstruct_volume(stack, DEPTHS, raw, method="admm", iterations=60,
                                   memory_limit_bytes=limit, announce=lines.append)
    assert rec.info.method == "fista" and "streamed 3D FISTA" in rec.info.method_reason
    assert "automatic tv weight: the held-out path" in rec.info.method_reason
    assert any("automatic tv weight: the held-out path" in line for line in lines)
    estimate = rec.info.extra["memory"]["estimate_bytes"]
    assert estimate == rec.info.extra["memory_plan"]["estimate_bytes"] <= limit
    assert any(f"estimated peak memory {estimate / 1e9:.2f} GB" in line
               and "4 copies of the iterates" in line for line in lines)
    auto = rec.info.auto[0]
    assert auto["weight"] == rec.info.tv and auto["regulariser"] == "tv"
    choice = auto["weight_choice"]
    assert choice["criterion"] == "holdout" and choice["stop_reason"]
    # 3.5 x 60, less the final solve's 60 on every pixel (the caustics are compact: the
    # held-out blocks hide object pixels)
    assert 0 < choice["path_iterations"] <= choice["budget_iterations"] == 150
    assert choice["final_pixels"].startswith("all") and choice["final_iterations"] <= 60
    assert all({"weight", "holdout_error", "status", "converged",
                "remaining_in_standard_errors"} <= set(p) for p in choice["path"])
    assert auto["planes_kept"] == list(range(len(DEPTHS))) and "not tested" in auto["reason"]
    assert auto["noise"] and "8 x 8 blocks" in auto["reason"]
    assert rec.volume.shape == stack.shape
    assert _found(rec.volume) == set(BEADS)
    m = rec.metrics(floor_s=1.0)
    assert m["auto"]["weight"] == m["tv"]
    mem = m["memory"]
    assert mem["peak_rss_bytes"] == peak_rss_bytes() or mem["peak_rss_bytes"] > 0
    assert mem["estimate_bytes"] > mem["arrays"]["total"]
    # the path's copies of the iterates: at their most, exactly the estimate's
    assert mem["path_copies_peak_bytes"] == mem["arrays"]["path_copies"] > 0
    assert m["memory_plan"]["streamed"] and m["support"] == "sensor"


def test_reconstruct_streams_a_fixed_weight_as_given(monkeypatch):
    fix_baseline(monkeypatch)
    stack, raw = bead_problem()
    rec = recon.reconstruct_volume(stack, DEPTHS, raw, method="fista", iterations=60,
                                   tv=1e-4, memory_limit_bytes=bead_limit("streamed", None,
                                                                          "fista"))
    assert rec.info.tv == 1e-4 and not rec.info.auto
    assert "automatic" not in rec.info.method_reason
    assert "path_copies" not in rec.metrics(floor_s=1.0)["memory"]["arrays"]
    assert _found(rec.volume) == set(BEADS)


@pytest.mark.parametrize("case", ["beads", "wide"])
def test_streamed_auto_chooses_what_the_in_memory_fista_path_chooses(case, problem, wide):
    stack, scale, b, op, lip = problem if case == "beads" else wide
    energy = float(weighted_variance(op.sensor_weights, NOISE, b).sum())
    ref, ref_choice = admm_auto(op, b, iterations=60, noise_energy=energy,
                                rule=VOLUME_RULES["tv"], plan_of=MemoryFistaPlan.maker(lip))
    slab = VolumeSlab(stack, 0, len(stack), scale, support="padded")
    got, record = auto_streamed(LocalSlabs([slab]), b, noise=NOISE, iterations=60)
    choice = record["weight_choice"]
    assert record["weight"] == choice["weight"] == ref_choice.weight
    assert [(p["weight"], p["status"], p["iterations"], p["kept_iteration"])
            for p in choice["path"]] == \
        [(p["weight"], p["status"], p["iterations"], p["kept_iteration"])
         for p in ref_choice.path]
    np.testing.assert_allclose([p["holdout_error"] for p in choice["path"]],
                               [p["holdout_error"] for p in ref_choice.path], rtol=1e-4)
    assert choice["stop_reason"] == ref_choice.stop_reason
    assert choice["path_iterations"] == ref_choice.path_iterations
    assert choice["holdout_coverage"] == pytest.approx(ref_choice.holdout_coverage, rel=1e-5)
    assert choice["final_pixels"] == ref_choice.final_pixels == (
        "fit, held-out watched" if case == "wide"
        else "all (the held-out blocks hide object pixels)")
    assert got.x.shape == ref.x.shape == op.shape_in
    assert _rel(got.x, ref.x) < REL
    assert got.params["iterations_used"] == ref.params["iterations_used"]
    assert got.final_objective == pytest.approx(ref.final_objective, rel=REL)
    assert record["planes_kept"] == list(range(len(stack)))
    # the path held at most the copies the memory estimate counts, and that many
    assert slab.peak_saved_bytes == path_copies(VOLUME_RULES["tv"]) * slab.x.nbytes


def test_slab_fista_continues_across_windows(problem):
    """Windows with the momentum handed on are one run, iterate for iterate."""
    stack, scale, b, op, lip = problem
    one = streamed_fista3d(stack, b, psf_scale=scale, slabs=2, iterations=25, tv=1e-3,
                           lipschitz=lip)
    group = LocalSlabs([VolumeSlab(stack, a, z, scale) for a, z in plan_slabs(len(stack), 2)])
    first = slab_fista(group, b, iterations=10, tv=1e-3, lipschitz=lip, final=False,
                       gather=False)
    assert first.x is None and first.final_objective == first.history.objective[-1]
    rest = slab_fista(group, b, iterations=15, tv=1e-3, lipschitz=lip, t=first.params["t"])
    np.testing.assert_array_equal(rest.x, one.x)
    assert first.history.objective + rest.history.objective == one.history.objective


def test_slab_keeps_named_copies(problem):
    stack, scale, *_ = problem
    slab = VolumeSlab(stack, 0, len(stack), scale)
    base = slab.memory_bytes()
    slab.x[...] = 1.0
    slab.y[...] = 2.0
    slab.save("a")
    slab.save("s", state=True)
    slab.save("t", "s", state=True)
    slab.x[...] = 3.0
    assert slab.saved_bytes() == slab.peak_saved_bytes == 5 * slab.x.nbytes
    assert slab.memory_bytes() == base + 5 * slab.x.nbytes
    np.testing.assert_array_equal(slab.estimate("a"), 1.0)
    ones = slab.forward("a")
    slab.restore("t")
    assert np.all(slab.x == 1.0) and np.all(slab.y == 2.0)
    np.testing.assert_array_equal(slab.forward("x"), ones)
    slab.x[...] = 0.0
    slab.restore("a")
    assert np.all(slab.x == 1.0) and np.all(slab.y == 1.0)
    with pytest.raises(ReconInputError, match="exists already"):
        slab.save("a")
    slab.release(["a", "s", "t", "gone"])
    assert slab.saved_bytes() == 0 and slab.peak_saved_bytes == 5 * slab.x.nbytes
    slab.reset()
    assert not slab.x.any() and not slab.y.any()


def test_the_path_copies_are_in_the_estimate():
    assert path_copies(VOLUME_RULES["tv"]) == path_copies(VOLUME_RULES["l1"]) == 4
    fixed = streamed_memory_bytes((64, 64), 5)
    auto = streamed_memory_bytes((64, 64), 5, path_copies=4)
    assert auto["path_copies"] == 4 * fixed["iterates"] // 3
    assert auto["total"] == fixed["total"] + auto["path_copies"] + auto["path_sensor_images"]
    assert auto["path_sensor_images"] == int(7.5 * 4 * 64 * 64)
    seed = streamed_memory_bytes((2048, 2048), 128, path_copies=4)
    assert seed["path_copies"] == 4 * 128 * 2048 * 2048 * 4 and seed["total"] < 25e9

"""The generic path of the automatic weight, Wiener and 3D FISTA against the NumPy path.

Under ``array-api-strict`` and PyTorch's CPU backend (standing in for a GPU): the
automatic weight's held-out path and final solve (:func:`recon.auto.weight.admm_auto`
on :class:`recon.solvers.xp_admm.XpAdmmPlan`, and in 3D on
:class:`recon.volume.xp_admm3d.XpVolumeAdmmPlan`), Wiener
(:func:`recon.solvers.xp_wiener.wiener_xp`) and 3D FISTA
(:func:`recon.volume.xp_fista3d.fista3d_xp`) match the NumPy path to float32 rounding
(the tolerance of tests/recon/test_backends.py), and make the same choices. Each test
also fails if the generic path silently fell back to NumPy: the NumPy kernels are
made to raise during the device solve, or the device arrays' type is asserted.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

import recon
from recon.auto import ChannelProblem, solve_channel
from recon.errors import ReconInputError
from recon.options import ReconOptions
from recon.planar import scaled_problem
from recon.solvers import wiener
from recon.solvers.device import device_solvers, fft_pair_seconds_on
from recon.solvers.xp_admm import XpAdmmPlan
from recon.volume import fista3d
from recon.volume.xp_admm3d import XpVolumeAdmmPlan

from .test_backends import SOLVER_TOL, _backend, _problem_2d, _problem_3d, host, on
from .test_device import _pair, _stand_in, _volume

NAMES = ["array-api-strict", "torch-cpu"]
# the modules (their packages export functions of the same names)
admm_mod = importlib.import_module("recon.solvers.admm")
wiener_mod = importlib.import_module("recon.solvers.wiener")
fista3d_mod = importlib.import_module("recon.volume.fista")
admm3d_mod = importlib.import_module("recon.volume.admm")
weight_mod = importlib.import_module("recon.auto.weight")


def _forbid(monkeypatch, module, name: str):
    """Make a NumPy-path function raise: a silent fallback to it fails the test."""
    def refuse(*args, **kwargs):
        raise AssertionError(f"{module.__name__}.{name} ran: the NumPy path, not the device")

    monkeypatch.setattr(module, name, refuse)


def _scene():
    """A lensless pair whose held-out path takes several stages at 150 iterations."""
    psf, raw = _pair()
    psf = psf - 4.0
    op, b = scaled_problem(psf, raw - 4.0)
    return op, b, raw - 4.0, float(np.abs(raw - 4.0).max())


def _spy_on_device_runs(monkeypatch, backend):
    """Record the measurement type of every generic ADMM run of the path."""
    seen = []
    real = XpAdmmPlan.run

    def run(self, b, state, **kwargs):
        seen.append((type(b), type(state.x)))
        return real(self, b, state, **kwargs)

    monkeypatch.setattr(XpAdmmPlan, "run", run)
    return seen


def _both_paths(monkeypatch, name: str, method: str):
    """``solve_channel`` with an automatic TV weight on the host and on the device
    (the NumPy ADMM loop forbidden there); the device's ADMM runs recorded."""
    backend = _backend(name)
    op, b, raw, scale = _scene()
    problem = ChannelProblem(op, b, raw, scale)
    options = ReconOptions.from_defaults(method=method, iterations=150, tv="auto", l1=0.0)
    ref = solve_channel(problem, options)
    seen = _spy_on_device_runs(monkeypatch, backend)
    _forbid(monkeypatch, admm_mod, "NumbaKernels2D")  # the NumPy path's ADMM kernels
    got = solve_channel(problem, options, solvers=device_solvers(backend), backend=backend)
    return backend, seen, ref, got


@pytest.mark.parametrize("name", NAMES)
def test_the_automatic_weight_path_runs_on_the_device_and_chooses_as_numpy(monkeypatch, name):
    backend, seen, (ref, ref_rec), (got, rec) = _both_paths(monkeypatch, name, "auto")
    path, ref_path = rec["weight"]["path"], ref_rec["weight"]["path"]
    assert len(ref_path) >= 4  # a real path: several warm-started solves
    assert seen and all(not issubclass(t, np.ndarray) for pair in seen for t in pair)
    assert len(seen) >= len(path) + 1  # every stage and the final solve's windows
    assert rec["method"]["method"] == ref_rec["method"]["method"] == "admm"
    assert rec["tv"] == ref_rec["tv"]  # the same chosen weight
    assert [p["weight"] for p in path] == [p["weight"] for p in ref_path]
    assert [p["holdout_error"] for p in path] == pytest.approx(
        [p["holdout_error"] for p in ref_path], rel=SOLVER_TOL)
    assert rec["weight"]["kept_final_iteration"] == ref_rec["weight"]["kept_final_iteration"]
    assert rec["iterations_used"] == ref_rec["iterations_used"]
    assert isinstance(got.x, np.ndarray) and got.params["device"] == backend.label
    assert np.abs(got.x - ref.x).max() <= SOLVER_TOL * np.abs(ref.x).max()


@pytest.mark.parametrize("name", NAMES)
def test_an_automatic_weight_for_fista_is_chosen_on_the_device(monkeypatch, name):
    backend, seen, (ref, ref_rec), (got, rec) = _both_paths(monkeypatch, name, "fista")
    assert seen  # the path ran on the device
    assert rec["weight"]["chosen_by"] == "ADMM path, used by fista"
    assert rec["tv"] == ref_rec["tv"]
    assert got.params["device"] == backend.label
    assert np.abs(got.x - ref.x).max() <= SOLVER_TOL * np.abs(ref.x).max()


def test_reconstruct_with_automatic_choices_on_a_device_equals_the_cpu(monkeypatch):
    psf, raw = _pair()
    ref = recon.reconstruct(psf, raw, iterations=150)  # method and tv "auto"
    standin = _stand_in(monkeypatch, "torch-cpu")
    _forbid(monkeypatch, admm_mod, "NumbaKernels2D")
    got = recon.reconstruct(psf, raw, iterations=150, device="cuda")
    assert got.info.device == standin.label
    assert got.results[0].params["device"] == standin.label
    assert got.info.method == ref.info.method == "admm"
    assert got.info.tv == ref.info.tv
    assert "chosen_by" not in got.info.auto[0]["weight"]  # the path's own solve
    assert np.abs(got.image - ref.image).max() <= SOLVER_TOL * np.abs(ref.image).max()


def test_the_automatic_path_is_refused_when_it_does_not_fit(monkeypatch):
    psf, raw = _pair()
    _stand_in(monkeypatch, "array-api-strict", free=1000)
    with pytest.raises(ReconInputError, match=r"automatic 2D ADMM at 48 x 64 needs 0.00 GiB "
                                              r"on cpu \(array-api-strict\), 0.00 GiB are free"):
        recon.reconstruct(psf, raw, iterations=20, device="cuda")


def test_a_time_budget_on_a_device_is_counted_in_that_devices_fft_floor(monkeypatch):
    psf, raw = _pair()
    standin = _stand_in(monkeypatch, "torch-cpu")
    asked = []

    def floor(backend, shape, repeats=None):
        asked.append(backend)
        return 1e-3  # 20 ms afford 3 iterations: Wiener

    monkeypatch.setattr(recon.planar, "fft_pair_seconds_on", floor)
    got = recon.reconstruct(psf, raw, seconds=0.02, device="cuda")
    assert asked == [standin]
    assert got.info.method == "wiener" and "of 1.00 ms" in got.info.method_reason
    assert fft_pair_seconds_on(standin, (32, 48), repeats=2) > 0  # the real measurement


@pytest.mark.parametrize("name", NAMES)
def test_wiener_on_the_device_equals_the_numpy_path(monkeypatch, name):
    backend = _backend(name)
    op, b = _problem_2d()
    ref = wiener(op, b)
    given = wiener(op, b, regularization=1e-2)
    _forbid(monkeypatch, wiener_mod, "rfftn")  # the NumPy path's FFT
    got = wiener(op, on(backend, b))
    assert not isinstance(got.x, np.ndarray)
    assert got.params["regularization"] == ref.params["regularization"]  # same estimate
    assert np.abs(host(got.x) - ref.x).max() <= SOLVER_TOL * np.abs(ref.x).max()
    assert got.final_objective == pytest.approx(ref.final_objective, rel=SOLVER_TOL)
    off = wiener(op, on(backend, b), regularization=1e-2)
    assert np.abs(host(off.x) - given.x).max() <= SOLVER_TOL * np.abs(given.x).max()
    # a wrong lambda is caught by the tolerance
    assert np.abs(host(off.x) - ref.x).max() > 10 * SOLVER_TOL * np.abs(ref.x).max()


def test_reconstruct_wiener_on_a_device_equals_the_cpu(monkeypatch):
    psf, raw = _pair()
    ref = recon.reconstruct(psf, raw, "wiener")
    standin = _stand_in(monkeypatch, "array-api-strict")
    _forbid(monkeypatch, wiener_mod, "rfftn")
    got = recon.reconstruct(psf, raw, "wiener", device="cuda")
    assert got.results[0].params["device"] == standin.label
    assert np.abs(got.image - ref.image).max() <= SOLVER_TOL * np.abs(ref.image).max()


FISTA3D = {"tv": {"tv": 1e-3}, "tv-l1": {"tv": 1e-3, "l1": 1e-3}, "l1": {"tv": 0.0, "l1": 1e-3},
           "signed": {"tv": 1e-3, "nonneg": False}}


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("case", sorted(FISTA3D))
def test_fista3d_on_the_device_matches_the_numpy_path(monkeypatch, name, case):
    backend = _backend(name)
    op, b = _problem_3d()
    ref = fista3d(op, b, iterations=40, **FISTA3D[case])
    _forbid(monkeypatch, fista3d_mod._kernels3d, "proximal_step_3d")
    res = fista3d(op, on(backend, b), iterations=40, **FISTA3D[case])
    assert not isinstance(res.x, np.ndarray)
    x = host(res.x)
    assert x.shape == ref.x.shape
    assert np.abs(x - ref.x).max() <= SOLVER_TOL * np.abs(ref.x).max()
    assert res.final_objective == pytest.approx(ref.final_objective, rel=SOLVER_TOL)
    assert res.history.objective == pytest.approx(ref.history.objective, rel=SOLVER_TOL)
    assert res.history.extra["restarts"] == ref.history.extra["restarts"]
    assert res.params["lipschitz"] == pytest.approx(ref.params["lipschitz"], rel=1e-5)


def test_fista3d_with_a_wrong_weight_is_caught_by_the_tolerance():
    backend = _backend("array-api-strict")
    op, b = _problem_3d()
    ref = fista3d(op, b, iterations=40, tv=1e-3)
    off = host(fista3d(op, on(backend, b), iterations=40, tv=1.3e-3).x)
    assert np.abs(off - ref.x).max() > 10 * SOLVER_TOL * np.abs(ref.x).max()


def test_reconstruct_a_stack_with_fista_on_a_device_equals_the_cpu(monkeypatch):
    stack, depths, raw = _volume()
    ref = recon.reconstruct(recon.PsfStack(stack, depths), raw, "fista", iterations=20,
                            tv=1e-3)
    standin = _stand_in(monkeypatch, "torch-cpu")
    _forbid(monkeypatch, fista3d_mod._kernels3d, "proximal_step_3d")
    got = recon.reconstruct(recon.PsfStack(stack, depths), raw, "fista", iterations=20,
                            tv=1e-3, device="cuda")
    assert got.info.device == standin.label and got.info.method == "fista"
    assert np.abs(got.volume - ref.volume).max() <= SOLVER_TOL * np.abs(ref.volume).max()


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("method", ["admm", "fista"])
def test_the_automatic_3d_weight_runs_on_the_device_and_chooses_as_numpy(monkeypatch, name,
                                                                        method):
    stack, depths, raw = _volume()
    ref = recon.reconstruct(recon.PsfStack(stack, depths), raw, method, iterations=150)
    standin = _stand_in(monkeypatch, name)
    seen = []
    real = XpVolumeAdmmPlan.run

    def run(self, b, state, **kwargs):
        seen.append((type(b), type(state.x)))
        return real(self, b, state, **kwargs)

    monkeypatch.setattr(XpVolumeAdmmPlan, "run", run)
    _forbid(monkeypatch, admm3d_mod, "NumbaKernels3D")  # the NumPy path's 3D ADMM kernels
    _forbid(monkeypatch, fista3d_mod._kernels3d, "proximal_step_3d")
    got = recon.reconstruct(recon.PsfStack(stack, depths), raw, method, iterations=150,
                            device="cuda")
    a, g = ref.info.auto[0], got.info.auto[0]
    path, ref_path = g["weight_choice"]["path"], a["weight_choice"]["path"]
    assert len(ref_path) >= 3  # warm-started solves, a rise, the choice
    assert seen and all(not issubclass(t, np.ndarray) for pair in seen for t in pair)
    assert got.info.device == standin.label and got.results[0].params["device"] == standin.label
    assert g["weight"] == a["weight"] and got.info.tv == ref.info.tv
    assert [p["holdout_error"] for p in path] == pytest.approx(
        [p["holdout_error"] for p in ref_path], rel=SOLVER_TOL)
    assert g["weight_choice"]["kept_final_iteration"] == a["weight_choice"]["kept_final_iteration"]
    assert g["planes_kept"] == a["planes_kept"]  # the plane tests (on the host) agree
    assert np.abs(got.volume - ref.volume).max() <= SOLVER_TOL * np.abs(ref.volume).max()


def test_the_automatic_3d_path_is_refused_when_it_does_not_fit(monkeypatch):
    stack, depths, raw = _volume()
    _stand_in(monkeypatch, "array-api-strict", free=1000)
    with pytest.raises(ReconInputError, match=r"automatic 3D ADMM on 3 planes of 24 x 32 needs "
                                              r"0.00 GiB on cpu \(array-api-strict\)"):
        recon.reconstruct(recon.PsfStack(stack, depths), raw, iterations=5, device="cuda")


def test_the_numpy_path_of_the_weight_path_is_untouched(monkeypatch):
    """On the host the path keeps the NumPy plans (no generic plan is made)."""
    op, b, raw, scale = _scene()

    def refuse(*args, **kwargs):
        raise AssertionError("a generic plan on the NumPy path")

    monkeypatch.setattr(weight_mod, "device_plan_of", refuse)
    res, rec = solve_channel(ChannelProblem(op, b, raw, scale),
                             ReconOptions.from_defaults(iterations=60, tv="auto", l1=0.0))
    assert isinstance(res.x, np.ndarray) and "device" not in res.params


def test_the_metrics_of_a_device_solve_use_that_devices_fft_floor(monkeypatch):
    """The ratio to the FFT floor of ``--metrics-json`` is the device's: the floor is
    measured on the device the solve ran on (2D pair; 3D ``n_z + 1`` pairs)."""
    device_mod = importlib.import_module("recon.solvers.device")
    psf, raw = _pair()
    stack, depths, vraw = _volume()
    standin = _stand_in(monkeypatch, "torch-cpu")
    floors = []
    real = device_mod.fft_pair_seconds_on

    def floor(backend, shape, repeats=None, n_z=0):
        floors.append((backend, tuple(shape), n_z))
        return real(backend, shape, repeats=2, n_z=n_z)

    monkeypatch.setattr(device_mod, "fft_pair_seconds_on", floor)
    rec = recon.reconstruct(psf, raw, "fista", iterations=5, tv=1e-3, device="cuda")
    m = rec.metrics()
    assert floors == [(standin, rec.operator.padded_shape, 0)]
    assert m["ratio_to_fft_floor"] == pytest.approx(m["seconds_per_iteration"]
                                                    / m["fft_pair_seconds"])
    vol = recon.reconstruct(recon.PsfStack(stack, depths), vraw, "admm", iterations=5, tv=1e-3,
                            device="cuda")
    vm = vol.metrics()
    assert floors[-1] == (standin, vol.operator.padded_shape, 3)
    assert vm["fft_floor_seconds"] > 0
    assert rec.metrics(0.5)["fft_pair_seconds"] == 0.5 and len(floors) == 2  # given: kept

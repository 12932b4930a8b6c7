"""``device=`` / ``--device``: resolution, the messages of an unusable request, the memory
check, and the plumbing from :func:`recon.reconstruct` and
:func:`recon.reconstruct_volume` to the generic solvers (exercised on the CPU by
standing PyTorch's CPU backend, or array-api-strict, in for the GPU)."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

import recon.backend as backend_mod
import recon.planar
import recon.spatial.api
import recon.volume.api
from recon import reconstruct, reconstruct_volume
from recon.backend import Backend, check_memory, resolve_device
from recon.errors import ReconInputError

xs = pytest.importorskip("array_api_strict")


def _gpu_usable() -> bool:
    try:
        return not resolve_device("auto").is_numpy
    except ReconInputError:
        return False


no_gpu = pytest.mark.skipif(_gpu_usable(), reason="a CUDA device is usable here")


def test_cpu_is_the_numpy_path_and_names_are_checked():
    assert resolve_device("cpu").is_numpy
    assert resolve_device(" CPU ").is_numpy
    with pytest.raises(ReconInputError, match="device 'tpu' is not one of cpu, cuda, auto"):
        resolve_device("tpu")


@no_gpu
def test_cuda_without_a_gpu_is_a_clear_input_error():
    with pytest.raises(ReconInputError, match="cuda requested but") as info:
        resolve_device("cuda")
    msg = str(info.value)
    assert ("not installed: pip install 'diffuserlab[gpu]'" in msg
            or "no CUDA device visible" in msg)


@no_gpu
def test_auto_falls_back_to_the_cpu():
    assert resolve_device("auto").is_numpy


def test_cuda_without_cupy_or_torch_names_the_install(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(backend_mod.importlib.util, "find_spec",
                        lambda name, *a: None if name in ("cupy", "torch") else real(name, *a))
    with pytest.raises(ReconInputError) as info:
        resolve_device("cuda")
    assert str(info.value) == ("cuda requested but CuPy/PyTorch with CUDA is not installed: "
                               "pip install 'diffuserlab[gpu]'")
    assert resolve_device("auto").is_numpy


def test_cuda_torch_without_a_device_says_none_is_visible(monkeypatch):
    torch = pytest.importorskip("torch")
    real = importlib.util.find_spec
    monkeypatch.setattr(backend_mod.importlib.util, "find_spec",
                        lambda name, *a: None if name == "cupy" else real(name, *a))
    monkeypatch.setattr(torch.version, "cuda", "12.4")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ReconInputError, match="no CUDA device visible .*nvidia-smi"):
        resolve_device("cuda")
    assert resolve_device("auto").is_numpy


def test_the_memory_check_says_what_is_needed_and_free():
    check_memory(2**30, None, what="x")  # unknown free memory: not checked
    check_memory(2**30, 2**31, what="x")
    with pytest.raises(ReconInputError, match=r"3D ADMM needs 2.00 GiB on cuda:0 \(torch\), "
                                              r"1.00 GiB are free; bin the data"):
        check_memory(2 * 2**30, 2**30, what="3D ADMM", where="cuda:0 (torch)")


def _stand_in(monkeypatch, name: str, free: int | None = None) -> Backend:
    """Make ``device="cuda"`` resolve to a CPU array-API backend (the GPU's stand-in)."""
    if name == "torch-cpu":
        standin = backend_mod.torch_cpu()
        if standin is None:
            pytest.skip("PyTorch is not installed")
    else:
        standin = Backend("array-api-strict", xs, None, "cpu (array-api-strict)")
    for mod in (recon.planar, recon.spatial.api, recon.volume.api):
        monkeypatch.setattr(mod, "resolve_device", lambda d: standin)
    monkeypatch.setattr(backend_mod, "free_device_bytes", lambda b: free)
    import recon.solvers.device as device_mod

    monkeypatch.setattr(device_mod, "free_device_bytes", lambda b: free)
    return standin


def _pair():
    rng = np.random.default_rng(0)
    psf = np.full((48, 64), 4.0)
    psf[rng.integers(0, 48, 40), rng.integers(0, 64, 40)] += 900.0
    raw = rng.poisson(200 + 100 * rng.random((48, 64))).astype(np.float64) + 4.0
    return psf, raw


@pytest.mark.parametrize("name", ["array-api-strict", "torch-cpu"])
@pytest.mark.parametrize("method", ["admm", "fista"])
def test_reconstruct_on_a_device_equals_the_cpu(monkeypatch, name, method):
    psf, raw = _pair()
    ref = reconstruct(psf, raw, method, iterations=30, tv=1e-3, auto_stop=False)
    standin = _stand_in(monkeypatch, name)
    got = reconstruct(psf, raw, method, iterations=30, tv=1e-3, auto_stop=False,
                      device="cuda")
    assert isinstance(got.image, np.ndarray) and isinstance(got.results[0].x, np.ndarray)
    assert got.info["device"] == standin.label
    assert ref.info["device"] == "cpu (numpy)"
    assert np.abs(got.image - ref.image).max() <= 1e-4 * np.abs(ref.image).max()


def test_reconstruct_on_a_device_with_automatic_choices(monkeypatch):
    psf, raw = _pair()
    _stand_in(monkeypatch, "array-api-strict")
    got = reconstruct(psf, raw, iterations=60, device="cuda")  # method and tv "auto"
    record = got.info["auto"][0]
    assert got.info["method"] == "admm"
    assert "chosen_by" not in record["weight"]  # the weight path's own solve, on the device
    assert got.results[0].params["device"] == "cpu (array-api-strict)"
    assert got.results[0].params["backend"] == "array_api_strict"


def test_a_problem_too_large_for_the_device_is_refused_before_the_solve(monkeypatch):
    psf, raw = _pair()
    _stand_in(monkeypatch, "array-api-strict", free=1000)
    with pytest.raises(ReconInputError, match=r"2D admm at 48 x 64 needs 0.00 GiB .* "
                                              r"0.00 GiB are free"):
        reconstruct(psf, raw, "admm", iterations=5, tv=1e-3, device="cuda")


def _volume():
    rng = np.random.default_rng(1)
    stack = np.full((3, 24, 32), 4.0)
    for k in range(3):
        stack[k, rng.integers(0, 24, 20), rng.integers(0, 32, 20)] += 800.0
    raw = rng.poisson(300 + 100 * rng.random((24, 32))).astype(np.float64) + 4.0
    return stack, [10.0, 20.0, 30.0], raw


def test_reconstruct_volume_on_a_device_equals_the_cpu(monkeypatch):
    stack, depths, raw = _volume()
    ref = reconstruct_volume(stack, depths, raw, iterations=20, tv=1e-3)
    standin = _stand_in(monkeypatch, "array-api-strict")
    got = reconstruct_volume(stack, depths, raw, iterations=20, tv=1e-3, device="cuda")
    assert got.info["device"] == standin.label
    assert np.abs(got.volume - ref.volume).max() <= 1e-4 * np.abs(ref.volume).max()


def test_reconstruct_volume_with_fista_or_an_automatic_weight_runs_on_the_device(monkeypatch):
    stack, depths, raw = _volume()
    standin = _stand_in(monkeypatch, "array-api-strict")
    for kw in ({}, {"tv": 1e-3, "method": "fista"}):  # tv auto (3D ADMM path), FISTA
        got = reconstruct_volume(stack, depths, raw, iterations=5, device="cuda", **kw)
        assert got.info["device"] == standin.label
        assert got.results[0].params["device"] == standin.label


def test_the_device_is_a_field_of_the_record_and_a_key_of_the_metrics(monkeypatch):
    psf, raw = _pair()
    ref = reconstruct(psf, raw, "fista", iterations=5, tv=1e-3)
    assert ref.info.device == "cpu (numpy)" and ref.metrics(1.0)["device"] == "cpu (numpy)"
    stack, depths, vraw = _volume()
    standin = _stand_in(monkeypatch, "array-api-strict")
    got = reconstruct(psf, raw, "fista", iterations=5, tv=1e-3, device="cuda")
    assert got.info.device == standin.label and got.metrics(1.0)["device"] == standin.label
    vol = reconstruct(recon.PsfStack(stack, depths), vraw, "admm", iterations=5, tv=1e-3,
                      device="cuda")
    assert vol.info.device == standin.label and vol.metrics(1.0)["device"] == standin.label


def test_a_psf_grid_runs_on_the_cpu_and_on_a_device(monkeypatch):
    from recon.spatial import PsfGrid

    psf, raw = _pair()
    grid = PsfGrid(psf[None], np.zeros((1, 2)), (1, 1))
    ok = reconstruct(grid, raw, iterations=3)  # device="cpu"
    assert ok.info.device == "cpu (numpy)" and ok.metrics(1.0)["device"] == "cpu (numpy)"
    standin = _stand_in(monkeypatch, "array-api-strict")
    for device in ("cuda", "auto"):  # auto resolves to the (stand-in) GPU here
        got = reconstruct(grid, raw, iterations=3, device=device)
        assert got.info.device == standin.label
        assert np.abs(got.image - ok.image).max() <= 1e-4 * np.abs(ok.image).max()

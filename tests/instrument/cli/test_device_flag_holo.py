"""``--device cpu|cuda|auto`` on ``holo evaluate`` and ``holo benchmark``: an unusable device
or a hologram too large for the GPU exits 2 with the message before anything is read or
written; ``auto`` without a GPU runs the NumPy path, a generic backend runs the optimiser
there and the report says where."""

from __future__ import annotations

import json

import pytest

import recon.backend
import recon.cgh.xp_optimize as xp_optimize
from instrument.cli import main
from recon.backend import torch_cpu
from tests.recon.test_device import no_gpu


@no_gpu
@pytest.mark.parametrize("action", ["evaluate", "benchmark"])
def test_cuda_without_a_gpu_exits_2_before_writing(capsys, tmp_path, action):
    out = tmp_path / "out"
    extra = (["--out", str(out)] if action == "evaluate" else ["--json", str(out)])
    assert main(["holo", action, "--quick", "--device", "cuda", *extra]) == 2
    err = capsys.readouterr().err
    assert "cuda requested but" in err
    assert "pip install 'diffuserlab[gpu]'" in err or "no CUDA device visible" in err
    assert not out.exists()


def test_an_unknown_device_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        main(["holo", "benchmark", "--quick", "--device", "tpu"])
    assert info.value.code == 2
    assert "--device: invalid choice: 'tpu'" in capsys.readouterr().err


@no_gpu
def test_auto_without_a_gpu_runs_the_numpy_path(capsys, tmp_path):
    report = tmp_path / "bench.json"
    assert main(["holo", "benchmark", "--quick", "--device", "auto", "--json",
                 str(report)]) == 0
    assert "on cpu (numpy)" in capsys.readouterr().out
    assert json.loads(report.read_text())["device"] == "cpu (numpy)"


def _as_gpu(monkeypatch, free_bytes):
    """``--device cuda`` answered by PyTorch's CPU backend with ``free_bytes`` free: the
    generic path through the command, as on a GPU."""
    backend = torch_cpu()
    if backend is None:
        pytest.skip("PyTorch is not installed")
    monkeypatch.setattr(recon.backend, "resolve_device",
                        lambda device="cpu": recon.backend.NUMPY if device == "cpu" else backend)
    monkeypatch.setattr(xp_optimize, "free_device_bytes", lambda b: free_bytes)
    return backend


@pytest.mark.parametrize("action", ["evaluate", "benchmark"])
def test_a_hologram_too_large_for_the_gpu_exits_2_saying_how_much(monkeypatch, capsys,
                                                                  tmp_path, action):
    _as_gpu(monkeypatch, 1000)
    out = tmp_path / "out"
    extra = (["--out", str(out)] if action == "evaluate" else ["--json", str(out)])
    assert main(["holo", action, "--quick", "--device", "cuda", *extra]) == 2
    err = capsys.readouterr().err
    # quick runs: benchmark 64 x 36 at 16x; evaluate N = 48 at 16x (SLM 12 x 12)
    what = "64 x 36 SLM at 16x" if action == "benchmark" else "12 x 12 SLM at 16x"
    assert f"the hologram of a {what} with 1 plane(s) needs" in err
    assert "0.00 GiB are free" in err and "use the CPU (device cpu)" in err
    assert not out.exists()


def test_the_benchmark_runs_the_generic_path_on_the_device_asked(monkeypatch, capsys, tmp_path):
    _as_gpu(monkeypatch, None)
    report = tmp_path / "bench.json"
    assert main(["holo", "benchmark", "--quick", "--device", "cuda", "--json",
                 str(report)]) == 0
    out = capsys.readouterr().out
    assert "on cpu (torch)" in out and "FFT share not timed (generic path)" in out
    rep = json.loads(report.read_text())
    assert rep["device"] == "cpu (torch)" and rep["iterations"] >= 1 and rep["fft_seconds"] > 0


def test_a_cpu_hologram_loads_no_gpu_library():
    """``holo benchmark`` on the CPU (the default device) runs the NumPy path and never
    imports CuPy, PyTorch or the array-API layers."""
    from .test_lazy_imports import GPU, _run

    code = f"""
import sys
from instrument.cli import main
assert main(["holo", "benchmark", "--quick"]) == 0
print(sorted({{m.split(".")[0] for m in sys.modules}} & set({GPU!r})))
"""
    assert _run(code).strip().splitlines()[-1] == "[]"

"""``--device cpu|cuda|auto`` on ``recon`` and ``recon3d``: an unusable device exits 2 with
the message before any file is read; ``cpu`` and ``auto`` (no GPU) run the NumPy path and
say so in the metrics."""

from __future__ import annotations

import json

import numpy as np
import pytest

from instrument.cli import main
from recon.backend import resolve_device
from recon.errors import ReconInputError


def _gpu_usable() -> bool:
    try:
        return not resolve_device("auto").is_numpy
    except ReconInputError:
        return False


@pytest.mark.skipif(_gpu_usable(), reason="a CUDA device is usable here")
@pytest.mark.parametrize("argv", [["recon", "--psf", "missing.npy", "--raw", "missing.npy"],
                                  ["recon3d", "--psf-stack", "missing.tif", "--raw",
                                   "missing.npy"]])
def test_cuda_without_a_gpu_exits_2_naming_what_is_missing(capsys, argv):
    assert main([*argv, "--device", "cuda"]) == 2
    err = capsys.readouterr().err
    assert "cuda requested but" in err
    assert "pip install 'diffuserlab[gpu]'" in err or "no CUDA device visible" in err
    assert "missing" not in err  # refused before any file is read


def test_an_unknown_device_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        main(["recon", "--psf", "p.npy", "--raw", "r.npy", "--device", "tpu"])
    assert info.value.code == 2
    assert "--device: invalid choice: 'tpu'" in capsys.readouterr().err


@pytest.mark.skipif(_gpu_usable(), reason="a CUDA device is usable here")
def test_auto_without_a_gpu_reconstructs_on_the_cpu(tmp_path):
    rng = np.random.default_rng(0)
    psf = np.full((32, 40), 4.0)
    psf[rng.integers(0, 32, 30), rng.integers(0, 40, 30)] += 900.0
    raw = rng.poisson(200 + 100 * rng.random((32, 40))).astype(np.float32) + 4
    np.save(tmp_path / "psf.npy", psf.astype(np.float32))
    np.save(tmp_path / "raw.npy", raw)
    out = tmp_path / "r"
    assert main(["recon", "--psf", str(tmp_path / "psf.npy"), "--raw", str(tmp_path / "raw.npy"),
                 "--method", "admm", "--tv", "1e-3", "--iterations", "10", "--device", "auto",
                 "--out", str(out), "--metrics-json", f"{out}.json"]) == 0
    metrics = json.loads(out.with_suffix(".json").read_text())
    assert metrics["device"] == "cpu (numpy)"


@pytest.fixture
def broken_cupy(tmp_path, monkeypatch):
    """A CuPy that is installed but fails to import (built for another CUDA)."""
    import sys

    pkg = tmp_path / "fake_site" / "cupy"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(
        "raise ImportError('libcudart.so.11.0: cannot open shared object file')\n")
    monkeypatch.delitem(sys.modules, "cupy", raising=False)
    monkeypatch.syspath_prepend(str(tmp_path / "fake_site"))


@pytest.mark.skipif(_gpu_usable(), reason="a CUDA device is usable here")
def test_a_cupy_that_fails_to_import(broken_cupy, tmp_path, capsys):
    """Before: ``--device auto`` and ``cuda`` ended in 'internal error (a bug)', exit 1."""
    with pytest.raises(ReconInputError, match="cupy is installed and cannot be imported "
                       r"\(libcudart.so.11.0"):
        resolve_device("cuda")
    auto = resolve_device("auto")
    assert auto.is_numpy and "cupy is installed and cannot be imported" in auto.note
    assert main(["recon", "--psf", "missing.npy", "--raw", "missing.npy", "--device",
                 "cuda"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cupy is installed and cannot be imported" in err
    assert "missing" not in err and "Traceback" not in err
    rng = np.random.default_rng(0)
    psf = np.full((32, 40), 4.0)
    psf[rng.integers(0, 32, 30), rng.integers(0, 40, 30)] += 900.0
    np.save(tmp_path / "psf.npy", psf.astype(np.float32))
    np.save(tmp_path / "raw.npy", rng.poisson(300, (32, 40)).astype(np.float32))
    assert main(["recon", "--psf", str(tmp_path / "psf.npy"), "--raw",
                 str(tmp_path / "raw.npy"), "--method", "wiener", "--device", "auto",
                 "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert "diffuserlab: note: --device auto: no usable GPU, running on the CPU: cupy is " \
        "installed and cannot be imported (libcudart.so.11.0" in err, err

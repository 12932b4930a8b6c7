"""The runnable examples in examples/ run as a user runs them (a subprocess from the
repository root) on small inputs, and write what they say they write."""

import os
import subprocess
import sys
from pathlib import Path

from recon.sample import data_dir
from recon.volume.sample import volume_data_dir

ROOT = Path(__file__).resolve().parents[2]


def _run(script: str, *args: str) -> str:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, f"examples/{script}", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout


def test_2d_tutorial_example(tmp_path):
    out = _run("reconstruct_2d_tutorial.py", str(data_dir()), "--bin", "8",
               "--iterations", "150", "--out", str(tmp_path))
    assert "admm, TV weight" in out and "weight: hold-out cross-validation" in out
    assert (tmp_path / "reconstruction.png").stat().st_size > 1000


def test_2d_example_names_missing_data(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "examples/reconstruct_2d_tutorial.py",
                           str(tmp_path)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2 and "no DiffuserCam tutorial sample" in proc.stderr


def test_3d_stack_example(tmp_path):
    out = _run("reconstruct_3d_stack.py", str(volume_data_dir()), "--bin", "4", "--planes", "4",
               "--iterations", "20", "--out", str(tmp_path))
    shares = [float(line.split(":")[1].split("%")[0]) for line in out.splitlines()
              if "% of the energy" in line]
    assert len(shares) >= 4 and abs(sum(shares) - 100.0) < 1.0
    assert (tmp_path / "max_projection.png").stat().st_size > 500


def test_scripted_bench_example(tmp_path):
    out_dir = tmp_path / "bench"
    out = _run("calibrate_and_capture_simulated.py", "--out", str(out_dir), "--depths", "3",
               "--iterations", "100")
    assert "PSF sweep: complete, 3 of 3 depths" in out
    psnr_db = float(out.split("PSNR against the known scene")[1].split("dB")[0])
    assert psnr_db > 12.0  # measured 16.7 dB at 200 iterations (on-axis PSF only)
    assert (out_dir / "psf_sweep.zarr").is_dir()
    again = subprocess.run([sys.executable, "examples/calibrate_and_capture_simulated.py",
                            "--out", str(out_dir)], cwd=ROOT, capture_output=True, text=True,
                           env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    assert again.returncode == 2 and "never overwritten" in again.stderr

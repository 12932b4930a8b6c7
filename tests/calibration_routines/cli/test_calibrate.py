"""`diffuserlab calibrate`, `runs` and `recon --psf RUN --depth` end to end on the
simulated bench, including Ctrl-C and resume."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from instrument.cli import main
from instrument.devices.virtual_bench import PlanarScene, VirtualBench
from instrument.runs.runstore import RunStore
from instrument.runs.stacks import load_psf_stack

ROOT = Path(__file__).resolve().parents[3]
BENCH = str(ROOT / "examples" / "bench-simulated.toml")


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "sweep.zarr"
    status = main(["calibrate", "psf-sweep", BENCH, "--simulate", "--z-min", "30",
                   "--z-max", "60", "--n-depths", "3", "--frames", "2", "--out", str(path),
                   "--note", "cli test"])
    assert status == 0
    return path


def test_calibrate_writes_a_complete_run_and_runs_show_reports_it(sweep, capsys):
    store = RunStore.open(sweep)
    assert store.status == "complete" and store.attrs["note"] == "cli test"
    assert main(["runs", "show", str(sweep)]) == 0
    out = capsys.readouterr().out
    assert "psf-sweep  (complete)" in out and "psf_stack: 3x256x320 float32" in out
    assert main(["runs", "show", str(sweep), "--json"]) == 0
    assert '"frames_done": 12' in capsys.readouterr().out


def test_export_import_roundtrip(sweep, tmp_path, capsys):
    tif = tmp_path / "stack.tif"
    assert main(["runs", "export", str(sweep), "--out", str(tif)]) == 0
    stack, depths, attrs = load_psf_stack(tif)
    ref, ref_depths, _ = load_psf_stack(sweep)
    np.testing.assert_array_equal(stack, ref)
    assert depths == ref_depths and attrs["units"] == "DN/s"
    frames_tif = tmp_path / "frames.tif"
    assert main(["runs", "export", str(sweep), "--frames", "--out", str(frames_tif)]) == 0
    np.save(tmp_path / "stack.npy", ref[::-1])
    imported = tmp_path / "imported.zarr"
    assert main(["runs", "import-psf", str(tmp_path / "stack.npy"), "--depths",
                 ",".join(str(z) for z in ref_depths[::-1]), "--out", str(imported)]) == 0
    stack2, depths2, _ = load_psf_stack(imported)
    np.testing.assert_array_equal(stack2, ref)  # sorted back to ascending depth
    assert depths2 == ref_depths
    capsys.readouterr()
    assert main(["runs", "import-psf", str(tmp_path / "stack.npy"), "--out",
                 str(tmp_path / "x.zarr")]) == 2
    assert "depths" in capsys.readouterr().err
    assert main(["runs", "show", str(tmp_path / "nothing.zarr")]) == 2


def test_recon_takes_one_depth_of_a_run(sweep, tmp_path, capsys):
    import tifffile

    with VirtualBench(seed=0) as vb:  # a scene at 45 mm, the stack has 30, 40, 60 mm
        vb.set_scene(PlanarScene(np.ones((16, 16)), 40.0, 6.0))
        vb.camera.exposure_s = 0.05
        raw = vb.camera.snap().image
        offset = f"{vb.camera.dark_offset_dn:g}"
    tifffile.imwrite(tmp_path / "raw.tif", raw)
    out = tmp_path / "recon"
    # the run's stack is dark-subtracted and a raw file records no level: --dark auto
    # asks for it (one meaning of auto, docs/cli.md)
    assert main(["recon", "--psf", str(sweep), "--depth", "40", "--raw",
                 str(tmp_path / "raw.tif"), "--iterations", "5", "--out", str(out)]) == 2
    assert "calibrated (dark-subtracted) PSF" in capsys.readouterr().err
    assert main(["recon", "--psf", str(sweep), "--depth", "40", "--raw",
                 str(tmp_path / "raw.tif"), "--iterations", "5", "--out", str(out),
                 "--dark", offset, "--metrics-json", str(tmp_path / "m.json")]) == 0
    assert '"psf_depth_mm": 40.0' in (tmp_path / "m.json").read_text()
    stack_tif = tmp_path / "stack.tif"  # the same from an exported TIFF stack
    assert main(["runs", "export", str(sweep), "--out", str(stack_tif)]) == 0
    assert main(["recon", "--psf", str(stack_tif), "--depth", "41", "--raw",
                 str(tmp_path / "raw.tif"), "--iterations", "5", "--out", str(out),
                 "--overwrite"]) == 0
    assert main(["recon", "--psf", str(sweep), "--psf-product", "psf_stack_raw", "--depth",
                 "40", "--raw", str(tmp_path / "raw.tif"), "--iterations", "5", "--out",
                 str(out), "--overwrite", "--dark", offset]) == 0
    capsys.readouterr()
    assert main(["recon", "--psf", str(sweep), "--raw", str(tmp_path / "raw.tif"),
                 "--out", str(out), "--overwrite"]) == 2
    assert "--depth" in capsys.readouterr().err
    assert main(["recon", "--psf", str(sweep), "--depth", "100", "--raw",
                 str(tmp_path / "raw.tif"), "--out", str(out), "--overwrite"]) == 2
    assert "nearest 60 mm" in capsys.readouterr().err


def test_ctrl_c_aborts_and_prints_how_to_resume(tmp_path):
    path = tmp_path / "long.zarr"
    cmd = [sys.executable, "-m", "instrument.cli", "calibrate", "psf-sweep", BENCH,
           "--simulate", "--z-min", "30", "--z-max", "120", "--n-depths", "12", "--frames",
           "8", "--out", str(path)]
    # SIGINT at its default in the child: a runner started in the background (nohup,
    # "&" without job control) passes SIGINT ignored, and Python then never raises
    # KeyboardInterrupt
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            try:
                if RunStore.open(path).done().sum() >= 20:
                    break
            except Exception:
                pass
            time.sleep(0.05)
        assert proc.poll() is None, "finished before the interrupt"
        os.kill(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err[-2000:]
    assert "aborted" in err and f"diffuserlab calibrate resume {path}" in err
    store = RunStore.open(path)
    assert store.status == "aborted" and 20 <= store.done().sum() < store.n_frames
    assert main(["calibrate", "resume", str(path), BENCH, "--simulate"]) == 0
    assert RunStore.open(path).status == "complete"


def test_bad_input_exits_2(tmp_path, capsys):
    assert main(["calibrate", "psf-sweep", str(tmp_path / "missing.toml"), "--simulate"]) == 2
    assert "cannot read" in capsys.readouterr().err
    assert main(["calibrate", "psf-sweep", BENCH, "--simulate", "--z-min", "50", "--z-max",
                 "20", "--n-depths", "3", "--out", str(tmp_path / "x.zarr")]) == 2
    assert "z_min < z_max" in capsys.readouterr().err


@pytest.mark.parametrize("routine, extra", [
    ("dark", ["--frames", "2"]),
    ("angular-response", ["--frames", "1", "--n-angles", "5"]),
    ("psf-grid", ["--frames", "1", "--n", "2", "--falloff-sigma-deg", "20"]),
])
def test_every_routine_runs_from_the_cli(tmp_path, routine, extra, capsys):
    path = tmp_path / f"{routine}.zarr"
    assert main(["calibrate", routine, BENCH, "--simulate", "--out", str(path), *extra]) == 0
    assert RunStore.open(path).status == "complete"
    assert "(complete)" in capsys.readouterr().out


def test_grid_takes_the_falloff_from_an_angular_run(tmp_path):
    angle = tmp_path / "angle.zarr"
    assert main(["calibrate", "angular-response", BENCH, "--simulate", "--out", str(angle),
                 "--frames", "1", "--n-angles", "7"]) == 0
    grid = tmp_path / "grid.zarr"
    assert main(["calibrate", "psf-grid", BENCH, "--simulate", "--out", str(grid), "--frames",
                 "1", "--n", "2", "--falloff-run", str(angle)]) == 0
    nyquist = RunStore.open(grid).attrs["summary"]["nyquist"]
    assert nyquist["checked"] and nyquist["falloff_sigma_deg"] == pytest.approx(20.0, rel=0.03)


def test_capture_live_from_the_calibrated_sweep(sweep, tmp_path, capsys):
    """The sweep's PSFs are dark-subtracted: capture live adds the frames' dark level
    (the simulated camera's offset) back, so the beads come out, not streaks."""
    from recon.io import load_image

    png = tmp_path / "live.png"
    assert main(["capture", "live", "--simulate", "--psf", str(sweep), "--depth", "30",
                 "--method", "admm:3", "--seconds", "2", "--preview-png", str(png)]) == 0
    assert "errors 0" in capsys.readouterr().out
    energy = np.sort(load_image(png).astype(np.float64).ravel() ** 2)[::-1]
    assert energy[: energy.size // 200].sum() > 0.2 * energy.sum()

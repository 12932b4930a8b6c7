"""A dark frame of another shape than the PSF's frames is bad input in every reconstruction
command with every PSF source (file, run, stack, grid) and every dark form: exit 2 and
one line naming the problem and the fix, never "internal error (a bug)" (issue 64: a
calibration run's PSF had the dark added before the shape check, in
instrument.processing.reconstruct_files.resolve_dark)."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from instrument.cli import main
from instrument.runs.runstore import RunStore

SMALL = (32, 40)  # the dark frame's shape; the simulated camera's frames are 256x320


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A calibration run (psf-sweep), a psf-grid run, a recorded video, the run's PSF as
    a file and as a TIFF and a .npy stack, a raw frame, and a 32x40 dark as an image and a run."""
    d = tmp_path_factory.mktemp("dark_shapes")
    for argv in (["calibrate", "psf-sweep", "--simulate", "--frames", "1", "--n-depths", "2",
                  "--out", str(d / "sweep.zarr")],
                 ["calibrate", "psf-grid", "--simulate", "--frames", "1",
                  "--out", str(d / "grid.zarr")],
                 ["capture", "video", "--simulate", "--frames", "2",
                  "--out", str(d / "video.zarr")]):
        assert main(argv) == 0
    stack, attrs = RunStore.open(d / "sweep.zarr").product("psf_stack")
    np.save(d / "psf.npy", stack[0])
    tifffile.imwrite(d / "stack.tif", stack, metadata={"depths_mm": attrs["depths_mm"]},
                     photometric="minisblack")
    np.save(d / "stack.npy", stack)
    np.save(d / "raw.npy", RunStore.open(d / "video.zarr").frame(0).image)
    np.save(d / "dark.npy", np.full(SMALL, 10.0, np.float32))
    dark = RunStore.create(d / "dark.zarr", plan_name="dark", plan_params={}, points=[{}],
                           frame_tags=[[]], frame_shape=SMALL, frame_dtype=np.uint16,
                           coord_names=["exposure_s"])
    dark.write_product("dark_mean", np.full(SMALL, 10.0, np.float32))
    dark.update_attrs(status="complete")
    return d


#: Each command's PSF options per source.
PSF = {
    "recon": {"file": ["--psf", "psf.npy"], "run": ["--psf", "sweep.zarr", "--depth", "20"],
              "stack": ["--psf", "stack.tif", "--depth", "20"],
              "grid": ["--psf-grid", "grid.zarr"]},
    "recon3d": {"file": ["--psf-stack", "stack.tif"], "run": ["--psf-stack", "sweep.zarr"],
                "stack": ["--psf-stack", "stack.npy", "--depths", "20,200"],
                "grid": ["--psf-grid", "grid.zarr"]},
    "recon-run": {"file": ["--psf", "psf.npy"],
                  "run": ["--psf", "sweep.zarr", "--depth", "20"],
                  "stack": ["--psf", "stack.tif", "--depth", "20"],
                  "grid": ["--psf-grid", "grid.zarr"]},
}


def _argv(d, command, source, dark):
    head = {"recon": ["recon", "--raw", "raw.npy", "--out", str(d / "out" / "r")],
            "recon3d": ["recon3d", "--raw", "raw.npy", "--out", str(d / "out" / "v.tif")],
            "recon-run": ["recon-run", str(d / "video.zarr"), "--workers", "1"]}[command]
    return [*head, *PSF[command][source], "--dark", dark, "--iterations", "2"]


@pytest.mark.parametrize("form", ["file", "run"])
@pytest.mark.parametrize("source", ["file", "run", "stack", "grid"])
@pytest.mark.parametrize("command", ["recon", "recon3d", "recon-run"])
def test_a_dark_frame_of_another_shape_is_refused_in_one_line(inputs, command, source, form,
                                                              capsys, monkeypatch):
    d = inputs
    monkeypatch.chdir(d)
    dark = "dark.npy" if form == "file" else "dark.zarr"
    capsys.readouterr()
    assert main(_argv(d, command, source, dark)) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("diffuserlab: error:") and "\n" not in err, err
    assert "internal error" not in err and "broadcast" not in err
    if source == "grid":  # a grid takes one level
        assert "--psf-grid subtracts one level, not a dark run or image" in err
        assert "use auto, none or a number" in err
    else:
        assert "dark frame is 32x40" in err and "256x320" in err
        assert "give a dark frame of the same camera region" in err and "--dark DN" in err
    assert not (d / "out").exists()
    assert not [n for n in RunStore.open(d / "video.zarr").products() if "recon" in n]


@pytest.mark.parametrize("form", ["none", "level"])
@pytest.mark.parametrize("command", ["recon", "recon3d", "recon-run"])
def test_the_other_dark_forms_with_a_calibration_runs_psf_reconstruct(inputs, command, form,
                                                                       tmp_path, monkeypatch):
    """none and a level (added to the calibrated PSF, then subtracted) work with the run's
    PSF in every command."""
    d = inputs
    monkeypatch.chdir(d)
    argv = _argv(d, command, "run", "none" if form == "none" else "10")
    argv = [a if a != str(d / "out" / "r") and a != str(d / "out" / "v.tif") else
            str(tmp_path / ("r" if command == "recon" else "v.tif")) for a in argv]
    if command == "recon-run":
        argv += ["--product", f"recon_{form}", "--method", "wiener"]
    assert main(argv) == 0

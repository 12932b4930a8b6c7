"""A damaged run (chunk file deleted or altered) is reported by every command that
reads it, naming the frame, and `calibrate resume --redo POINT` repairs it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import zarr

from instrument.cli import main
from instrument.runs.runstore import RunStore

ROOT = Path(__file__).resolve().parents[3]
BENCH = str(ROOT / "examples" / "bench-simulated.toml")


@pytest.fixture
def sweep(tmp_path):
    path = tmp_path / "sweep.zarr"
    assert main(["calibrate", "psf-sweep", BENCH, "--simulate", "--z-min", "30",
                 "--z-max", "60", "--n-depths", "3", "--frames", "2", "--out",
                 str(path)]) == 0
    return path


def _frame_of_point(path, point):
    return RunStore.open(path).frame_range(point).start


@pytest.mark.parametrize("damage", ["delete", "alter"])
def test_damaged_frame_is_named_and_redo_repairs_it(sweep, tmp_path, capsys, damage):
    index = _frame_of_point(sweep, 1)
    if damage == "delete":
        (sweep / f"frames/c/{index}/0/0").unlink()
    else:
        arr = zarr.open_group(str(sweep), mode="r+")["frames"]
        arr[index] = np.asarray(arr[index]) // 2 + 1
    capsys.readouterr()
    # export takes the intact frames and names the one it left out, with its repair
    assert main(["runs", "export", str(sweep), "--frames", "--out",
                 str(tmp_path / "f.tif")]) == 0
    said = " ".join(capsys.readouterr())
    assert f"frame {index} (point 1)" in said and "--redo 1" in said
    import tifffile

    from instrument.runs.tiff_export import read_tiff_metadata

    with tifffile.TiffFile(tmp_path / "f.tif") as tif:
        assert index not in read_tiff_metadata(tif)["frame_indices"]
    # a plain resume verifies every frame first and refuses, changing nothing
    assert main(["calibrate", "resume", str(sweep), BENCH, "--simulate"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"1 damaged frame(s) (frame {index}:" in err
    assert err.endswith(f"resume {sweep} BENCH.toml --redo 1")
    assert RunStore.open(sweep).attrs["resumes"] == []
    assert main(["calibrate", "resume", str(sweep), BENCH, "--simulate", "--redo", "1"]) == 0
    store = RunStore.open(sweep)
    assert store.status == "complete" and store.verify() == []
    assert len(store.attrs["resumes"]) == 1
    assert not (sweep / ".lock").exists()  # released after each run and resume


def test_redo_rejects_bad_points(sweep, capsys):
    assert main(["calibrate", "resume", str(sweep), BENCH, "--simulate", "--redo", "x"]) == 2
    assert "--redo 'x'" in capsys.readouterr().err
    assert main(["calibrate", "resume", str(sweep), BENCH, "--simulate", "--redo", "9"]) == 2
    assert "no point 9" in capsys.readouterr().err


def test_runs_verify_and_show(sweep, tmp_path, capsys):
    assert main(["runs", "verify", str(sweep)]) == 0
    assert "intact:" in capsys.readouterr().out
    index = _frame_of_point(sweep, 2)
    (sweep / f"frames/c/{index}/0/0").unlink()
    (sweep / "products/psf_stack/0/c/0/0/0").unlink()
    assert main(["runs", "verify", str(sweep)]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"frame {index} (point 2)") and "missing" in lines[0]
    assert lines[1].startswith("product 'psf_stack'") and "plane 0" in lines[1]
    assert lines[2].startswith("damaged: 2 problem(s)")
    assert main(["runs", "show", str(sweep)]) == 0
    out = capsys.readouterr().out
    assert "(complete, DAMAGED)" in out and f"damaged  frame {index} (point 2)" in out
    assert main(["runs", "export", str(sweep), "--out", str(tmp_path / "p.tif")]) == 2
    assert "product 'psf_stack'" in capsys.readouterr().err
    np.save(tmp_path / "raw.npy", np.ones((256, 320), np.float32))
    assert main(["recon", "--psf", str(sweep), "--depth", "30", "--raw",
                 str(tmp_path / "raw.npy"), "--out", str(tmp_path / "r.tif")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "product 'psf_stack'" in err and "plane 0" in err
    assert not (tmp_path / "r.tif").exists()
    assert main(["runs", "verify", str(tmp_path / "nothing.zarr")]) == 2
    assert "no run store" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["file", "dir"])
def test_calibrate_overwrite_refuses_what_is_not_a_run(tmp_path, capsys, kind):
    target = tmp_path / "results"
    if kind == "file":
        target.write_text("precious")
    else:
        target.mkdir()
        (target / "keep.txt").write_text("precious")
    assert main(["calibrate", "dark", BENCH, "--simulate", "--frames", "2", "--out",
                 str(target), "--overwrite"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(target) in err[0] and "not a diffuserlab run store" in err[0]
    assert (target if kind == "file" else target / "keep.txt").read_text() == "precious"


def test_calibrate_overwrite_replaces_a_run(sweep):
    assert main(["calibrate", "dark", BENCH, "--simulate", "--frames", "2", "--out",
                 str(sweep), "--overwrite"]) == 0
    assert RunStore.open(sweep).attrs["plan"]["name"] != "psf-sweep"

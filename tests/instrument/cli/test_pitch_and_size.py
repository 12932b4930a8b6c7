"""--pitch-um and --memory-limit: one check each, shared by the commands that take them
(instrument.options.check_pitch_um, instrument.cli.common.size_bytes); what is no pitch or
no size is refused in one line, exit 2, before any work (issue 64: recon wrote
PhysicalSizeX="inf", recon3d checked nothing, 0 was silently no pitch, .GB read as
1 GB)."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from instrument.cli import main
from instrument.cli.common import size_bytes

SHAPE = (24, 32)


@pytest.fixture
def files(tmp_path, monkeypatch):
    rng = np.random.default_rng(3)
    np.save(tmp_path / "psf.npy", rng.random(SHAPE).astype(np.float32))
    np.save(tmp_path / "raw.npy", (100 * rng.random(SHAPE)).astype(np.float32))
    tifffile.imwrite(tmp_path / "stack.tif", rng.random((2, *SHAPE)).astype(np.float32),
                     metadata={"depths_mm": [2.0, 4.0]}, photometric="minisblack")
    monkeypatch.chdir(tmp_path)
    return tmp_path


COMMANDS = {
    "recon": ["recon", "--psf", "psf.npy", "--raw", "raw.npy", "--out", "out/r"],
    "recon3d": ["recon3d", "--psf-stack", "stack.tif", "--raw", "raw.npy",
                "--out", "out/v.tif"],
    "runs import-psf": ["runs", "import-psf", "stack.tif", "--out", "out/i.zarr"],
    "analyze": ["analyze", "grid", "--psf-stack", "stack.tif", "--d-mm", "1",
                "--out", "out/a"],
}


def _refused(argv, capsys) -> str:
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("diffuserlab: error:") and "\n" not in err, err
    return err


@pytest.mark.parametrize("value", ["inf", "1e400", "nan", "-1", "0"])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_pitch_that_is_no_pitch_is_refused(files, command, value, capsys):
    err = _refused([*COMMANDS[command], "--pitch-um", value], capsys)
    assert "--pitch-um" in err
    if value == "0":
        assert "leave --pitch-um out for no pixel size" in err
    else:
        assert "a finite number > 0" in err
    assert not (files / "out").exists()


@pytest.mark.parametrize("text", [".GB", "GB", "", "-1GB", "0", "nanGB", "16 XB"])
def test_a_memory_limit_without_a_number_is_refused(files, text, capsys):
    err = _refused([*COMMANDS["recon3d"], f"--memory-limit={text}"], capsys)
    assert f"--memory-limit {text!r}: give a positive size" in err
    assert not (files / "out").exists()


def test_sizes_with_their_number_are_read():
    assert size_bytes("16GB") == 16 * 10 ** 9 and size_bytes("2GiB") == 2 * 2 ** 30
    assert size_bytes("0.5GB") == 5 * 10 ** 8 and size_bytes("1.5e9") == 15 * 10 ** 8
    assert size_bytes("1000") == 1000


def test_a_good_pitch_is_the_tiffs_pixel_size(files):
    assert main([*COMMANDS["recon"], "--pitch-um", "3.45", "--iterations", "2"]) == 0
    with tifffile.TiffFile(files / "out" / "r.tif") as tif:
        assert 'PhysicalSizeX="3.45"' in tif.pages[0].description


@pytest.mark.parametrize("value", [float("inf"), float("nan"), -1.0, 0, "3.45", True])
def test_import_psf_stack_from_python_checks_its_pitch(files, value):
    """The Python function takes the commands' check (issue 64 left it unchecked: a run
    recorded ``pixel_pitch_um`` inf), naming its keyword, before anything is written."""
    from diffuserlab.errors import InputError
    from instrument.runs.stacks import import_psf_stack

    with pytest.raises(InputError) as info:
        import_psf_stack(files / "stack.tif", files / "out" / "i.zarr", pitch_um=value)
    message = str(info.value)
    assert message.startswith("pitch_um=") and "\n" not in message, message
    assert ("leave pitch_um out" in message if value == 0
            else "a finite number > 0 (e.g. pitch_um=3.45)" in message), message
    assert not (files / "out").exists()
    store = import_psf_stack(files / "stack.tif", files / "out" / "i.zarr",
                             pitch_um=np.float32(3.45))
    assert store.attrs["camera"]["pixel_pitch_um"] == pytest.approx(3.45)

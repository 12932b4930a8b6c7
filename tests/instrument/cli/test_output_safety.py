"""Outputs never clobber inputs, and one error boundary for every command.

Table-driven: each bad case is a command line that must exit 2 with one line on
stderr (no traceback) naming the problem, before any work, leaving every file under
the test directory unchanged (sha256 before and after, no new files); the checks are
:func:`tests.faults.helpers.assert_refused`, shared with the fault table of every
other input class (``tests/faults``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile

import instrument.cli.recon
from instrument.cli import main
from instrument.writer.guards import OutputError, check_outputs
from tests.faults.helpers import assert_refused


@pytest.fixture
def files(tmp_path):
    """Small inputs: psf.npy, raw.tif, stack.tif (depths), a run store, a directory
    ``dir``, a regular file ``file.txt`` and earlier outputs of every command."""
    rng = np.random.default_rng(0)
    psf = rng.random((32, 32)).astype(np.float32)
    np.save(tmp_path / "psf.npy", psf)
    tifffile.imwrite(tmp_path / "raw.tif", (100 * rng.random((32, 32))).astype(np.float32))
    stack = rng.random((3, 32, 32)).astype(np.float32)
    tifffile.imwrite(tmp_path / "stack.tif", stack, metadata={"depths_mm": [2.0, 4.0, 8.0]},
                     photometric="minisblack")
    assert main(["runs", "import-psf", str(tmp_path / "stack.tif"), "--out",
                 str(tmp_path / "run.zarr")]) == 0
    (tmp_path / "dir").mkdir()
    (tmp_path / "file.txt").write_text("not a directory\n")
    (tmp_path / "old.png").write_bytes(b"earlier output")
    for folder, name in (("demo", "report.json"), ("analysis", "resolution.json"),
                         ("bench", "summary.json"), ("holo", "summary.json")):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / name).write_text("{}")
    (tmp_path / "holo.json").write_text("{}")
    return tmp_path


def _cases(d):
    recon = ["recon", "--psf", d / "psf.npy", "--raw", d / "raw.tif", "--iterations", 2]
    return {
        "recon metrics-json is a directory": (
            [*recon, "--out", d / "o", "--metrics-json", d / "dir"], ["is a directory"]),
        "recon out stem is the raw input": (
            [*recon, "--out", d / "raw"], ["raw.tif", "is the input", "--raw"]),
        "recon out is the psf input": (
            [*recon, "--out", d / "psf.npy", "--metrics-json", d / "psf.npy"],
            ["psf.npy", "is the input"]),
        "recon metrics-json is the png": (
            [*recon, "--out", d / "o.png", "--metrics-json", d / "o.png"],
            ["o.png", "is also the output"]),
        "recon out exists": ([*recon, "--out", d / "old.png"], ["exists", "--overwrite"]),
        "recon out unwritable": ([*recon, "--out", "/proc/x/y.png"], ["/proc/x", "cannot"]),
        "recon3d out is the stack": (
            ["recon3d", "--psf-stack", d / "stack.tif", "--raw", d / "raw.tif", "--out",
             d / "stack.tif"], ["stack.tif", "is the input", "--psf-stack"]),
        "demo out is a file": (["demo", "--out", d / "file.txt"], ["file.txt", "is a file"]),
        "demo negative seed": (["demo", "--seed", -1, "--out", d / "new"], ["--seed"]),
        "demo out holds a demo": (["demo", "--out", d / "demo"], ["report.json", "exists"]),
        "real sample out is a file": (["demo", "--real-sample", "--out", d / "file.txt"],
                                      ["is a file"]),
        "analyze out holds the analysis": (
            ["analyze", "resolution", "--psf-stack", d / "stack.tif", "--out", d / "analysis"],
            ["resolution.json", "exists"]),
        "analyze out inside the run store": (
            ["analyze", "resolution", "--psf-stack", d / "run.zarr", "--out",
             d / "run.zarr" / "x"], ["is inside the input", "run.zarr"]),
        "runs export out is a directory": (
            ["runs", "export", d / "run.zarr", "--out", d / "dir"], ["is a directory"]),
        "runs export out is the run": (
            ["runs", "export", d / "run.zarr", "--out", d / "run.zarr"], ["is the input"]),
        "runs export out exists": (
            ["runs", "export", d / "run.zarr", "--out", d / "raw.tif"], ["exists"]),
        "runs import-psf out is the stack": (
            ["runs", "import-psf", d / "stack.tif", "--out", d / "stack.tif"],
            ["is the input"]),
        "holo evaluate out is a file": (
            ["holo", "evaluate", "--quick", "--out", d / "file.txt"], ["is a file"]),
        "holo evaluate out holds an evaluation": (
            ["holo", "evaluate", "--quick", "--out", d / "holo"], ["summary.json", "exists"]),
        "holo benchmark json exists": (
            ["holo", "benchmark", "--quick", "--json", d / "holo.json"], ["exists", "--json"]),
        "benchmark out holds results": (
            ["benchmark", "recon", "--quick", "--only", "speed", "--out", d / "bench"],
            ["summary.json", "exists"]),
        "benchmark out is a file": (
            ["benchmark", "recon", "--quick", "--out", d / "file.txt"], ["is a file"]),
        "recon out inside a run store": (
            [*recon, "--out", d / "run.zarr" / "r.tif"], ["inside the run store", "run.zarr"]),
        "demo out inside a run store": (
            ["demo", "--out", d / "run.zarr" / "demo"], ["inside the run store"]),
        "runs export out inside the run it exports": (
            ["runs", "export", d / "run.zarr", "--out", d / "run.zarr" / "x.tif"],
            ["inside"]),
    }


CASES = list(_cases(__import__("pathlib").Path("x")))


@pytest.mark.parametrize("case", CASES)
def test_bad_output_exits_2_with_one_line_and_inputs_unchanged(files, capsys, case):
    argv, words = _cases(files)[case]
    assert_refused(argv, words, files, capsys)


def test_overwrite_replaces_an_earlier_output(files, capsys):
    argv = ["recon", "--psf", str(files / "psf.npy"), "--raw", str(files / "raw.tif"),
            "--iterations", "2", "--out", str(files / "out" / "r"),
            "--metrics-json", str(files / "out" / "m.json")]
    assert main(argv) == 0
    first = (files / "out" / "m.json").read_text()
    assert main(argv) == 2
    assert "exists" in capsys.readouterr().err
    assert (files / "out" / "m.json").read_text() == first
    assert main([*argv, "--overwrite"]) == 0
    assert json.loads((files / "out" / "m.json").read_text())["output_png"].endswith("r.png")
    assert sorted(p.name for p in (files / "out").iterdir()) == ["m.json", "r.png", "r.tif"]


def test_overwrite_never_replaces_an_input(files):
    with pytest.raises(OutputError, match="is the input"):
        check_outputs([files / "raw.tif"], {"--raw": files / "raw.tif"}, overwrite=True)


@pytest.mark.parametrize("exc, status", [
    (PermissionError(13, "Permission denied", "/some/file"), 2),
    (FileNotFoundError(2, "No such file or directory", "/gone"), 2),
    (IsADirectoryError(21, "Is a directory", "/tmp"), 2),
    (NotADirectoryError(20, "Not a directory", "/etc/passwd/x"), 2),
    (OSError(28, "No space left on device", "/full/disk.tif"), 2),
    (OSError(5, "Input/output error", "/dev/sdx"), 2),  # every OS error: the path named
    (OSError("1966080 requested and 101288 written"), 2),  # numpy's short write, no errno
    (RuntimeError("something unexpected"), 1),
    (KeyError("missing"), 1),
])
def test_error_boundary(monkeypatch, capsys, exc, status):
    def boom(args):
        raise exc

    monkeypatch.setattr(instrument.cli.recon, "run", boom)
    assert main(["recon", "--psf", "p.npy", "--raw", "r.npy"]) == status
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    if status == 2:
        assert err.startswith("diffuserlab: error: ") and (exc.filename or "written") in err
    else:
        assert "bug" in err and "--debug" in err
        with pytest.raises(type(exc)):
            main(["--debug", "recon", "--psf", "p.npy", "--raw", "r.npy"])


def test_import_psf_overwrite_replaces_a_store_without_the_zarr_suffix(files):
    store = files / "store"
    argv = ["runs", "import-psf", str(files / "stack.tif"), "--out", str(store)]
    assert main(argv) == 0
    assert main([*argv, "--overwrite"]) == 0
    check_outputs([store], None, overwrite=True, store=True)
    with pytest.raises(OutputError, match="is a directory"):
        check_outputs([files / "dir"], None, overwrite=True)


def test_error_boundary_takes_project_errors_raised_anywhere(monkeypatch, capsys):
    """A bench-file error is one line per problem, a plan error one line, both exit 2
    (not a bug line), whichever command raises them."""
    from instrument.acquisition.plan import PlanError
    from instrument.config import BenchConfigError
    from instrument.config.problems import Problem

    problems = [Problem("geometry", "missing", "add it"), Problem("name", "empty", "name it")]
    for exc, lines in ((BenchConfigError(problems, "b.toml"), 2),
                       (PlanError("n=0: give n >= 2"), 1)):
        def boom(args, exc=exc):
            raise exc

        monkeypatch.setattr(instrument.cli.recon, "run", boom)
        assert main(["recon", "--psf", "p.npy", "--raw", "r.npy"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == lines and all(e.startswith("diffuserlab: error: ") for e in err)
        assert "bug" not in " ".join(err)


#: ``recon --out OUT``: the files it writes. Only .png/.tif/.tiff are extensions (``.2``
#: is part of the name); a folder (a trailing /) gets recon.png and recon.tif inside.
OUT_NAMES = [
    ("take.2", ["take.2.png", "take.2.tif"]),
    ("take.v2.png", ["take.v2.png", "take.v2.tif"]),
    ("take.TIFF", ["take.png", "take.tif"]),
    ("newdir/", ["newdir/recon.png", "newdir/recon.tif"]),
    ("dir", ["dir/recon.png", "dir/recon.tif"]),
]


@pytest.mark.parametrize("out, written", OUT_NAMES, ids=[o for o, _ in OUT_NAMES])
def test_only_known_extensions_are_extensions(files, capsys, out, written):
    """An earlier take's take.png and take.tif (and every input) stay as they were, even
    with --overwrite; the command writes exactly ``written``."""
    from tests.faults.helpers import tree

    (files / "take.png").write_bytes(b"an earlier take")
    (files / "take.tif").write_bytes(b"an earlier take")
    before = tree(files)
    argv = ["recon", "--psf", files / "psf.npy", "--raw", files / "raw.tif", "--iterations", 2,
            "--method", "admm", "--tv", 1e-3, "--out", f"{files}/{out}", "--overwrite"]
    assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    after = tree(files)
    replaced = {k for k in before if before[k] != after.get(k)}
    if out == "take.TIFF":  # the same stem: the earlier take is replaced, as asked
        assert replaced == {"take.png", "take.tif"}
    else:
        assert replaced == set()
    added = {k for k in after if k not in before and after[k] != "dir"}
    assert added == set(written) - set(before)

"""What other tools read of a run (its ``ome`` blocks, its arrays' dimension names)
against what the run recorded when it wrote them (instrument.runs.run_description).

Each case edits one ``zarr.json`` of a copy of a run the project's own commands made
(a simulated PSF sweep with its ``psf_stack``; a simulated video with the per-frame
reconstruction ``recon-run`` adds), as a careless hand or another tool would: an axis
renamed, a pixel size times 10, axes reversed, an ``ome`` block deleted or added,
dimension names deleted, edited or reversed. Every checksum still holds, so before
the record ``runs verify`` called each run intact while OME-Zarr readers and xarray
read other sizes or axes from it. Now it exits 1 with one line naming the node and
what changed, and changes nothing; the runs as the project writes, resumes,
extends and upgrades them verify intact.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from instrument.cli import main

from .helpers import run_cli, tree

ROOT = Path(__file__).resolve().parents[2]
BENCH = str(ROOT / "examples" / "bench-simulated.toml")
#: How a problem line of this check begins.
LINE = "metadata of "


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("described")
    assert main(["calibrate", "psf-sweep", BENCH, "--simulate", "--frames", "1",
                 "--n-depths", "2", "--out", str(d / "sweep.zarr")]) == 0
    assert main(["capture", "video", "--simulate", "--frames", "8",
                 "--shard-frames", "4", "--out", str(d / "video.zarr")]) == 0
    assert main(["recon-run", str(d / "video.zarr"), "--psf", str(d / "sweep.zarr"),
                 "--depth", "20", "--method", "wiener", "--workers", "1",
                 "--frames", "0:2"]) == 0
    return d


def _edit(node: str, change):
    """A damage: ``change(doc)`` applied to the ``zarr.json`` of ``node`` ("." the root)."""
    def damage(run: Path) -> None:
        meta = run / node / "zarr.json"
        doc = json.loads(meta.read_text())
        change(doc)
        meta.write_text(json.dumps(doc))
    return damage


def _ms(doc: dict) -> dict:
    return doc["attributes"]["ome"]["multiscales"][0]


def _scale(doc: dict) -> list:
    return _ms(doc)["datasets"][0]["coordinateTransformations"][0]["scale"]


def _rename_axis(doc: dict) -> None:
    _ms(doc)["axes"][1]["name"] = "row"


def _pixel_size_x10(doc: dict) -> None:
    scale = _scale(doc)
    scale[-2:] = [v * 10 for v in scale[-2:]]


def _reverse_axes(doc: dict) -> None:
    _ms(doc)["axes"].reverse()
    _scale(doc).reverse()


def _delete_ome(doc: dict) -> None:
    del doc["attributes"]["ome"]


def _delete_dims(doc: dict) -> None:
    del doc["dimension_names"]


def _rename_dim(doc: dict) -> None:
    doc["dimension_names"][-1] = "col"


def _reverse_dims(doc: dict) -> None:
    doc["dimension_names"].reverse()


def _depths(doc: dict) -> None:
    _ms(doc)["metadata"]["depths_mm"][0] = 2.0


def _add_block(run: Path) -> None:
    """``products/`` given an ``ome`` block listing ``psf_stack`` (it had none)."""
    block = json.loads((run / "products/psf_stack/zarr.json").read_text())
    _edit("products", lambda doc: doc["attributes"].update(
        ome=block["attributes"]["ome"]))(run)


#: (run, damage, words its line holds); every case: exit 1, one line
CASES = {
    "frames' image: axis renamed": (
        "sweep", _edit(".", _rename_axis),
        ["the run's root group", 'ome.multiscales[0].axes[1].name "row", recorded "y"',
         "runs upgrade"]),
    "frames' image: pixel size x10": (
        "video", _edit(".", _pixel_size_x10),
        ["the run's root group", "coordinateTransformations[0].scale [", "130.0",
         "recorded [", "13.0]"]),
    "frames' image: axes reversed": (
        "sweep", _edit(".", _reverse_axes),
        ["the run's root group", "ome.multiscales[0] changed",
         'ome.multiscales[0].axes[0].name "x", recorded "t"']),
    "frames' image: ome block deleted": (
        "video", _edit(".", _delete_ome),
        ["the run's root group", "ome is gone", "runs upgrade"]),
    "frames: dimension names deleted": (
        "sweep", _edit("frames", _delete_dims),
        ["'frames'", 'dimension_names is gone (recorded ["t","y","x"])', "runs upgrade"]),
    "frames: dimension name edited": (
        "sweep", _edit("frames", _rename_dim),
        ["'frames'", 'dimension_names ["t","y","col"], recorded ["t","y","x"]',
         "put the recorded values back", "backup copy"]),
    "frames: dimension names reversed": (
        "video", _edit("frames", _reverse_dims),
        ["'frames'", 'dimension_names ["x","y","t"], recorded ["t","y","x"]']),
    "coords: dimension name edited": (
        "video", _edit("coords", _rename_dim),
        ["'coords'", 'dimension_names ["t","col"], recorded ["t","coord"]']),
    "psf_stack image: axis renamed": (
        "sweep", _edit("products/psf_stack", _rename_axis),
        ["'products/psf_stack'", 'axes[1].name "row", recorded "y"']),
    "psf_stack image: pixel size x10": (
        "sweep", _edit("products/psf_stack", _pixel_size_x10),
        ["'products/psf_stack'", "coordinateTransformations[0].scale [", "130.0",
         "recorded ["]),
    "psf_stack image: axes reversed": (
        "sweep", _edit("products/psf_stack", _reverse_axes),
        ["'products/psf_stack'", 'axes[0].name "x", recorded "z"']),
    "psf_stack image: ome block deleted": (
        "sweep", _edit("products/psf_stack", _delete_ome),
        ["'products/psf_stack'", "ome is gone", "runs upgrade"]),
    "psf_stack image: depths edited": (
        "sweep", _edit("products/psf_stack", _depths),
        ["'products/psf_stack'", "ome.multiscales[0].metadata.depths_mm [2.0,"]),
    "psf_stack array: dimension names reversed": (
        "sweep", _edit("products/psf_stack/0", _reverse_dims),
        ["'products/psf_stack/0'", 'dimension_names ["x","y","z"], recorded ["z","y","x"]']),
    "psf_stack array: dimension names deleted": (
        "sweep", _edit("products/psf_stack/0", _delete_dims),
        ["'products/psf_stack/0'", "dimension_names is gone"]),
    "per-frame recon image: pixel size x10": (
        "video", _edit("products/recon_wiener", _pixel_size_x10),
        ["'products/recon_wiener'", "scale [", "recorded ["]),
    "per-frame recon done flags: dimension name edited": (
        "video", _edit("products/recon_wiener__done", _rename_dim),
        ["'products/recon_wiener__done'", 'dimension_names ["col"], recorded ["t"]']),
    "products/: an ome block added": (
        "sweep", _add_block, ["'products'", "ome {", "was added (the run recorded none)"]),
}


@pytest.mark.parametrize("name", CASES)
def test_an_edit_of_what_other_tools_read_is_damage(runs, tmp_path, capsys, name):
    which, damage, words = CASES[name]
    run = Path(shutil.copytree(runs / f"{which}.zarr", tmp_path / f"{which}.zarr"))
    damage(run)
    before = tree(tmp_path)
    code, out, err = run_cli(["runs", "verify", run], capsys)
    assert code == 1, out + err
    assert "Traceback" not in err
    lines = [line for line in out.splitlines() if line.startswith(LINE)]
    assert len(lines) == 1 and len(out.splitlines()) == 2, out  # its line and the verdict
    assert "changed since the run wrote it" in lines[0]
    for word in words:
        assert word in lines[0], f"{word!r} not in: {lines[0]}"
    assert out.splitlines()[-1].startswith("damaged: 1 problem(s)")
    assert tree(tmp_path) == before
    code, out, _ = run_cli(["runs", "show", run], capsys)
    assert code == 0 and "DAMAGED" in out and words[0] in out, out


def test_the_runs_the_project_writes_verify(runs, capsys):
    for which in ("sweep", "video"):
        code, out, _ = run_cli(["runs", "verify", runs / f"{which}.zarr"], capsys)
        assert code == 0 and out.startswith("intact"), out
        assert "written before" not in out, out


def test_later_writes_of_the_project_keep_the_run_intact(runs, tmp_path, capsys):
    """A resumed and an extended per-frame product, one replaced, a point captured
    again, an upgrade of a current run: each records what it wrote."""
    video = Path(shutil.copytree(runs / "video.zarr", tmp_path / "video.zarr"))
    sweep = Path(shutil.copytree(runs / "sweep.zarr", tmp_path / "sweep.zarr"))
    psf = ["--psf", str(runs / "sweep.zarr"), "--depth", "20", "--method", "wiener",
           "--workers", "1"]  # (the PSF the product was made with: it is resumed)
    steps = [
        ["recon-run", video, *psf, "--frames", "2:4"],  # the product resumed
        ["recon-run", video, *psf, "--frames", "0:2", "--overwrite"],  # replaced
        ["recon-run", video, *psf, "--frames", "0:2", "--product", "recon_b", "--bin", "2"],
        ["calibrate", "resume", sweep, BENCH, "--simulate", "--redo", "1"],
        ["runs", "upgrade", video],
        ["runs", "upgrade", sweep],
    ]
    for argv in steps:
        code, out, err = run_cli(argv, capsys)
        assert code == 0, f"{argv}: {out}{err}"
        run = video if video in argv else sweep
        code, out, _ = run_cli(["runs", "verify", run], capsys)
        assert code == 0 and out.startswith("intact"), f"after {argv}: {out}"
    products = json.loads((video / "products" / "zarr.json").read_text())["attributes"]
    assert {"recon_b", "recon_b/0", "recon_b__done"} <= set(products["described"])


def test_upgrade_writes_the_ome_blocks_again_but_keeps_an_edited_name(runs, tmp_path,
                                                                      capsys):
    """``runs upgrade`` repairs the ome blocks it derives (deleted, scaled) and names the
    dimensions of arrays that lost them; it never records an edited dimension name as
    the run's: that stays damage until the recorded names are put back."""
    run = Path(shutil.copytree(runs / "sweep.zarr", tmp_path / "sweep.zarr"))
    _edit(".", _delete_ome)(run)
    _edit("products/psf_stack", _pixel_size_x10)(run)
    _edit("frames", _delete_dims)(run)
    _edit("products/psf_stack/0", _rename_dim)(run)
    code, out, _ = run_cli(["runs", "verify", run], capsys)
    assert code == 1 and out.count(LINE) == 4, out
    assert main(["runs", "upgrade", str(run)]) == 0
    code, out, _ = run_cli(["runs", "verify", run], capsys)
    lines = sorted(line for line in out.splitlines() if line.startswith(LINE))
    assert code == 1 and len(lines) == 2, out  # the block written from the names, they
    assert lines[0].startswith(f"{LINE}'products/psf_stack' ") and \
        '"col", recorded "x"' in lines[0]
    assert lines[1].startswith(f"{LINE}'products/psf_stack/0' ") and '"col"' in lines[1]
    _edit("products/psf_stack/0", lambda doc: doc["dimension_names"].__setitem__(-1, "x"))(
        run)
    code, out, _ = run_cli(["runs", "verify", run], capsys)
    assert code == 1 and out.count(LINE) == 1 and "'products/psf_stack'" in out, out
    assert main(["runs", "upgrade", str(run)]) == 0
    code, out, _ = run_cli(["runs", "verify", run], capsys)
    assert code == 0 and out.startswith("intact"), out


def test_a_run_written_before_the_record(runs, tmp_path, capsys):
    """A run without the record verifies as before, saying what is not checked; ``runs
    upgrade`` records its metadata as it is, and an edit after that is damage."""
    run = Path(shutil.copytree(runs / "video.zarr", tmp_path / "video.zarr"))
    for node in (".", "products"):
        _edit(node, lambda doc: doc["attributes"].pop("described"))(run)
    code, out, _ = run_cli(["runs", "verify", run], capsys)
    assert code == 0 and "intact" in out and "ome blocks and dimension names are not " \
        "checked" in " ".join(out.split()), out
    assert main(["runs", "upgrade", str(run)]) == 0
    code, out, _ = run_cli(["runs", "verify", run], capsys)
    assert code == 0 and out.startswith("intact") and "written before" not in out, out
    _edit("products/recon_wiener/0", _reverse_dims)(run)
    code, out, _ = run_cli(["runs", "verify", run], capsys)
    assert code == 1 and "'products/recon_wiener/0'" in out, out

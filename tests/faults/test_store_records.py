"""Store damage that checksums cannot see: a run compared with what it recorded.

Table-driven like the fault table: each case damages a copy of a valid run (a
24-frame simulated video of shards of 8, a complete simulated PSF sweep) and runs a
command on it. ``runs verify`` exits 1 and names the damage on its line (docs/data-safety.md's
"Data safety": 1 damaged, 2 unreadable), ``runs show`` says DAMAGED, and ``runs export
--frames`` exports the intact frames and lists what it left out. Every command leaves
every file under the test directory as it was (sha256 before and after).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from instrument.cli import main

from .helpers import run_cli, tree


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("records")
    assert main(["capture", "video", "--simulate", "--frames", "24", "--shard-frames", "8",
                 "--out", str(d / "video.zarr")]) == 0
    assert main(["calibrate", "psf-sweep", "--simulate", "--frames", "1", "--n-depths", "2",
                 "--out", str(d / "sweep.zarr")]) == 0
    return d


def _done_chunk(run: Path) -> None:
    (run / "done" / "c" / "1").unlink()


def _product(run: Path) -> None:
    shutil.rmtree(run / "products" / "psf_stack")


def _doubled_plan(run: Path) -> None:
    meta = run / "zarr.json"
    doc = json.loads(meta.read_text())
    other = dict(doc["attributes"]["plan"], points=doc["attributes"]["plan"]["points"] * 2)
    text = meta.read_text().replace('"attributes": {',
                                    '"attributes": {"plan": ' + json.dumps(other) + ",", 1)
    assert text.count('"plan"') == 2
    meta.write_text(text)


def _sweep_done(run: Path) -> None:
    (run / "done" / "c" / "2").unlink()


def _undamaged(run: Path) -> None:
    pass


def _killed(run: Path) -> None:
    """What a SIGKILL while recording leaves: status recording, no summary, the last
    shard (frames 16-23) not yet written."""
    meta = run / "zarr.json"
    doc = json.loads(meta.read_text())
    doc["attributes"].update(status="recording", summary=None)
    meta.write_text(json.dumps(doc))
    (run / "done" / "c" / "2").unlink()
    shutil.rmtree(run / "frames" / "c" / "2")


def _frame_chunk(run: Path) -> None:
    """One byte of the second shard (frames 8-15) flipped: frame 11 no longer decodes."""
    chunk = run / "frames" / "c" / "1" / "0" / "0"
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0xFF
    chunk.write_bytes(bytes(data))


#: (run, damage, command, exit status, words the output must hold)
CASES = {
    "video done-flag chunk deleted: verify": (
        "video", _done_chunk, ["runs", "verify"], 1,
        ["frames 8-15", "not flagged done", "recorded 24 frames", "done/c/1", "backup"]),
    "video done-flag chunk deleted: show": (
        "video", _done_chunk, ["runs", "show"], 0, ["complete, DAMAGED", "frames 8-15"]),
    "complete sweep without psf_stack: verify": (
        "sweep", _product, ["runs", "verify"], 1,
        ["product 'psf_stack'", "missing", "calibrate resume"]),
    "complete sweep without psf_stack: show": (
        "sweep", _product, ["runs", "show"], 0, ["complete, DAMAGED", "psf_stack"]),
    "doubled plan in zarr.json: verify": (
        "sweep", _doubled_plan, ["runs", "verify"], 1, ["zarr.json", "'plan' twice"]),
    "complete sweep with a done chunk deleted: verify": (
        "sweep", _sweep_done, ["runs", "verify"], 1,
        ["frames 2", "not flagged done", "the run is complete"]),
    "altered video frame: export the intact frames": (
        "video", _frame_chunk, ["runs", "export", "--frames", "--out", "{d}/out/e.tif"], 0,
        ["wrote", "frame 11 (point 0)", "damaged", "cannot be captured again"]),
    # a recording is never continued (before: "no plan named 'video' is registered")
    "video: calibrate resume": (
        "video", _undamaged, ["calibrate", "resume", "--simulate"], 2,
        ["is a video recording", "cannot be continued", "24 stored frames are kept",
         "runs export", "--frames", "recon-run", "capture video"]),
    "killed video: calibrate resume": (
        "video", _killed, ["calibrate", "resume", "--simulate"], 2,
        ["is a video recording", "16 stored frames are kept"]),
    "altered video frame: verify offers no re-recording": (
        "video", _frame_chunk, ["runs", "verify"], 1,
        ["frame 11 (point 0)", "restore the run from a backup", "recon-run"]),
}


@pytest.mark.parametrize("name", CASES)
def test_damage_against_the_record_is_named(runs, tmp_path, capsys, name):
    which, damage, command, status, words = CASES[name]
    run = Path(shutil.copytree(runs / f"{which}.zarr", tmp_path / f"{which}.zarr"))
    damage(run)
    before = tree(tmp_path)
    argv = [a.format(d=tmp_path) for a in command[:2]] + [run] + \
        [a.format(d=tmp_path) for a in command[2:]]
    code, out, err = run_cli(argv, capsys)
    assert code == status, out + err
    assert "Traceback" not in err and "resume" not in (out + err if which == "video" else "")
    text = " ".join((out + err).split())
    for word in words:
        assert word in text, f"{word!r} not in: {text}"
    after = tree(tmp_path)
    assert {k: v for k, v in after.items() if not k.startswith("out")} == before
    if "export" in command:
        import tifffile

        from instrument.tiff_export import read_tiff_metadata

        with tifffile.TiffFile(tmp_path / "out" / "e.tif") as tif:
            frames = tif.asarray()
            meta = read_tiff_metadata(tif)  # (ImageJ hyperstack: its Info)
        assert frames.shape[0] == 23 and 11 not in meta["frame_indices"]


def test_the_intact_runs_verify(runs, capsys):
    for which in ("video", "sweep"):
        code, out, _ = run_cli(["runs", "verify", runs / f"{which}.zarr"], capsys)
        assert code == 0 and out.startswith("intact"), out


def test_the_api_never_continues_a_recording(runs, tmp_path):
    """Runner.resume refuses a video before it locks or touches the run."""
    from instrument.runner import Runner
    from instrument.runstore import RunStoreError

    run = Path(shutil.copytree(runs / "video.zarr", tmp_path / "video.zarr"))
    before = tree(tmp_path)
    with pytest.raises(RunStoreError, match="is a video recording"):
        Runner(bench=None).resume(run)
    assert tree(tmp_path) == before

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

from .helpers import assert_one_error_line, run_cli, tree


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


def _edit_meta(run: Path, array: str, **fields) -> None:
    """Edit data-defining fields of an array's zarr.json (what a careless hand does)."""
    meta = run / array / "zarr.json"
    doc = json.loads(meta.read_text())
    doc.update(fields)
    meta.write_text(json.dumps(doc))


def _float16(run: Path) -> None:
    _edit_meta(run, "frames", data_type="float16")


def _fewer_frames(run: Path) -> None:
    _edit_meta(run, "frames", shape=[16, 256, 320])


def _flipped(path: Path, at: int = 0) -> None:
    data = bytearray(path.read_bytes())
    data[at] ^= 0xFF
    path.write_bytes(bytes(data))


def _checksum_chunk(run: Path) -> None:
    """The zstd frame header of the checksums of frames 8-15 broken: it cannot decode."""
    _flipped(run / "crc32" / "c" / "1")


def _done_flags_chunk(run: Path) -> None:
    _flipped(run / "done" / "c" / "1")


def _compression_level(run: Path) -> None:
    """The frames' compression level edited deep inside their codecs (a long value)."""
    meta = run / "frames" / "zarr.json"
    doc = json.loads(meta.read_text())

    def edit(codecs):
        for c in codecs:
            conf = c.get("configuration") or {}
            if "clevel" in conf:  # blosc's
                conf["clevel"] = (int(conf["clevel"]) + 3) % 10
                return True
            if edit(conf.get("codecs") or []):
                return True
        return False

    assert edit(doc["codecs"]), doc["codecs"]
    meta.write_text(json.dumps(doc))


def _product_dtype(run: Path) -> None:
    _edit_meta(run / "products" / "psf_stack", "0", data_type="int32")


def _old_store_fewer_frames(run: Path) -> None:
    """A run written before the layout record, its frames' shape then cut."""
    meta = run / "zarr.json"
    doc = json.loads(meta.read_text())
    del doc["attributes"]["arrays"]
    meta.write_text(json.dumps(doc))
    _fewer_frames(run)


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
    # the arrays' metadata against what the run recorded when it wrote them (before:
    # float16 frames verified intact and exported as garbage; fewer frames and a broken
    # checksum chunk were "internal error (a bug)")
    "frames relabelled float16: verify": (
        "video", _float16, ["runs", "verify"], 1,
        ["frames/zarr.json is damaged", "data_type 'float16'", "recorded data_type 'uint16'",
         "put the recorded values back", "backup copy"]),
    "frames relabelled float16: show": (
        "video", _float16, ["runs", "show"], 0, ["complete, DAMAGED", "data_type 'float16'"]),
    "frames relabelled float16: export refuses": (
        "video", _float16, ["runs", "export", "--frames", "--out", "{d}/out/e.tif"], 2,
        ["frames/zarr.json is damaged", "data_type"]),
    "frames cut to fewer: verify": (
        "video", _fewer_frames, ["runs", "verify"], 1,
        ["frames/zarr.json is damaged", "shape [16,256,320]", "recorded shape [24,256,320]"]),
    "frames cut to fewer: show": (
        "video", _fewer_frames, ["runs", "show"], 0, ["complete, DAMAGED", "shape [16,256,320]"]),
    # a long value is shown down to the entry that differs (its head alone hid it)
    "frames' compression level edited: verify": (
        "video", _compression_level, ["runs", "verify"], 1,
        ["frames/zarr.json is damaged", ".configuration.clevel 8", "recorded codecs["]),
    "checksum chunk unreadable: verify": (
        "video", _checksum_chunk, ["runs", "verify"], 1,
        ["frame 8 (point 0)", "frame 15 (point 0)", "checksum chunk crc32/c/1 cannot be read",
         "cannot be verified", "restore crc32/c/1"]),
    "checksum chunk unreadable: export leaves its frames out": (
        "video", _checksum_chunk, ["runs", "export", "--frames", "--out", "{d}/out/e.tif"], 0,
        ["wrote", "skipped", "crc32/c/1"]),
    "done-flag chunk unreadable: verify": (
        "video", _done_flags_chunk, ["runs", "verify"], 1,
        ["done flags", "done/c/1 is damaged", "backup copy"]),
    "checksums deleted: verify": (  # before: read as a run without checksums, "intact"
        "video", lambda run: shutil.rmtree(run / "crc32"), ["runs", "verify"], 1,
        ["crc32/zarr.json is missing", "no frame can be verified", "backup copy"]),
    "product relabelled int32: verify": (
        "sweep", _product_dtype, ["runs", "verify"], 1,
        ["products/psf_stack/0/zarr.json is damaged", "data_type 'int32'",
         "recorded data_type 'float"]),
    "old store without the record, frames cut: verify": (
        "video", _old_store_fewer_frames, ["runs", "verify"], 1,
        ["frames/zarr.json is damaged", "holds 16 frame slots", "plan records 24",
         "written before runs recorded their array layout"]),
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
    if "export" in command and status == 0:
        import tifffile

        from instrument.runs.tiff_export import read_tiff_metadata

        with tifffile.TiffFile(tmp_path / "out" / "e.tif") as tif:
            frames = tif.asarray()
            meta = read_tiff_metadata(tif)  # (ImageJ hyperstack: its Info)
        left_out = {11} if damage is _frame_chunk else set(range(8, 16))
        assert frames.shape[0] == 24 - len(left_out)
        assert not left_out & set(meta["frame_indices"])
    if status == 2:
        assert not (tmp_path / "out").exists()


def test_the_intact_runs_verify(runs, capsys):
    for which in ("video", "sweep"):
        code, out, _ = run_cli(["runs", "verify", runs / f"{which}.zarr"], capsys)
        assert code == 0 and out.startswith("intact"), out


def test_an_old_store_without_the_layout_record_still_verifies(runs, tmp_path, capsys):
    """A run written before the record opens and verifies, and says what its check
    cannot see."""
    run = Path(shutil.copytree(runs / "video.zarr", tmp_path / "video.zarr"))
    meta = run / "zarr.json"
    doc = json.loads(meta.read_text())
    del doc["attributes"]["arrays"]
    meta.write_text(json.dumps(doc))
    code, out, _ = run_cli(["runs", "verify", run], capsys)
    assert code == 0 and "intact" in out and "written before runs recorded" in out, out


def test_metadata_that_is_not_data_may_change(runs, tmp_path, capsys):
    """An array's own attributes are no damage, nor its dimension names written again
    as they were (changed ones are: tests/faults/test_description_record.py)."""
    run = Path(shutil.copytree(runs / "video.zarr", tmp_path / "video.zarr"))
    _edit_meta(run, "frames", dimension_names=["t", "y", "x"],
               attributes={"note": "added by hand"})
    code, out, _ = run_cli(["runs", "verify", run], capsys)
    assert code == 0 and out.startswith("intact"), out


def test_a_path_inside_a_store_names_the_run(runs, capsys):
    """``runs verify RUN.zarr/frames`` calls a healthy run neither damaged nor intact."""
    run = runs / "video.zarr"
    for argv in (["runs", "verify", run / "frames"], ["runs", "show", run / "crc32"]):
        code, out, err = run_cli(argv, capsys)
        assert code == 2 and "damaged" not in err, err
        assert_one_error_line(err, ["inside the run store", str(run)])


def test_a_damaged_layout_is_never_written(runs, tmp_path):
    """A writer (a resume, recon-run) refuses a run whose arrays are described otherwise."""
    from instrument.runs.runstore import RunStore, RunStoreError

    run = Path(shutil.copytree(runs / "video.zarr", tmp_path / "video.zarr"))
    _float16(run)
    store = RunStore.open(run, "r+")
    with pytest.raises(RunStoreError, match="data_type 'float16'"):
        store.lock()
    with pytest.raises(RunStoreError, match="data_type 'float16'"):
        store.frame(0)
    assert not (run / ".lock").exists()


def test_the_api_never_continues_a_recording(runs, tmp_path):
    """Runner.resume refuses a video before it locks or touches the run."""
    from instrument.acquisition.runner import Runner
    from instrument.runs.runstore import RunStoreError

    run = Path(shutil.copytree(runs / "video.zarr", tmp_path / "video.zarr"))
    before = tree(tmp_path)
    with pytest.raises(RunStoreError, match="is a video recording"):
        Runner(bench=None).resume(run)
    assert tree(tmp_path) == before

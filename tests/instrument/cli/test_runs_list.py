"""``diffuserlab runs list DIR``: one line per run with its kind, status, frames and lock
(held by whom, or stale), and who closed a run whose writer was killed."""

from __future__ import annotations

import json
import multiprocessing
import os
import socket

import pytest

from instrument.acquisition.video import record_video
from instrument.bench.bench_recovery import close_orphaned_run
from instrument.cli import main
from instrument.devices.virtual_bench import VirtualBench
from instrument.runs.run_integrity import LOCK_NAME
from instrument.runs.runstore import RunStore


def _dead_pid() -> int:
    """The pid of a process that has ended (and been reaped)."""
    process = multiprocessing.get_context("spawn").Process(target=int)
    process.start()
    process.join()
    return process.pid


def _lock_as(path, pid: int) -> None:
    (path / LOCK_NAME).write_text(json.dumps({"pid": pid, "host": socket.gethostname(),
                                              "started_utc": "2026-01-01T00:00:00Z"}))


def test_one_line_per_run_with_status_frames_and_lock(tmp_path, capsys):
    folder = tmp_path / "runs"
    with VirtualBench(seed=0) as vb:
        for name in ("done", "writing", "killed", "closed"):
            record_video(vb, folder / f"{name}.zarr", frames=3, fps=20.0)
    (folder / "sub").mkdir()
    (folder / "sub" / "broken.zarr").mkdir()
    writing = RunStore.open(folder / "writing.zarr", "r+")
    writing.update_attrs(status="recording")
    writing.lock()  # this process writes it
    dead = _dead_pid()
    for name in ("killed", "closed"):
        RunStore.open(folder / f"{name}.zarr", "r+").update_attrs(status="recording")
        _lock_as(folder / f"{name}.zarr", dead)
    assert close_orphaned_run(folder / "closed.zarr", writer_pid=dead,
                              closed_by="the window (pid 1)", why="it was killed")
    try:
        assert main(["runs", "list", str(folder)]) == 0
    finally:
        writing.unlock()
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 5
    by_name = {os.path.basename(line.split("  ")[0]): line for line in lines}
    assert by_name["done.zarr"].endswith("video  complete  3/3 frames  unlocked")
    assert (f"video  recording  3/3 frames  locked by pid {os.getpid()} on "
            f"{socket.gethostname()} (running)") in by_name["writing.zarr"]
    assert f"recording  3/3 frames  stale lock: pid {dead} is gone" in by_name["killed.zarr"]
    assert ("interrupted  3/3 frames  unlocked  closed by the window (pid 1): it was "
            "killed") in by_name["closed.zarr"]
    assert "not a readable run" in by_name["broken.zarr"]


def test_a_folder_that_is_not_there_is_one_line_and_status_2(tmp_path, capsys):
    assert main(["runs", "list", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"diffuserlab: error: runs list {tmp_path / 'nope'}: no such folder; "
                   "give the folder the runs are in"]


@pytest.mark.parametrize("alive", [True, False], ids=["alive", "dead"])
def test_a_run_is_closed_only_while_its_dead_writer_holds_it(tmp_path, alive):
    with VirtualBench(seed=0) as vb:
        record_video(vb, tmp_path / "v.zarr", frames=2, fps=20.0)
    RunStore.open(tmp_path / "v.zarr", "r+").update_attrs(status="recording")
    pid = os.getpid() if alive else _dead_pid()
    _lock_as(tmp_path / "v.zarr", pid)
    closed = close_orphaned_run(tmp_path / "v.zarr", writer_pid=pid, closed_by="x", why="y")
    store = RunStore.open(tmp_path / "v.zarr")
    assert closed is (not alive)
    assert store.status == ("recording" if alive else "interrupted")
    assert (store.lock_owner() is None) is (not alive)

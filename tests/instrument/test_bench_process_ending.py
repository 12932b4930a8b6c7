"""The bench process closes a recording's run, whatever ends it: its parent (the window)
killed outright, or a SIGTERM to the bench process itself. The run is left ``stopped``,
its writer lock released and every frame it holds intact, as a Ctrl-C'd ``capture
video`` leaves it."""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from instrument.runs.runstore import RunStore

from .test_bench_process import _zombie

OPEN = {"bench_path": None, "simulate": True, "seed": 0, "scene": "none"}

#: A recording far longer than any test: 2400 frames at 20 fps (2 min), so it is
#: running when the test ends its process.
RECORD = {"frames": 2400, "seconds": None, "options": {"fps": 20.0}, "simulated": None}

#: Hang guard, s: the longest any step may take on a loaded machine.
HANG_S = 60.0

pytestmark = pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads /proc (Linux)")


def _window_script(tmp_path) -> str:
    """A window's stand-in: opens the simulated bench in a bench process, prints the
    bench process's pid, starts a recording and prints each progress report."""
    script = textwrap.dedent(f"""
        import json, sys, time
        sys.path[:0] = {sys.path!r}
        from instrument.bench.bench_process import BenchClient
        if __name__ == "__main__":
            c = BenchClient()
            c.run_job("open_bench", {OPEN!r})
            print(json.dumps({{"host_pid": c._manager._process.pid}}), flush=True)
            report = lambda p: print(json.dumps({{"recorded": p["recorded"]}}), flush=True)
            try:
                got = c.run_job("record", dict(out=sys.argv[1], **{RECORD!r}),
                                report=report)
                print(json.dumps({{"status": got["status"]}}), flush=True)
            except Exception as exc:
                print(json.dumps({{"error": str(exc)}}), flush=True)
            time.sleep({HANG_S})
        """)
    path = tmp_path / "window.py"
    path.write_text(script)
    return str(path)


def _recording_window(tmp_path):
    """The window process, the bench process's pid, the run's path and the frames
    recorded when the run first held some (read from the window's progress)."""
    run = tmp_path / "rec.zarr"
    window = subprocess.Popen([sys.executable, _window_script(tmp_path), str(run)],
                              stdout=subprocess.PIPE, text=True)
    lines: queue.SimpleQueue = queue.SimpleQueue()
    threading.Thread(target=lambda: [lines.put(x) for x in window.stdout], daemon=True).start()

    def next_line() -> dict:
        try:
            return json.loads(lines.get(timeout=HANG_S))
        except queue.Empty:
            window.kill()
            pytest.fail(f"the window printed nothing for {HANG_S:.0f} s")

    host_pid = next_line()["host_pid"]
    recorded = 0
    while recorded < 1:  # a shard is in the store (the progress says so)
        recorded = next_line().get("recorded", 0)
    return window, host_pid, run, recorded


def _wait_gone(pid: int) -> None:
    deadline = time.monotonic() + HANG_S
    while not _zombie(pid):  # ended: gone, or not reaped (its parent died first)
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            pytest.fail(f"the bench process was still running {HANG_S:.0f} s later")
        time.sleep(0.05)


def _assert_closed(run, recorded_before: int) -> None:
    store = RunStore.open(run)
    assert store.attrs["status"] == "stopped"
    assert store.attrs["ended_utc"]
    assert store.lock_owner() is None and not (run / ".lock").exists()
    summary = store.summary()
    assert summary["problems"] == []
    assert summary["frames_done"] == summary["frames"] >= recorded_before  # cut to its frames
    assert summary["summary"]["recording"]["recorded"] == summary["frames_done"]


def test_a_killed_window_leaves_its_recording_closed(tmp_path):
    window, host_pid, run, recorded = _recording_window(tmp_path)
    try:
        os.kill(window.pid, signal.SIGKILL)
        window.wait(HANG_S)
        _wait_gone(host_pid)
    finally:
        if window.poll() is None:
            window.kill()
    _assert_closed(run, recorded)


def test_sigterm_to_the_bench_process_closes_its_recording(tmp_path):
    window, host_pid, run, recorded = _recording_window(tmp_path)
    try:
        os.kill(host_pid, signal.SIGTERM)
        _wait_gone(host_pid)
    finally:
        window.kill()
        window.wait(HANG_S)
    _assert_closed(run, recorded)

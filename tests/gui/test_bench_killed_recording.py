"""The bench process killed (SIGKILL) while the window records: the window closes the
run (interrupted, who closed it and why, frames kept, lock gone) before Restart bench,
and its message names no Connect button the window does not show."""

from __future__ import annotations

import os
import signal

import pytest

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs SIGKILL")


def test_a_recording_under_a_killed_bench_is_closed_by_the_window(window, wait, tmp_path):
    from instrument.runs.runstore import RunStore, RunStoreError

    session, devices, panel = window.session, window.devices, window.record
    out = str(tmp_path / "video.zarr")
    panel.out.setText(out)
    panel.frames.setText("5000")
    panel.fps.setText("20")
    job = panel.start_recording()
    assert job is not None, panel.record_error.text()
    def recorded() -> int:
        try:
            return int(RunStore.open(out).done().sum())
        except RunStoreError:  # being created
            return 0

    wait(lambda: str(out) in session.service.writing.values() and recorded() > 2, 60.0,
         "frames recorded")
    pid = session.service._manager._process.pid
    window_name = session.service.name
    os.kill(pid, signal.SIGKILL)
    wait(lambda: devices.lost_box.isVisible() and job.done, 60.0,
         "the window to notice the bench ended")
    wait(lambda: RunStore.open(out).status == "interrupted", 60.0, "the run closed")
    store = RunStore.open(out)
    assert store.lock_owner() is None and store.done().sum() > 2
    closed = store.attrs["closed_by"]
    assert closed["by"] == window_name and "SIGKILL" in closed["why"]
    said = " ".join([panel.record_error.text(), panel.counters.text(),
                     devices.lost_label.text()])
    assert "connect again" not in said.lower() and "press connect" not in said.lower()
    assert "Restart bench" in devices.lost_label.text()

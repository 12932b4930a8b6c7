"""The bench process killed under the window (kill -9 while the stream and the live
reconstruction run): the window says so in an operator's words, reaps the process,
disables every device's commands and offers one action, Restart bench, which works."""

from __future__ import annotations

import os
import signal

import pytest

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs SIGKILL")


def _zombie_or_running(pid: int) -> bool:
    """Whether ``pid`` still has a process table entry (running or a zombie)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return bool(f.read())
    except FileNotFoundError:
        return False


def test_bench_killed_is_said_reaped_and_restarted(window, wait, qtbot,
                                                   psf_file):
    from PySide6.QtCore import Qt

    from gui.messages import how_it_ended

    session, devices, live = window.session, window.devices, window.live
    live.psf.setText(psf_file)
    live.depth.setEditText("")
    live.dark.setText("")
    live.method.setCurrentText("wiener")
    live.device.setCurrentText("cpu")
    job = live.start_reconstruction()  # the stream starts with it
    wait(lambda: job.done and live._shown_recon >= 0, 120.0, "the live reconstruction")
    assert session.streaming and live.live is not None, live.error.text()
    recon_pid = live.live._child.pid
    pid = session.service._manager._process.pid
    assert not devices.lost_box.isVisible()

    os.kill(pid, signal.SIGKILL)
    wait(lambda: devices.lost_box.isVisible(), 60.0, "the window to notice the bench ended")

    said = devices.lost_label.text()
    assert "bench process stopped" in said and how_it_ended(-signal.SIGKILL) in said
    assert "SIGKILL" in said and "Restart bench" in said
    assert "Errno" not in said and "reconnect()" not in said
    log_text = window.log_pane.text.toPlainText()
    assert "bench process stopped" in log_text
    assert not _zombie_or_running(pid), "the killed bench process was left a zombie"
    assert not session.connected and not session.streaming
    # one action: Restart bench; the devices' own commands are off while the bench is down
    assert devices.restart_button.isVisible() and devices.restart_button.isEnabled()
    assert not devices.connect_button.isVisible()
    assert devices.boxes, "the devices' boxes went away instead of showing the bench down"
    for box in devices.boxes.values():
        assert not box.reconnect_button.isEnabled()
        assert "bench process stopped" in box.state.text()
    assert not live.start_button.isEnabled()
    # the live reconstruction is stopped with the bench, its process ended (and reaped)
    assert live.live is None and live.recon_button.text() == "Start reconstruction"
    wait(lambda: not _zombie_or_running(recon_pid), 60.0,
         "the live reconstruction's process to end")

    qtbot.mouseClick(devices.restart_button, Qt.MouseButton.LeftButton)
    wait(lambda: session.connected and not devices.lost_box.isVisible(), 120.0,
         "Restart bench to open the bench again")
    assert session.lost is None
    assert set(devices.boxes) == set(session.devices)
    for box in devices.boxes.values():
        assert box.isEnabled() and box.reconnect_button.isEnabled()
    box = devices.boxes["camera"]
    job = box.reconnect()
    wait(lambda: not job.running, 60.0, "the camera's Reconnect")
    assert box.error.text() == "", box.error.text()
    assert devices.connect_button.isVisible()
    assert devices.state.text().startswith(f"{len(devices.boxes)} devices: "
                                           f"{len(devices.boxes)} open")


def test_connection_errors_read_as_the_bench_stopped():
    from gui.workers import readable_error

    text = readable_error(ConnectionRefusedError(111, "Connection refused"))
    assert "Errno" not in text and "bug" not in text
    assert "bench process" in text and "Restart bench" in text

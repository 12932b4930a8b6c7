"""The live reconstruction's process killed (kill -9) while it runs: the panel says
how it ended above the views (wrapped, and in the log), not under the image, and its
button is back to Start reconstruction; the raw stream goes on."""

from __future__ import annotations

import os
import signal

import pytest

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs SIGKILL")


def test_a_killed_live_reconstruction_is_said_and_reset(window, wait, psf_file):
    from gui.messages import how_it_ended

    live, session = window.live, window.session
    live.psf.setText(psf_file)
    live.depth.setEditText("")
    live.dark.setText("")
    live.method.setCurrentText("wiener")
    live.device.setCurrentText("cpu")
    job = live.start_reconstruction()
    wait(lambda: job.done, 120, "the live reconstruction to build")
    assert live.live is not None, live.error.text()
    assert live.recon_button.text() == "Stop reconstruction"
    wait(lambda: live._shown_recon >= 0, 120, "a reconstruction")
    pid = live.live._child.pid

    os.kill(pid, signal.SIGKILL)
    wait(lambda: live.live is None, 60, "the panel to notice the process ended")

    assert live.recon_button.text() == "Start reconstruction"
    assert live.recon_button.isEnabled()
    said = live.error.text()
    assert "live reconstruction stopped: " in said and how_it_ended(-signal.SIGKILL) in said
    assert "Start reconstruction" in said and "exit status None" not in said
    assert live.error.wordWrap()
    # the line under the image stays one short line; the message is above the views
    assert len(live.recon_stats.text()) < 80, live.recon_stats.text()
    assert "SIGKILL" in window.log_pane.text.toPlainText()
    first = session.latest_frame().index
    wait(lambda: session.latest_frame().index > first + 2, 60, "more raw frames")
    job = session.stream_job(False)
    wait(lambda: job.done and not session.streaming, 60, "the stream to stop")

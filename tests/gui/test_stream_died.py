"""A live stream whose camera goes silent (no error, no frame) ends as a stream that
died, in the real window (issue 67: *Stop stream* stayed shown after the stream died):
one operator's line in the log, the button back to *Start stream*, the raw view's line
saying the stream stopped and why; then it starts again. Waits on the window, not on
the clock: the silence bound is made short once the frames flow."""

from __future__ import annotations

import pytest


# -- jobs the bench process runs in this test (imported there by name) -------------------
def silence_camera(ctx, *, floor_s: float) -> None:
    """The camera delivers nothing from now on (every frame lost, no error), and the
    stream's silence floor is ``floor_s``."""
    ctx.bench.camera.faults.drop_frames(probability=1.0)
    ctx.host.stream_silence_floor_s = floor_s


def camera_back(ctx) -> None:
    """The camera delivers again; the silence floor is the default."""
    from instrument.bench.bench_host import STREAM_SILENCE_FLOOR_S

    ctx.bench.camera.faults.clear()
    ctx.host.stream_silence_floor_s = STREAM_SILENCE_FLOOR_S


JOBS = {"silence_camera": silence_camera, "camera_back": camera_back}


@pytest.fixture(scope="module")
def jobs_registered():
    """This module's jobs among those the window's bench process runs (before the
    window starts it)."""
    from gui.session import BENCH_JOBS

    BENCH_JOBS.update(JOBS)
    yield
    for name in JOBS:
        BENCH_JOBS.pop(name, None)


def test_a_silent_camera_puts_the_button_back_and_says_why(jobs_registered, window, wait,
                                                          qtbot):
    from PySide6.QtCore import Qt

    session, live = window.session, window.live
    window.docks["Live view"].raise_()
    qtbot.mouseClick(live.start_button, Qt.MouseButton.LeftButton)
    wait(lambda: live._shown_raw >= 0 and live.start_button.text() == "Stop stream", 60.0,
         "frames in the live view")
    assert session.streaming
    lines_before = window.log_pane.text.toPlainText().count("camera stream stopped")

    session.run_on_bench("silence_camera", {"floor_s": 0.2})
    wait(lambda: live.start_button.text() == "Start stream", 60.0,
         "the button to go back to Start stream")
    assert not session.streaming
    wait(lambda: "stream stopped" in live.raw_stats.text(), 10.0,
         "the raw view's line to say the stream stopped")
    shown = live.raw_stats.text()
    assert shown.startswith("camera: stream stopped: no frame from the camera for "), shown
    assert "(the last)" in shown
    wait(lambda: "camera stream stopped" in window.log_pane.text.toPlainText(), 10.0,
         "the log's line")
    log_text = window.log_pane.text.toPlainText()
    assert log_text.count("camera stream stopped") == lines_before + 1  # one line
    line = next(t for t in log_text.splitlines() if "camera stream stopped" in t)
    assert "check the camera's cable and power" in line and "()" not in line
    assert "Traceback" not in log_text

    session.run_on_bench("camera_back")
    qtbot.mouseClick(live.start_button, Qt.MouseButton.LeftButton)
    shown_at = live._shown_raw
    wait(lambda: live._shown_raw > shown_at and live.start_button.text() == "Stop stream",
         60.0, "frames again after Start stream")
    assert session.streaming
    wait(lambda: not live.raw_stats.text().startswith("camera: stream stopped"), 10.0,
         "the raw view's line to show the stream again")
    job = live.toggle_stream()
    wait(lambda: job.done and not session.streaming, 60.0, "the stream to stop")


class _NoResult:
    """A live reconstruction that finishes no frame (its process starved)."""

    def stats(self) -> dict:
        return {"running": True, "reconstructed": 0, "skipped": 40, "errors": 0,
                "method": "admm", "iterations": 5, "fps": 0.0, "latency_median_s": None,
                "last_error": ""}

    def latest(self):
        return None


def test_a_reconstruction_finishing_no_frame_is_not_said_to_wait_for_frames(window, wait):
    """Seen in the soak at load 34: 'no new result for 512 s (waiting for frames)' while
    the camera's frames arrived and the reconstruction's process got no time."""
    session, live = window.session, window.live
    window.docks["Live view"].raise_()
    job = live.toggle_stream()
    wait(lambda: job.done and session.streaming, 60.0, "the stream to start")
    live.live = _NoResult()
    try:
        wait(lambda: "frames since has finished" in live.recon_stats.text(), 60.0,
             "the reconstruction's line to say the frames since found no result")
        text = live.recon_stats.text()
        assert "no new result for" in text and "busy machine" in text, text
        assert "waiting for frames" not in text, text
    finally:
        live.live = None
        job = live.toggle_stream()
        wait(lambda: job.done and not session.streaming, 60.0, "the stream to stop")


def hold_camera(ctx) -> str:
    """Hold the camera until stopped (a hang guard of 10 minutes)."""
    import time

    deadline = time.monotonic() + 600.0
    while not ctx.stop.is_set() and time.monotonic() < deadline:
        ctx.stop.wait(0.05)
    return "stopped" if ctx.stop.is_set() else "timed out"


def _holding_camera():
    from instrument.bench.bench_jobs import holding

    return holding("camera")(hold_camera)


JOBS["hold_camera"] = _holding_camera()


def test_a_job_holding_the_camera_is_shown_on_the_live_view_until_it_gives_it_back(
        jobs_registered, window, wait):
    session, live = window.session, window.live
    window.docks["Live view"].raise_()
    job = live.toggle_stream()
    wait(lambda: job.done and session.streaming and live.start_button.text() == "Stop stream",
         60.0, "the stream to start")
    handle = session.service.start_job("hold_camera")
    wait(lambda: live.raw_stats.text().startswith("camera taken by job "), 60.0,
         "the raw view's line to say a job took the camera")
    shown = live.raw_stats.text()
    assert "(hold_camera) of the window" in shown and "comes back when it ends" in shown
    assert live.start_button.text() == "Stop stream"  # the live view comes back by itself
    shown_at = live._shown_raw
    handle.stop()
    assert handle.result(timeout_s=600.0) == "stopped"
    wait(lambda: live._shown_raw > shown_at and live.raw_stats.text().startswith("camera: "),
         60.0, "the live view back with new frames")
    job = live.toggle_stream()
    wait(lambda: job.done and not session.streaming, 60.0, "the stream to stop")

"""Every job's start, outcome and output path is a line of the log pane (a recording's
completion, a batch's end, an alignment's result), and the batch shows an ETA."""

from __future__ import annotations

import numpy as np
import pytest

from tests.gui.test_fixes import _video_run


def _lines_since(pane, n: int) -> str:
    return "\n".join(pane.lines[n:])


def test_a_recording_and_a_batch_log_start_outcome_and_path(window, wait, tmp_path):
    pane, panel = window.log_pane, window.record
    n = len(pane.lines)
    path = str(tmp_path / "video.zarr")
    panel.out.setText(path)
    panel.frames.setText("5")
    panel.seconds.setText("")
    job = panel.start_recording()
    wait(lambda: job.done, 60, "the recording")
    wait(lambda: f"5 frames written to {path}" in _lines_since(pane, n), 10, "the log line")
    log = _lines_since(pane, n)
    assert f"recording started: 5 frames into {path}" in log
    rng = np.random.default_rng(0)
    _video_run(tmp_path / "v.zarr", n=3,
               image=lambda i: rng.integers(100, 4000, (64, 80)).astype(np.uint16))
    psf = np.zeros((64, 80), np.float32)
    psf[30:34, 38:42] = 100.0
    np.save(tmp_path / "psf.npy", psf)
    panel.run_path.setText(str(tmp_path / "v.zarr"))
    for flag, text in (("--psf", str(tmp_path / "psf.npy")), ("--frames", "0:3"),
                       ("--workers", "1"), ("--dark", "0")):
        panel.batch_fields[flag].setText(text)
    panel.batch_fields["--method"].setCurrentText("wiener")
    job = panel.start_batch()
    wait(lambda: job.done, 600, "the batch reconstruction")
    assert panel.batch_result is not None, panel.batch_error.text()
    wait(lambda: "batch reconstruction finished" in _lines_since(pane, n), 10, "the log line")
    log = _lines_since(pane, n)
    assert f"batch reconstruction started: {tmp_path / 'v.zarr'} with wiener" in log
    assert f"finished: product recon_wiener of {tmp_path / 'v.zarr'}, 3 frames" in log


def test_the_batch_shows_an_eta_from_the_frames_rate(window, monkeypatch):
    """The batch's reports: the total before the workers start, then one per frame. The
    ETA follows the rate since the first frame (the workers' start left out). The
    clock is the test's, stopped: the ETA is computed and read at the same instant (a
    wall clock let a loaded host's delay between the two count down the ETA)."""
    import time

    import gui.panels.common
    import gui.panels.record

    now = 1000.0

    class Clock:  # the module ``time`` with the test's monotonic clock
        def __getattr__(self, name):
            return getattr(time, name)

        @staticmethod
        def monotonic() -> float:
            return now

    monkeypatch.setattr(gui.panels.record, "time", Clock())
    monkeypatch.setattr(gui.panels.common, "time", Clock())
    panel = window.record
    progress = panel.batch_progress
    progress.start(0)
    panel._rate_from = None
    panel.on_batch_progress({"kind": "start", "total": 40, "run": "v.zarr"})
    assert progress.maximum() == 40 and "starting the workers" in progress.label.text()
    panel.on_batch_progress({"done": 1, "total": 40, "skipped": 0, "elapsed_s": 20.0,
                             "fps": 0.05})
    assert "ETA 13 min" in progress.label.text()  # 39 frames at the first frame's rate
    panel._rate_from = (now - 2.0, 1)  # frame 1 two seconds ago
    panel.on_batch_progress({"done": 11, "total": 40, "skipped": 0, "elapsed_s": 22.0,
                             "fps": 0.5})
    eta = progress.eta_s()
    assert eta == pytest.approx(5.8), progress.label.text()  # 29 frames at 5/s, not 58 s
    assert "ETA -" not in progress.label.text()
    progress.finish()


def test_an_alignment_logs_its_result_pose_and_record(window, wait):
    pane, al = window.log_pane, window.alignment
    n = len(pane.lines)
    al._out = "out/align/mask-test.align"
    al.on_report({"steps": {"verify": {"passed": True}},
                  "summary": {"translation_px": (0.1, -0.2), "theta_rad": 0.001,
                              "captures": 30, "stage_pose": {"x": 0.08, "rotation": 0.13}}})
    wait(lambda: "mask alignment" in _lines_since(pane, n), 10, "the log line")
    log = _lines_since(pane, n)
    assert "mask alignment completed (passed)" in log
    assert "mask stage stays at x +0.0800 mm, rotation +0.1300 deg" in log
    assert "record out/align/mask-test.align" in log

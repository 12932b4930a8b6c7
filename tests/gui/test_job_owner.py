"""A job whose widget is deleted while it runs (a window closed with work in flight)
delivers nothing to that widget's slots: they would touch deleted widgets and raise
``RuntimeError`` inside Qt's event loop. The job still ends (``done``) and is let go."""

from __future__ import annotations

import threading

import numpy as np
import shiboken6
from PySide6.QtCore import QCoreApplication, QEvent


def _delete_now(qapp, widget) -> None:
    """Delete ``widget`` now, and only it: flushing every deferred deletion
    (``sendPostedEvents(None, ...)``) also ran those of the earlier tests' windows in
    this process, which took over 10 s in CI (the held read timed out first)."""
    widget.deleteLater()
    QCoreApplication.sendPostedEvents(widget, QEvent.Type.DeferredDelete)
    assert not shiboken6.isValid(widget)


def test_a_results_panel_deleted_mid_read_gets_no_result(qapp, wait, tmp_path, monkeypatch):
    from gui.panels import results
    from gui.panels.results import ResultsPanel

    path = tmp_path / "image.npy"
    np.save(path, np.ones((8, 8), np.float32))
    gate, real = threading.Event(), results.read_result

    def held(p):  # the read ends only after the panel is gone
        assert gate.wait(120.0)  # set right after the deletion
        return real(p)

    monkeypatch.setattr(results, "read_result", held)
    panel = ResultsPanel()
    errors: list = []
    job = panel.open(str(path))
    job.succeeded.connect(lambda result: errors.append("succeeded reached a deleted panel"))
    job.finished.connect(lambda: errors.append("finished reached a deleted panel"))
    _delete_now(qapp, panel)
    gate.set()
    wait(lambda: job.done, 10.0, "the read's end")
    assert job.cancelled and job.result is not None and not errors


def test_a_job_without_an_owner_or_with_a_live_one_delivers_everything(qapp, wait):
    from PySide6.QtWidgets import QWidget

    from gui.workers import Job

    owner = QWidget()
    got: list = []
    for kw in ({}, {"owner": owner}):
        job = Job(lambda job: (job.report(1), 7)[1], name="owned", **kw)
        job.progress.connect(lambda v: got.append(("progress", v)))
        job.succeeded.connect(lambda v: got.append(("succeeded", v)))
        job.finished.connect(lambda: got.append(("finished",)))
        job.start()
        wait(lambda job=job: job.done, 10.0, "the job's end")
    assert got == [("progress", 1), ("succeeded", 7), ("finished",)] * 2
    failing = Job(lambda job: 1 / 0, name="owned-fails", owner=owner)
    failed: list = []
    failing.failed.connect(failed.append)
    failing.start()
    wait(lambda: failing.done, 10.0, "the failing job's end")
    assert failed and "division" in failed[0]
    owner.deleteLater()

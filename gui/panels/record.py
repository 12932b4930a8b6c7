"""Record panel: start / stop a video recording (frames written, MB/s, dropped), and
batch reconstruction of a recorded run (progress, cancel).

Recording is :func:`instrument.video.record_video` on a worker (the camera streams
into a ring, every frame goes to the recorder; the live view keeps showing the newest
frame and, if it runs, the live reconstruction); Stop sets its ``stop`` event, and
the run keeps what was recorded. Batch reconstruction is
:func:`instrument.batch.reconstruct_run` on a worker (dask), cancelled through its
``cancel`` event; its results are a product of the run, shown in the Results panel.
"""

from __future__ import annotations

import datetime as _dt
import threading

from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QComboBox,
    QGridLayout,
    QGroupBox,
    QLabel,
    QLineEdit,
    QProgressBar,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from recon.solvers import METHODS

from ..session import Session
from ..workers import Job
from .common import error_label

__all__ = ["RecordPanel"]



def _number(text: str, what: str, kind=float):
    text = text.strip()
    if not text:
        return None
    try:
        return kind(text)
    except ValueError:
        raise ValueError(f"{what} {text!r}: give a number or leave it empty") from None


class _LiveTap:
    """What :func:`instrument.video.record_video` offers every frame to: the session's
    display (newest frame) and the live panel's reconstruction, if running."""

    def __init__(self, session: Session, live) -> None:
        self.session, self.live = session, live

    def start(self) -> None:  # the live reconstruction, if any, runs already
        pass

    def stop(self, timeout_s: float = 5.0) -> None:
        pass

    def offer(self, frame) -> None:
        self.session.show_frame(frame)
        if self.live is not None:
            self.live.offer(frame)

    def stats(self) -> dict | None:
        return None if self.live is None else self.live.stats()


class RecordPanel(QWidget):
    """See the module docstring.

    Signals
    -------
    result_ready(str, str)
        ``(run, product)`` of a finished batch reconstruction (the Results panel shows
        it).
    """

    result_ready = Signal(str, str)

    def __init__(self, session: Session, live_panel=None, parent=None) -> None:
        super().__init__(parent)
        self.session = session
        self.live_panel = live_panel
        self.record_job: Job | None = None
        self.batch_job: Job | None = None
        self.stop_event = threading.Event()
        self.last_run: str | None = None
        self.summary: dict | None = None
        self.batch_result: dict | None = None
        layout = QVBoxLayout(self)
        rec = QGroupBox("record a video")
        g = QGridLayout(rec)
        g.addWidget(QLabel("run store:"), 0, 0)
        self.out = QLineEdit()
        self.out.setPlaceholderText("default out/runs/video-TIME.zarr")
        g.addWidget(self.out, 0, 1, 1, 3)
        g.addWidget(QLabel("frames:"), 1, 0)
        self.frames = QLineEdit("100")
        self.frames.setToolTip("number of frames (or give seconds instead)")
        g.addWidget(self.frames, 1, 1)
        g.addWidget(QLabel("or seconds (s):"), 1, 2)
        self.seconds = QLineEdit()
        g.addWidget(self.seconds, 1, 3)
        g.addWidget(QLabel("frame rate (Hz):"), 2, 0)
        self.fps = QLineEdit()
        self.fps.setPlaceholderText("camera's setting")
        g.addWidget(self.fps, 2, 1)
        g.addWidget(QLabel("exposure (s):"), 2, 2)
        self.exposure = QLineEdit()
        self.exposure.setPlaceholderText("camera's setting")
        g.addWidget(self.exposure, 2, 3)
        self.record_button = QPushButton("Start recording")
        self.record_button.clicked.connect(self.toggle_recording)
        g.addWidget(self.record_button, 3, 0)
        self.record_progress = QProgressBar()
        self.record_progress.setFormat("%v / %m frames written")
        g.addWidget(self.record_progress, 3, 1, 1, 3)
        self.counters = QLabel("not recording")
        self.counters.setWordWrap(True)
        g.addWidget(self.counters, 4, 0, 1, 4)
        self.record_error = error_label()
        g.addWidget(self.record_error, 5, 0, 1, 4)
        layout.addWidget(rec)
        batch = QGroupBox("batch reconstruction of a recorded run (dask)")
        b = QGridLayout(batch)
        b.addWidget(QLabel("run:"), 0, 0)
        self.run_path = QLineEdit()
        self.run_path.setPlaceholderText("RUN.zarr (default: the last recording)")
        b.addWidget(self.run_path, 0, 1, 1, 3)
        self.batch_fields: dict[str, QWidget] = {}
        method = QComboBox()
        method.addItems(METHODS)
        method.setCurrentText("admm")
        iterations = QLineEdit("100")
        rows = (("--psf", "PSF (image, stack or run):", QLineEdit(), ""),
                ("--depth", "depth (mm):", QLineEdit(), "stack plane"),
                ("--method", "method:", method, ""),
                ("--iterations", "iterations:", iterations, ""),
                ("--frames", "frames (A:B):", QLineEdit(), "all"),
                ("--workers", "dask workers:", QLineEdit(), "one per core"),
                ("--dark", "dark (DN or dark run):", QLineEdit(), "auto"),
                ("--dff", "ΔF/F baseline percentile:", QLineEdit(), "none (e.g. 20)"))
        for i, (flag, label, widget, hint) in enumerate(rows):
            if isinstance(widget, QLineEdit):
                widget.setPlaceholderText(hint)
            widget.setObjectName(f"batch{flag}")
            self.batch_fields[flag] = widget
            b.addWidget(QLabel(label), 1 + i // 2, 2 * (i % 2))
            b.addWidget(widget, 1 + i // 2, 2 * (i % 2) + 1)
        self.batch_button = QPushButton("Reconstruct run")
        self.batch_button.clicked.connect(self.toggle_batch)
        b.addWidget(self.batch_button, 6, 0)
        self.batch_progress = QProgressBar()
        self.batch_progress.setFormat("%v / %m frames reconstructed")
        b.addWidget(self.batch_progress, 6, 1, 1, 3)
        self.batch_status = QLabel("")
        self.batch_status.setWordWrap(True)
        b.addWidget(self.batch_status, 7, 0, 1, 4)
        self.batch_error = error_label()
        b.addWidget(self.batch_error, 8, 0, 1, 4)
        layout.addWidget(batch)
        layout.addStretch(1)

    # -- recording -----------------------------------------------------------------------
    @property
    def recording(self) -> bool:
        return self.record_job is not None and self.record_job.running

    def toggle_recording(self) -> None:
        if self.recording:
            self.stop_event.set()
            self.record_button.setText("Stopping ...")
        else:
            self.start_recording()

    def start_recording(self) -> Job | None:
        """Record into a new run store on a worker (:func:`gui.jobs.record`)."""
        from ..jobs import record

        self.record_error.setText("")
        if not self.session.connected:
            self.record_error.setText("no bench is connected; press Connect on the Devices "
                                      "panel")
            return None
        try:
            frames = _number(self.frames.text(), "frames", int)
            seconds = _number(self.seconds.text(), "seconds")
            fps = _number(self.fps.text(), "frame rate")
            exposure_s = _number(self.exposure.text(), "exposure")
        except ValueError as exc:
            self.record_error.setText(str(exc))
            return None
        if seconds is not None:
            frames = None
        out = self.out.text().strip() or f"out/runs/video-{_dt.datetime.now():%Y%m%d-%H%M%S}.zarr"
        self.stop_event = threading.Event()
        tap = _LiveTap(self.session, getattr(self.live_panel, "live", None))
        self.record_progress.setRange(0, frames or 0)
        self.record_progress.setValue(0)
        self.counters.setText(f"recording into {out} ...")
        self.record_job = Job(record, self.session, out, self.stop_event, frames=frames,
                              seconds=seconds, fps=fps, exposure_s=exposure_s, tap=tap,
                              name="record-video")
        self.record_job.progress.connect(self.on_record_progress)
        self.record_job.succeeded.connect(self.on_recorded)
        self.record_job.failed.connect(self.on_record_failed)
        self.record_button.setText("Stop recording")
        self.last_run = out
        return self.record_job.start()

    def on_record_progress(self, p: dict) -> None:
        self.record_progress.setValue(int(p.get("recorded", 0)))
        self.counters.setText(
            f"{p.get('elapsed_s', 0):.1f} s: written {p.get('recorded', 0)} frames, "
            f"{p.get('write_mb_s', 0):.1f} MB/s, camera {p.get('fps', 0):.1f} fps; dropped by "
            f"the camera {p.get('dropped_by_camera', 0)}, skipped by the ring "
            f"{p.get('skipped_by_ring', 0)}, lost by the recorder {p.get('lost_by_recorder', 0)}")

    def on_recorded(self, summary: dict) -> None:
        self.summary = summary
        self.record_button.setText("Start recording")
        self.record_progress.setMaximum(max(int(summary.get("frames_requested", 0)), 1))
        self.record_progress.setValue(int(summary.get("recorded", 0)))
        lost = int(summary.get("lost_by_recorder", 0)) + int(summary.get("dropped_by_camera", 0))
        self.counters.setText(
            f"{summary['status']}: {summary.get('recorded', 0)} frames written to "
            f"{summary['path']} at {summary.get('write_mb_s', 0):.1f} MB/s "
            f"({summary.get('fps', 0):.1f} fps); "
            + ("no frame lost" if not lost else f"{lost} frame(s) lost (see runs show)"))
        self.run_path.setText(summary["path"])

    def on_record_failed(self, text: str) -> None:
        self.record_button.setText("Start recording")
        self.record_error.setText(f"recording stopped: {text}\nThe frames recorded so far are "
                                  "kept in the run.")

    # -- batch ---------------------------------------------------------------------------
    def toggle_batch(self) -> None:
        if self.batch_job is not None and self.batch_job.running:
            self.batch_job.cancel()
            self.batch_button.setText("Cancelling ...")
        else:
            self.start_batch()

    def start_batch(self) -> Job | None:
        """Reconstruct the frames of a run on a worker (:func:`gui.jobs.batch_reconstruct`)."""
        from ..jobs import batch_reconstruct

        self.batch_error.setText("")
        run = self.run_path.text().strip() or self.last_run
        if not run:
            self.batch_error.setText("give the run to reconstruct (RUN.zarr)")
            return None
        options = {flag: w.currentText() if isinstance(w, QComboBox) else w.text().strip()
                   for flag, w in self.batch_fields.items()}
        self.batch_progress.setValue(0)
        self.batch_status.setText(f"reconstructing {run} ...")
        self.batch_job = Job(batch_reconstruct, run, options, name="batch-recon")
        self.batch_job.progress.connect(self.on_batch_progress)
        self.batch_job.succeeded.connect(lambda result: self.on_batch_done(run, result))
        self.batch_job.failed.connect(self.on_batch_failed)
        self.batch_button.setText("Cancel")
        return self.batch_job.start()

    def on_batch_progress(self, p: dict) -> None:
        self.batch_progress.setMaximum(int(p["total"]))
        self.batch_progress.setValue(int(p["done"]))
        self.batch_status.setText(f"{p['done']} of {p['total']} frames ({p['skipped']} done "
                                  f"before), {p['fps']:.2f} frames/s, {p['elapsed_s']:.0f} s")

    def on_batch_done(self, run: str, result: dict) -> None:
        self.batch_result = result
        self.batch_button.setText("Reconstruct run")
        if result.get("cancelled"):
            self.batch_status.setText(
                f"cancelled: {result['reconstructed']} frames reconstructed and kept in "
                f"{result['product']}; press Reconstruct run again to finish")
            return
        self.batch_status.setText(
            f"{result['product']}: {result['reconstructed']} frames reconstructed, "
            f"{result['skipped']} already done, {result['seconds']:.1f} s "
            f"({result['fps']:.2f} frames/s, {result['workers'] or 0} workers)")
        self.result_ready.emit(run, result["product"])

    def on_batch_failed(self, text: str) -> None:
        self.batch_button.setText("Reconstruct run")
        self.batch_error.setText(text)

    def cancel(self) -> None:
        """Stop a recording and cancel a batch reconstruction (window closing)."""
        self.stop_event.set()
        if self.batch_job is not None:
            self.batch_job.cancel()

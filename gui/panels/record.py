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
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from ..session import Session
from ..workers import Job
from .common import error_label

__all__ = ["RecordPanel"]

#: Methods offered for batch reconstruction.
BATCH_METHODS = ("admm", "fista", "gd", "wiener")


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
    result_ready(str)
        A run whose batch reconstruction finished (the Results panel opens it).
    """

    result_ready = Signal(str)

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
        b.addWidget(QLabel("PSF (image, stack or run):"), 1, 0)
        self.psf = QLineEdit()
        b.addWidget(self.psf, 1, 1, 1, 3)
        b.addWidget(QLabel("depth (mm):"), 2, 0)
        self.depth = QLineEdit()
        self.depth.setPlaceholderText("stack plane")
        b.addWidget(self.depth, 2, 1)
        b.addWidget(QLabel("method:"), 2, 2)
        self.method = QComboBox()
        self.method.addItems(BATCH_METHODS)
        b.addWidget(self.method, 2, 3)
        b.addWidget(QLabel("iterations:"), 3, 0)
        self.iterations = QSpinBox()
        self.iterations.setRange(1, 5000)
        self.iterations.setValue(100)
        b.addWidget(self.iterations, 3, 1)
        b.addWidget(QLabel("dask workers:"), 3, 2)
        self.workers = QLineEdit()
        self.workers.setPlaceholderText("local default")
        b.addWidget(self.workers, 3, 3)
        b.addWidget(QLabel("frames (A:B):"), 4, 0)
        self.frame_range = QLineEdit()
        self.frame_range.setPlaceholderText("all")
        b.addWidget(self.frame_range, 4, 1)
        self.batch_button = QPushButton("Reconstruct run")
        self.batch_button.clicked.connect(self.toggle_batch)
        b.addWidget(self.batch_button, 5, 0)
        self.batch_progress = QProgressBar()
        self.batch_progress.setFormat("%v / %m frames reconstructed")
        b.addWidget(self.batch_progress, 5, 1, 1, 3)
        self.batch_status = QLabel("")
        self.batch_status.setWordWrap(True)
        b.addWidget(self.batch_status, 6, 0, 1, 4)
        self.batch_error = error_label()
        b.addWidget(self.batch_error, 7, 0, 1, 4)
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
        """Record into a new run store on a worker (camera claimed for the recording)."""
        from instrument.video import record_video

        self.record_error.setText("")
        if not self.session.connected:
            self.record_error.setText("no bench is connected; press Connect on the Devices "
                                      "panel")
            return None
        try:
            frames = _number(self.frames.text(), "frames", int)
            seconds = _number(self.seconds.text(), "seconds")
            options = {"fps": _number(self.fps.text(), "frame rate"),
                       "exposure_s": _number(self.exposure.text(), "exposure")}
            if seconds is not None:
                frames = None
            self.session.claim_camera("the video recording")
        except Exception as exc:  # noqa: BLE001 (shown, never raised)
            from ..workers import readable_error

            self.record_error.setText(readable_error(exc))
            return None
        out = self.out.text().strip() or f"out/runs/video-{_dt.datetime.now():%Y%m%d-%H%M%S}.zarr"
        self.stop_event = threading.Event()
        live = getattr(self.live_panel, "live", None)
        tap = _LiveTap(self.session, live)
        self.record_progress.setRange(0, frames or 0)
        self.record_progress.setValue(0)
        self.counters.setText(f"recording into {out} ...")

        def record(job: Job) -> dict:
            try:
                return record_video(self.session.bench, out, frames=frames, seconds=seconds,
                                    stop=self.stop_event, on_progress=job.report,
                                    progress_every_s=0.25, live=tap,
                                    **{k: v for k, v in options.items() if v is not None})
            finally:
                self.session.release_camera("the video recording")

        self.record_job = Job(record, name="record-video")
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
        """Reconstruct every frame of a run on a worker
        (:func:`instrument.batch.reconstruct_run`)."""
        from instrument.batch import reconstruct_run

        self.batch_error.setText("")
        run = self.run_path.text().strip() or self.last_run
        if not run:
            self.batch_error.setText("give the run to reconstruct (RUN.zarr)")
            return None
        try:
            depth = _number(self.depth.text(), "depth")
            workers = _number(self.workers.text(), "dask workers", int)
        except ValueError as exc:
            self.batch_error.setText(str(exc))
            return None
        frames = self.frame_range.text().strip() or None
        psf = self.psf.text().strip()
        method, iterations = self.method.currentText(), self.iterations.value()
        self.batch_progress.setValue(0)
        self.batch_status.setText(f"reconstructing {run} ...")

        def work(job: Job) -> dict:
            return reconstruct_run(run, psf, depth_mm=depth, method=method,
                                   iterations=iterations, frames=frames, workers=workers,
                                   on_progress=job.report, cancel=job.cancel_event)

        self.batch_job = Job(work, name="batch-recon")
        self.batch_job.progress.connect(self.on_batch_progress)
        self.batch_job.succeeded.connect(lambda result: self.on_batch_done(run, result))
        self.batch_job.failed.connect(self.on_batch_failed)
        self.batch_button.setText("Cancel")
        return self.batch_job.start()

    def on_batch_progress(self, p: dict) -> None:
        total = int(p.get("total", p.get("frames_total", 0)) or 0)
        done = int(p.get("done", p.get("frames_done", 0)) or 0)
        if total:
            self.batch_progress.setMaximum(total)
        self.batch_progress.setValue(done)
        rate = p.get("frames_per_s")
        self.batch_status.setText(f"{done} of {total} frames" +
                                  ("" if rate is None else f", {rate:.2f} frames/s"))

    def on_batch_done(self, run: str, result: dict) -> None:
        self.batch_result = result
        self.batch_button.setText("Reconstruct run")
        status = result.get("status", "complete")
        self.batch_status.setText(f"{status}: " + ", ".join(
            f"{k} {v}" for k, v in result.items() if isinstance(v, int | float | str)
            and k != "status"))
        if status == "complete":
            self.result_ready.emit(run)

    def on_batch_failed(self, text: str) -> None:
        self.batch_button.setText("Reconstruct run")
        self.batch_error.setText(text)

    def cancel(self) -> None:
        """Stop a recording and cancel a batch reconstruction (window closing)."""
        self.stop_event.set()
        if self.batch_job is not None:
            self.batch_job.cancel()

"""Live view: the raw camera frame (histogram, saturation overlay, fps) beside the live
reconstruction (its own fps, latency, skipped and error counters).

The session's stream hands every frame to :class:`instrument.live.LiveReconstruction`
(Wiener preview or warm-started ADMM with a few iterations per frame; PSF from a file
or a run store, :func:`gui.jobs.build_live`); a 20 Hz timer shows the newest frame
and the newest reconstruction and the counters. Nothing here waits on the camera or
the solver.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QTimer
from PySide6.QtWidgets import (
    QComboBox,
    QFileDialog,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from ..session import CameraBusy, Session
from ..workers import Job, readable_error
from .common import FrameView, error_label

__all__ = ["LivePanel"]

#: Consumer name of the live reconstruction on the session's stream.
CONSUMER = "live-reconstruction"


class LivePanel(QWidget):
    """See the module docstring."""

    def __init__(self, session: Session, parent=None) -> None:
        super().__init__(parent)
        self.session = session
        self.live = None
        self.job: Job | None = None
        self._shown_raw = -1
        self._shown_recon = -1
        self._saturation_shown = False
        layout = QVBoxLayout(self)
        controls = QGridLayout()
        self.start_button = QPushButton("Start stream")
        self.start_button.clicked.connect(self.toggle_stream)
        controls.addWidget(self.start_button, 0, 0)
        controls.addWidget(QLabel("PSF (image, stack or run):"), 0, 1)
        self.psf = QLineEdit()
        self.psf.setPlaceholderText("e.g. out/runs/psf-sweep-....zarr")
        controls.addWidget(self.psf, 0, 2, 1, 3)
        browse = QPushButton("Browse...")
        browse.clicked.connect(self._browse)
        controls.addWidget(browse, 0, 5)
        controls.addWidget(QLabel("depth (mm):"), 1, 1)
        self.depth = QLineEdit()
        self.depth.setPlaceholderText("stack plane; empty: single PSF")
        controls.addWidget(self.depth, 1, 2)
        controls.addWidget(QLabel("dark (DN or dark run):"), 1, 3)
        self.dark = QLineEdit()
        self.dark.setPlaceholderText("auto")
        controls.addWidget(self.dark, 1, 4)
        controls.addWidget(QLabel("method:"), 2, 1)
        self.method = QComboBox()
        self.method.addItems(["wiener", "admm"])
        self.method.currentTextChanged.connect(self._method_changed)
        controls.addWidget(self.method, 2, 2)
        controls.addWidget(QLabel("ADMM iterations per frame:"), 2, 3)
        self.iterations = QSpinBox()
        self.iterations.setRange(1, 50)
        self.iterations.setValue(5)
        self.iterations.valueChanged.connect(self._method_changed)
        controls.addWidget(self.iterations, 2, 4)
        self.recon_button = QPushButton("Start reconstruction")
        self.recon_button.clicked.connect(self.toggle_reconstruction)
        controls.addWidget(self.recon_button, 1, 5, 2, 1)
        layout.addLayout(controls)
        self.error = error_label()
        layout.addWidget(self.error)
        views = QHBoxLayout()
        left, right = QVBoxLayout(), QVBoxLayout()
        self.raw_view = FrameView("raw frame (DN)", histogram_hz=2.0)
        self.saturation = pg.ImageItem()
        self.raw_view.plot.addItem(self.saturation)
        self.saturation.setZValue(10)
        left.addWidget(self.raw_view, 1)
        self.raw_stats = QLabel("camera: not streaming")
        self.raw_stats.setWordWrap(True)
        left.addWidget(self.raw_stats)
        self.recon_view = FrameView("live reconstruction (upright)", histogram_hz=2.0)
        right.addWidget(self.recon_view, 1)
        self.recon_stats = QLabel("reconstruction: off")
        self.recon_stats.setWordWrap(True)
        right.addWidget(self.recon_stats)
        views.addLayout(left, 1)
        views.addLayout(right, 1)
        layout.addLayout(views, 1)
        self.timer = QTimer(self)
        self.timer.timeout.connect(self.refresh)
        self.timer.start(50)
        session.changed.connect(self._session_changed)
        self._session_changed()

    # -- controls ------------------------------------------------------------------------
    def _browse(self) -> None:
        path = QFileDialog.getExistingDirectory(self, "PSF run store") or \
            QFileDialog.getOpenFileName(self, "PSF image or stack")[0]
        if path:
            self.psf.setText(path)

    def _session_changed(self) -> None:
        streaming = self.session.streaming
        self.start_button.setText("Stop stream" if streaming else "Start stream")
        self.start_button.setEnabled(self.session.connected)
        self.recon_button.setEnabled(self.session.connected)
        if not self.session.connected and self.live is not None:
            self.stop_reconstruction()

    def toggle_stream(self) -> None:
        self.error.setText("")
        if self.session.streaming:
            self.session.stop_stream()
            return
        try:
            self.session.start_stream()
        except (CameraBusy, Exception) as exc:  # noqa: B014 (shown, never raised)
            self.error.setText(readable_error(exc))

    def toggle_reconstruction(self) -> None:
        if self.live is not None:
            self.stop_reconstruction()
        else:
            self.start_reconstruction()

    def start_reconstruction(self) -> Job | None:
        """Build the reconstruction on a worker (PSF loading, FFT plans), then start it
        on the stream (started too if it was not)."""
        from ..jobs import build_live

        self.error.setText("")
        depth_text = self.depth.text().strip()
        try:
            depth = float(depth_text) if depth_text else None
        except ValueError:
            self.error.setText(f"depth {depth_text!r}: give a number in mm, or leave it empty")
            return None
        self.recon_button.setEnabled(False)
        self.job = Job(lambda job: build_live(
            self.session, self.psf.text().strip(), depth_mm=depth,
            method=self.method.currentText(), iterations=self.iterations.value(),
            dark=self.dark.text()), name="build-live")
        self.job.succeeded.connect(self._live_ready)
        self.job.failed.connect(self.error.setText)
        self.job.finished.connect(lambda: self.recon_button.setEnabled(True))
        return self.job.start()

    def _live_ready(self, live) -> None:
        try:
            live.start()
            self.live = live
            self.session.add_consumer(CONSUMER, live.offer)
            if not self.session.streaming:
                self.session.start_stream()
        except Exception as exc:  # noqa: BLE001 (shown, never raised)
            self.error.setText(readable_error(exc))
        self.recon_button.setText("Stop reconstruction" if self.live else
                                  "Start reconstruction")

    def stop_reconstruction(self) -> None:
        """Detach the worker from the stream and stop it (it ends with its frame)."""
        self.session.remove_consumer(CONSUMER)
        live, self.live = self.live, None
        if live is not None:
            job = Job(lambda job: live.stop(timeout_s=10.0), name="stop-live")
            job.failed.connect(self.error.setText)
            self.job = job.start()
        self.recon_button.setText("Start reconstruction")

    def _method_changed(self, *_) -> None:
        if self.live is not None:
            try:
                self.live.set_method(self.method.currentText(), self.iterations.value())
            except Exception as exc:  # noqa: BLE001 (shown, never raised)
                self.error.setText(readable_error(exc))

    # -- display -------------------------------------------------------------------------
    def refresh(self) -> None:
        """Show the newest frame and reconstruction and the counters (timer slot; does
        nothing while the panel is hidden)."""
        from recon.io import scene_view

        if not self.isVisible():
            return
        frame = self.session.latest_frame()
        if frame is not None and frame.index != self._shown_raw:
            first = self._shown_raw < 0
            self._shown_raw = frame.index
            image = frame.image
            self.raw_view.setImage(image, autoLevels=first)
            cam = self.session.bench.camera if self.session.connected else None
            if cam is not None:
                sat = image >= 2 ** int(cam.bit_depth) - 1
                if sat.any() or self._saturation_shown:
                    overlay = np.zeros(image.shape + (4,), np.uint8)
                    overlay[sat] = (255, 0, 0, 255)
                    self.saturation.setImage(overlay, autoLevels=False)
                    self._saturation_shown = bool(sat.any())
        if frame is not None:
            sat = f"saturated {int(frame.saturated_pixels)} px (red)"
            if self.session.streaming:
                c = self.session.stream_counters()
                self.raw_stats.setText(
                    f"camera: {c['fps']:.1f} fps, frame {frame.index}, acquired "
                    f"{c['acquired']}, dropped {c['dropped']}, skipped by the ring "
                    f"{c['skipped']}; {sat}")
            elif self.session.camera_user is not None:
                self.raw_stats.setText(f"camera busy with {self.session.camera_user}: frame "
                                       f"{frame.index}; {sat}")
        if self.live is not None:
            s = self.live.stats()
            lat = "-" if s["latency_median_s"] is None else f"{1e3 * s['latency_median_s']:.0f}"
            method = s["method"] + ("" if s["method"] == "wiener" else f" x{s['iterations']}")
            self.recon_stats.setText(
                f"reconstruction ({method}): {s['fps']:.1f} fps, latency {lat} ms, "
                f"reconstructed {s['reconstructed']}, skipped {s['skipped']}, errors "
                f"{s['errors']}" + (f" - {s['last_error']}" if s["last_error"] else ""))
            latest = self.live.latest()
            if latest is not None and latest.frame_index != self._shown_recon:
                self._shown_recon = latest.frame_index
                self.recon_view.setImage(scene_view(latest.image), autoLevels=True)

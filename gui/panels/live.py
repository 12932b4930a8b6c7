"""Live view: the raw camera frame (histogram, saturation overlay, fps) beside the live
reconstruction (its own fps, latency, skipped and error counters), Snap.

The session's stream hands every frame to the live reconstruction, which runs in a
process of its own (:class:`instrument.acquisition.live_process.LiveReconstructionProcess`: frames
and results through shared memory, so the window shares its interpreter lock with no
solver; Wiener preview or warm-started ADMM with a few iterations per frame; PSF from a file
or a run store, :func:`gui.jobs.build_live`); a 20 Hz timer shows the newest frame
and the newest reconstruction and the counters, fewer times a second while the window
falls behind (:class:`gui.pacing.DisplayPacer`: the frames not shown are counted under
the raw frame). Nothing here waits on the camera or the solver. The PSF, depth, dark
level, method, iterations and device (cpu, cuda or auto: where the solves run,
:class:`recon.live.LiveReconstructor`) are remembered between sessions; the depth offers
the stack's planes and shows the plane used; the PSF and depth in use are handed to the
batch reconstruction (``psf_chosen``). A device that cannot be used (no GPU, no CuPy /
PyTorch, too little GPU memory) is refused with the message in the panel; the raw
stream goes on.
"""

from __future__ import annotations

import time
from collections import deque

from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtWidgets import (
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from instrument.options import COMMAND_FIELDS
from recon.options import LiveOptions, ReconOptions

from ..fields import choose_psf_path, remember
from ..forms import OptionsForm
from ..pacing import DisplayPacer
from ..session import Session
from ..workers import InputError, Job, readable_error
from .common import FrameView, dark_hint, depth_field, error_label, offer_depths

__all__ = ["LivePanel", "STALE_S"]

#: Consumer name of the live reconstruction on the session's stream.
CONSUMER = "live-reconstruction"
#: A reconstruction rate older than this (s) is shown as stale, not as a rate.
STALE_S = 2.0
#: The display timer's interval, ms (20 images a second at most).
TICK_MS = 50
#: The counters under the views are rewritten at most this often on the timer, s (a
#: rewrite lays the panel out again: about 2 ms of the GUI thread).
COUNTERS_S = 0.25


class LivePanel(QWidget):
    """See the module docstring.

    Signals
    -------
    psf_chosen(str, str)
        ``(psf, depth)`` of a live reconstruction that started (the batch fields
        take them).
    """

    psf_chosen = Signal(str, str)

    def __init__(self, session: Session, parent=None) -> None:
        super().__init__(parent)
        self.session = session
        self.live = None
        self.job: Job | None = None
        self.stream_job: Job | None = None
        self.depth_job: Job | None = None
        self.depth_used: float | None = None
        self._shown_raw = -1
        #: Raw frames shown, and the frames the window received but did not show
        #: (newer ones came first, or the pacer showed fewer while the window was busy).
        self.frames_shown = 0
        self.frames_not_shown = 0
        self._seen_at_shown: int | None = None
        self._shown_times: deque[float] = deque(maxlen=64)
        self.pacer = DisplayPacer(TICK_MS / 1000.0)
        self._counters_at = -1e18
        self._shown_recon = -1
        self._recon_count = (-1, time.monotonic(), 0)  # (results, when, frames seen)
        self._live_settings: dict = {}
        layout = QVBoxLayout(self)
        controls = QGridLayout()
        self.start_button = QPushButton("Start stream")
        self.start_button.setObjectName("live.stream")
        self.start_button.setToolTip("start or stop the camera's live stream (F5)")
        self.start_button.clicked.connect(self.toggle_stream)
        controls.addWidget(self.start_button, 0, 0)
        self.snap_button = QPushButton("Snap")
        self.snap_button.setObjectName("live.snap")
        self.snap_button.setToolTip("stop the stream and take one frame (F6)")
        self.snap_button.clicked.connect(self.snap)
        controls.addWidget(self.snap_button, 1, 0)
        controls.addWidget(QLabel("PSF (image, stack or run):"), 0, 1)
        self.psf = remember(QLineEdit(), "live/psf")
        self.psf.setObjectName("live.psf")
        self.psf.setPlaceholderText("e.g. out/runs/psf-sweep-....zarr")
        self.psf.editingFinished.connect(self.offer_depths)
        controls.addWidget(self.psf, 0, 2, 1, 3)
        browse = QPushButton("Browse...")
        browse.clicked.connect(self._browse)
        controls.addWidget(browse, 0, 5)
        controls.addWidget(QLabel("depth (mm):"), 1, 1)
        self.depth = remember(depth_field("live.depth"), "live/depth")
        controls.addWidget(self.depth, 1, 2)
        # the settings are generated from capture live's declarations (gui.forms)
        self.live_form = OptionsForm(LiveOptions, tuple(s.dest for s in LiveOptions.specs()),
                                     name="live.", remember_as="live")
        self.recon_form = OptionsForm(ReconOptions, COMMAND_FIELDS["capture live"],
                                      name="live.", remember_as="live")
        for form in (self.live_form, self.recon_form):  # live.method, live.dark, ...
            for field, widget in form.widgets.items():
                widget.setObjectName(f"live.{field}")
        self.method = self.live_form.widgets["method"]
        self.method.currentTextChanged.connect(self._method_changed)
        self.iterations = self.live_form.widgets["iterations"]
        self.iterations.valueChanged.connect(self._method_changed)
        self.dark = self.recon_form.widgets["dark"]
        self.dark.setPlaceholderText(dark_hint(session))
        self.dark.setToolTip("the frames' dark level: a number in DN or a dark run (calibrate "
                             "dark); empty on the virtual bench: its camera's offset, on a real "
                             "bench: estimated from a single PSF image's corner (a PSF sweep "
                             "needs it given)")
        self.device = self.recon_form.widgets["device"]
        self.device.setToolTip("where the reconstruction runs: cpu (NumPy), cuda (a GPU "
                               "through CuPy or PyTorch) or auto (the GPU when one is "
                               "usable); taken when the reconstruction starts")
        # dark beside the depth, then the method's and the reconstruction's settings
        rows = (self.recon_form.rows(("dark",)) + self.live_form.rows()
                + self.recon_form.rows(f for f in self.recon_form.widgets if f != "dark"))
        for i, (label, widget) in enumerate(rows):
            r, c = 1 + (i + 1) // 2, 1 + 2 * ((i + 1) % 2)
            controls.addWidget(label, r, c)
            controls.addWidget(widget, r, c + 1)
        device_row = 1 + (len(rows) + 1) // 2
        self.device_used = QLabel("")
        self.device_used.setObjectName("live.device_used")
        controls.addWidget(self.device_used, device_row, 1, 1, 4)
        for column in (2, 4):  # the two columns of fields share the width
            controls.setColumnStretch(column, 1)
        self.recon_button = QPushButton("Start reconstruction")
        self.recon_button.setObjectName("live.reconstruct")
        self.recon_button.clicked.connect(self.toggle_reconstruction)
        controls.addWidget(self.recon_button, 1, 5, 2, 1)
        self.plane = QLabel("")
        self.plane.setObjectName("live.plane")
        controls.addWidget(self.plane, 2, 0)
        layout.addLayout(controls)
        self.error = error_label()
        layout.addWidget(self.error)
        views = QHBoxLayout()
        left, right = QVBoxLayout(), QVBoxLayout()
        self.raw_view = FrameView("raw frame (DN)", histogram_hz=2.0, name="raw")
        self.raw_view.metadata = self._raw_metadata
        left.addWidget(self.raw_view, 1)
        self.raw_stats = QLabel("camera: not streaming")
        self.raw_stats.setWordWrap(True)
        self._stats_below(self.raw_stats)
        left.addWidget(self.raw_stats)
        self.recon_view = FrameView("live reconstruction (upright)", histogram_hz=2.0,
                                    name="reconstruction")
        self.recon_view.metadata = self._recon_metadata
        right.addWidget(self.recon_view, 1)
        self.recon_stats = QLabel("reconstruction: off")
        self.recon_stats.setWordWrap(True)
        self._stats_below(self.recon_stats)
        right.addWidget(self.recon_stats)
        views.addLayout(left, 1)
        views.addLayout(right, 1)
        layout.addLayout(views, 1)
        self.timer = QTimer(self)
        self.timer.timeout.connect(self._tick)
        self.timer.start(TICK_MS)
        session.changed.connect(self._session_changed)
        self._session_changed()

    # -- controls ------------------------------------------------------------------------
    def _browse(self) -> None:
        path = choose_psf_path(self)
        if path:
            self.psf.setText(path)
            self.offer_depths()

    def offer_depths(self) -> Job:
        """Offer the PSF stack's depths in the depth field (read on a worker)."""
        self.depth_job = offer_depths(self.depth, self.psf.text())
        return self.depth_job

    #: Lines of text the counters under a view have room for (the camera's wrap to
    #: three on a 1366x768 screen).
    STATS_LINES = 3

    @classmethod
    def _stats_below(cls, label: QLabel) -> None:
        """A view's counters: top-aligned, with room for :data:`STATS_LINES` lines, so
        a longer text is never drawn over the view's axis title (a wrapped label
        given two lines' height centred three, its first over the view)."""
        label.setAlignment(Qt.AlignmentFlag.AlignTop | Qt.AlignmentFlag.AlignLeft)
        label.setMinimumHeight(cls.STATS_LINES * label.fontMetrics().lineSpacing() + 4)

    def _session_changed(self) -> None:
        streaming = self.session.streaming
        self.start_button.setText("Stop stream" if streaming else "Start stream")
        self.start_button.setEnabled(self.session.connected)
        self.snap_button.setEnabled(self.session.connected)
        self.recon_button.setEnabled(self.session.connected)
        if not self.session.connected and self.live is not None:
            self.stop_reconstruction()
        self.dark.setPlaceholderText(dark_hint(self.session))

    def toggle_stream(self) -> Job | None:
        """Start or stop the camera's stream (on a worker)."""
        self.error.setText("")
        if not self.session.connected:
            self.error.setText("no bench is connected; press Connect on the Devices panel")
            return None
        self.stream_job = self.session.stream_job(not self.session.streaming,
                                                  on_error=self.error.setText)
        return self.stream_job

    def snap(self) -> Job | None:
        """Stop the stream and take one frame on a worker (shown as the raw frame)."""
        self.error.setText("")
        if not self.session.connected:
            self.error.setText("no bench is connected; press Connect on the Devices panel")
            return None
        if self.session.camera_user is not None:
            self.error.setText(f"the camera is busy with {self.session.camera_user}")
            return None
        self.stream_job = self.session.stream_job(False, then=self.session.service.snap,
                                                  on_error=self.error.setText,
                                                  done=self.session.show_frame)
        return self.stream_job

    def toggle_reconstruction(self) -> None:
        if self.live is not None:
            self.stop_reconstruction()
        else:
            self.start_reconstruction()

    def _depth_mm(self) -> float | None:
        text = self.depth.currentText().strip().removesuffix("mm").strip()
        if not text:
            return None
        try:
            return float(text)
        except ValueError:
            raise InputError(f"depth {text!r}: give a number in mm (one of the stack's "
                             "depths), or leave it empty for a single PSF image") from None

    def start_reconstruction(self) -> Job | None:
        """Build the reconstruction on a worker (PSF loading, FFT plans), then start it
        on the stream (started too if it was not)."""
        from ..jobs import build_live

        self.error.setText("")
        if not self.session.connected:
            self.error.setText("no bench is connected; press Connect on the Devices panel")
            return None
        try:
            depth = self._depth_mm()
        except InputError as exc:
            self.error.setText(str(exc))
            return None
        psf = self.psf.text().strip()
        try:
            live_options, options = self.live_form.values(), self.recon_form.values()
        except InputError as exc:
            from ..messages import operator_text

            self.error.setText(operator_text(str(exc), {**self.live_form.flag_labels(),
                                                        **self.recon_form.flag_labels()}))
            return None
        self.recon_button.setEnabled(False)

        def build(job):
            live, depth_used = build_live(self.session, psf, depth_mm=depth,
                                          live=live_options, options=options)
            live.start()  # its process or thread started here (waits for a core)
            return live, depth_used

        self.job = Job(build, name="build-live", owner=self)
        self._live_settings = {"psf": psf, "depth_requested_mm": depth,
                               "dark": str(options.dark), "bin_factor": options.bin_factor,
                               "device_requested": options.device}
        self.job.succeeded.connect(self._live_ready)
        self.job.failed.connect(self.error.setText)
        self.job.finished.connect(lambda: self.recon_button.setEnabled(True))
        return self.job.start()

    def _live_ready(self, result) -> None:
        live, depth = result
        self.depth_used = depth
        self._live_settings["depth_used_mm"] = depth
        label = live.backend_label
        self._live_settings["device"] = label
        self.device_used.setText(f"running on {label}")
        self.plane.setText("" if depth is None else f"plane used: z = {depth:g} mm")
        try:
            self.session.add_consumer(CONSUMER, live.offer)
            self.live = live
            if not self.session.streaming and self.session.camera_user is None:
                self.stream_job = self.session.stream_job(True, on_error=self.error.setText)
        except Exception as exc:  # noqa: BLE001 (shown, never raised)
            self.error.setText(readable_error(exc))
            if self.live is None:  # not attached: its thread stops (on a worker)
                Job(lambda job: live.stop(timeout_s=10.0), name="stop-live").start()
        self.recon_button.setText("Stop reconstruction" if self.live else
                                  "Start reconstruction")
        if self.live is not None:
            from ..logpane import job_ended

            job_ended("live reconstruction", f"started: {self.method.currentText()} on "
                      f"{label}, PSF {self._live_settings['psf']}"
                      + ("" if depth is None else f", plane z = {depth:g} mm"))
            self.psf_chosen.emit(self._live_settings["psf"],
                                 "" if depth is None else f"{depth:g}")

    def stop_reconstruction(self) -> None:
        """Detach the worker from the stream and stop it (it ends with its frame)."""
        self.session.remove_consumer(CONSUMER)
        live, self.live = self.live, None
        if live is not None:
            from ..logpane import gui_log

            gui_log.info("live reconstruction stopped")
            job = Job(lambda job: live.stop(timeout_s=10.0), name="stop-live")
            job.failed.connect(self.error.setText)
            self.job = job.start()
        self.recon_button.setText("Start reconstruction")
        self.plane.setText("")
        self.device_used.setText("")

    def _method_changed(self, *_) -> None:
        if self.live is not None:
            try:
                self.live.set_method(self.method.currentText(), self.iterations.value())
            except Exception as exc:  # noqa: BLE001 (shown, never raised)
                self.error.setText(readable_error(exc))

    # -- snapshot metadata ---------------------------------------------------------------
    def _raw_metadata(self) -> dict:
        frame = self.session.latest_frame()
        out: dict = {"kind": "raw camera frame"}
        if frame is not None:
            out["frame"] = {"index": int(frame.index),
                            "timestamp_s": float(getattr(frame, "timestamp_s", 0.0) or 0.0)}
        if self.session.connected:
            out["device_settings"] = self.session.service.settings_snapshot()
            out["bench"] = self.session.bench_path or "built-in simulated bench"
        return out

    def _recon_metadata(self) -> dict:
        out = self._raw_metadata()
        out["kind"] = "live reconstruction (upright)"
        out["reconstruction"] = {**self._live_settings, "method": self.method.currentText(),
                                 "iterations": self.iterations.value()}
        if self.live is not None:
            s = self.live.stats()
            out["reconstruction"].update(method=s["method"], iterations=s["iterations"])
        return out

    # -- display -------------------------------------------------------------------------
    def _tick(self) -> None:
        """The timer's slot: :meth:`refresh` when the pacer says this tick shows, the
        counters at most every :data:`COUNTERS_S`."""
        now = time.monotonic()
        if self.isVisible() and self.pacer.tick(now):
            counters = now - self._counters_at >= COUNTERS_S
            if counters:
                self._counters_at = now
            self.refresh(counters=counters)

    def refresh(self, counters: bool = True) -> None:
        """Show the newest frame and reconstruction and, with ``counters``, the
        counters (does nothing while the panel is hidden)."""
        from recon.io import scene_view

        if not self.isVisible():
            return
        frame = self.session.latest_frame()
        if frame is not None and frame.index != self._shown_raw:
            first = self._shown_raw < 0
            self._shown_raw = frame.index
            self._count_shown()
            image = frame.image
            self.raw_view.setImage(image, autoLevels=first or not self.raw_view.levels_locked)
            if self.session.connected:  # saturated pixels in red (at the drawn stride)
                full_scale = 2 ** self.session.frame_bit_depth() - 1
                saturated = image.size and image.max() >= full_scale  # no mask when none
                self.raw_view.mark(image >= full_scale if saturated else None)
        if frame is not None and counters:
            sat = f"saturated {int(frame.saturated_pixels)} px (red)"
            if self.session.streaming and self.session.stream_taken_by:
                self.raw_stats.setText(f"camera taken by {self.session.stream_taken_by}: "
                                       "the live view comes back when it ends (Stop stream "
                                       f"keeps it off); frame {frame.index} (the last); {sat}")
            elif self.session.streaming:
                c = self.session.stream_counters()
                self.raw_stats.setText(
                    f"camera: {c['fps']:.1f} fps (last 2 s), frame {frame.index}, acquired "
                    f"{c['acquired']}, dropped {c['dropped']}, skipped by the ring "
                    f"{c['skipped']}; {self._shown_text()}; {sat}")
            elif self.session.camera_user is not None:
                self.raw_stats.setText(f"camera busy with {self.session.camera_user}: frame "
                                       f"{frame.index}; {sat}")
            else:
                self.raw_stats.setText(f"{self._stopped_text()}; frame {frame.index} (the "
                                       f"last); {sat}")
        elif frame is None and counters and not self.session.streaming:
            self.raw_stats.setText(self._stopped_text())
        if self.live is not None and counters:
            self._show_live_stats()
        if self.live is not None:  # (its process may have just been found ended)
            latest = self.live.latest()
            if latest is not None and latest.frame_index != self._shown_recon:
                self._shown_recon = latest.frame_index
                self.recon_view.setImage(scene_view(latest.image), autoLevels=True)

    def _stopped_text(self) -> str:
        """The raw view's line while the stream is stopped: why, when it ended
        unasked (the bench's line), and how to start it."""
        reason = self.session.stream_end_reason
        if reason:
            return f"camera: {reason.removeprefix('camera ')}"
        return "camera: not streaming (Start stream or F5)"

    def _count_shown(self) -> None:
        seen = self.session.frames_seen
        if self._seen_at_shown is not None:
            self.frames_not_shown += max(seen - self._seen_at_shown - 1, 0)
        self._seen_at_shown = seen
        self.frames_shown += 1
        self._shown_times.append(time.monotonic())

    def _shown_text(self) -> str:
        """``"shown 20.0 fps, not shown 412"`` (the rate over the last 2 s), and why
        fewer while the pacer holds the rate down."""
        times = [t for t in self._shown_times if self._shown_times[-1] - t <= 2.0]
        span = times[-1] - times[0] if times else 0.0
        rate = (len(times) - 1) / span if span > 0.2 else 0.0
        slowed = (f" (at most {self.pacer.rate_hz:.0f} a second while the window catches "
                  "up)" if self.pacer.period_s > self.pacer.tick_s else "")
        return f"shown {rate:.1f} fps{slowed}, not shown {self.frames_not_shown}"

    def _show_live_stats(self) -> None:
        s = self.live.stats()
        if not s.get("running", True):
            self._live_ended()
            return
        now = time.monotonic()
        frames = self.session.frames_seen
        if s["reconstructed"] != self._recon_count[0]:
            self._recon_count = (s["reconstructed"], now, frames)
        idle = now - self._recon_count[1]
        offered = frames - self._recon_count[2]
        method = s["method"] + ("" if s["method"] == "wiener" else f" x{s['iterations']}")
        if idle > STALE_S:
            why = ("the camera is busy" if self.session.camera_user is not None
                   else "the stream is stopped" if not self.session.streaming
                   else f"none of the {offered} frames since has finished: the "
                   "reconstruction is slower than the camera, or gets little time on a "
                   "busy machine" if offered > 0
                   else "waiting for frames")
            rate = f"no new result for {idle:.0f} s ({why})"
        else:
            lat = ("-" if s["latency_median_s"] is None
                   else f"{1e3 * s['latency_median_s']:.0f}")
            rate = f"{s['fps']:.1f} fps, latency {lat} ms"
        self.recon_stats.setText(
            f"reconstruction ({method}): {rate}, reconstructed {s['reconstructed']}, "
            f"skipped {s['skipped']}, errors {s['errors']}")
        if s["last_error"]:  # wrapped above the views (and logged), not under the image
            self.error.setText(f"live reconstruction: {s['last_error']}")

    def _live_ended(self) -> None:
        """The live reconstruction's process ended unasked: say how above the views
        (wrapped, and in the log) and put the controls back to start it again."""
        from ..messages import how_it_ended

        ended = getattr(self.live, "exit_status", lambda: None)()
        self.stop_reconstruction()
        self.error.setText(f"the live reconstruction stopped: {how_it_ended(ended)}. The "
                           "camera stream goes on; press Start reconstruction to start it "
                           "again")
        self.recon_stats.setText("reconstruction: stopped (the message above says why)")

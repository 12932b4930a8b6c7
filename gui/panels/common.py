"""What several panels share: an error line that also goes to the log, run controls,
and the overall progress of a long job with its elapsed time and ETA."""

from __future__ import annotations

import time

from PySide6.QtCore import QEvent, QTimer
from PySide6.QtWidgets import (
    QComboBox,
    QFrame,
    QHBoxLayout,
    QLabel,
    QProgressBar,
    QPushButton,
    QScrollArea,
    QWidget,
)

from ..fields import wheel_needs_focus
from ..imageview import FrameView
from ..logpane import gui_log
from ..workers import Job

__all__ = ["ErrorLabel", "FrameView", "JobProgress", "PanelScroll", "RunControls", "dark_hint",
           "depth_field",
           "error_label", "eta_text", "offer_depths"]


class ErrorLabel(QLabel):
    """A wrapped, red label for the messages of refused actions; each message also goes
    to the log pane (the session's history)."""

    def __init__(self, text: str = "", parent=None) -> None:
        super().__init__(text, parent)
        self.setWordWrap(True)
        self.setStyleSheet("color: #b00020;")

    def setText(self, text: str) -> None:  # noqa: N802 (Qt's name)
        if text and text != self.text():
            gui_log.warning("%s", text)
        super().setText(text)


class PanelScroll(QScrollArea):
    """A task panel in its dock: the panel fills the dock, and scrolls only when the
    dock is smaller than the panel's *minimum* (a laptop screen).

    Qt's resizable scroll area sizes a panel with word-wrapped labels by its height
    for the width, computed from the *preferred* sizes: an image view that prefers 480
    px once it shows a frame made the Calibration panel taller than its dock after the
    first run, and Start, Pause, Abort and the progress bar needed a scroll. Here the
    panel is as tall as the dock, or its minimum height for the width when that is more.
    """

    def __init__(self, panel: QWidget, parent=None) -> None:
        super().__init__(parent)
        self.setFrameShape(QFrame.Shape.NoFrame)
        self.setWidgetResizable(False)
        self.setWidget(panel)
        panel.installEventFilter(self)

    def fit(self) -> None:
        """Size the panel to the viewport (at least its minimum for the width)."""
        panel, port = self.widget(), self.viewport().size()
        if panel is None:
            return
        layout = panel.layout()
        width = max(port.width(), panel.minimumSizeHint().width())
        low = (layout.totalMinimumHeightForWidth(width) if layout is not None
               and layout.hasHeightForWidth() else panel.minimumSizeHint().height())
        height = max(port.height(), low)
        if panel.size().toTuple() != (width, height):
            panel.resize(width, height)

    def resizeEvent(self, event) -> None:  # noqa: N802 (Qt's name)
        super().resizeEvent(event)
        self.fit()

    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt's name)
        if obj is self.widget() and event.type() == QEvent.Type.LayoutRequest:
            QTimer.singleShot(0, self.fit)
        return False


def error_label() -> ErrorLabel:
    """A wrapped, red label for the messages of refused actions (:class:`ErrorLabel`)."""
    return ErrorLabel()


def dark_hint(session) -> str:
    """What an empty dark-level field means on this session's bench (its placeholder).

    The virtual bench knows its camera's dark offset; on a real (or emulated) bench an
    empty field estimates the level from a single PSF image's corner, and a calibrated
    PSF stack (a PSF sweep) needs the level given: "auto" there was refused."""
    if session.simulate or session.is_virtual:
        return "auto: the simulated camera's offset"
    return "DN or dark run; needed with a PSF sweep"


def depth_field(name: str) -> QComboBox:
    """An editable depth field (mm) that offers a stack's depths (:func:`offer_depths`)."""
    box = QComboBox()
    box.setEditable(True)
    box.setObjectName(name)
    box.lineEdit().setPlaceholderText("stack plane; empty: single PSF")
    box.setToolTip("the PSF stack's depths are offered (mm)")
    wheel_needs_focus(box)
    return box


def offer_depths(box: QComboBox, psf_path: str) -> Job:
    """Read the depths of the PSF stack ``psf_path`` on a worker and offer them in
    ``box`` (the text typed stays; the first depth is filled in if none was)."""
    from ..jobs import stack_depths

    job = Job(lambda job: stack_depths(psf_path), name="stack-depths", owner=box)

    def show(depths: list[float]) -> None:
        text = box.currentText()
        box.blockSignals(True)
        box.clear()
        box.addItems([f"{z:g}" for z in depths])
        box.blockSignals(False)
        box.setEditText(text if text or not depths else f"{depths[0]:g}")
        box.setToolTip(f"the stack's depths: {', '.join(f'{z:g}' for z in depths)} mm"
                       if depths else "a single PSF image: leave empty")

    job.succeeded.connect(show)
    return job.start()


def eta_text(seconds: float | None) -> str:
    """``"ETA 2 min 05 s"``, ``"ETA 40 s"`` or ``"ETA -"`` (unknown)."""
    if seconds is None:
        return "ETA -"
    m, s = divmod(int(round(max(seconds, 0.0))), 60)
    h, m = divmod(m, 60)
    if h:
        return f"ETA {h} h {m:02d} min"
    return f"ETA {m} min {s:02d} s" if m else f"ETA {s} s"


def _clock(seconds: float) -> str:
    m, s = divmod(int(seconds), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class JobProgress(QWidget):
    """A progress bar with the elapsed time and the ETA of a long job, ticking once a
    second between the job's own reports (which may be minutes apart).

    The ETA is the job's own estimate when it gives one (counted down between reports),
    else ``elapsed * remaining / done`` from its rate so far.

    Parameters
    ----------
    unit : str
        What is counted (``"frames"``, ``"readings"``).
    """

    def __init__(self, unit: str = "frames", parent=None) -> None:
        super().__init__(parent)
        self.unit = unit
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self.bar = QProgressBar()
        self.bar.setFormat(f"%v / %m {unit} (%p %)")
        layout.addWidget(self.bar, 3)
        self.label = QLabel("")
        self.label.setMinimumWidth(160)
        self.label.setWordWrap(True)  # a narrow dock wraps the ETA and note
        layout.addWidget(self.label, 2)
        self.timer = QTimer(self)
        self.timer.timeout.connect(self.tick)
        self._t0: float | None = None
        self._eta: tuple[float, float] | None = None  # (eta_s, at monotonic time)
        self._done = 0
        self._total = 0
        self.note = ""

    @property
    def running(self) -> bool:
        return self._t0 is not None

    def value(self) -> int:
        """Units done (the bar's value)."""
        return self.bar.value()

    def maximum(self) -> int:
        """Units in all (the bar's maximum; 0 while unknown)."""
        return self.bar.maximum()

    def start(self, total: int = 0, note: str = "") -> None:
        """A job starts (``total``: how many units it will do; 0 unknown)."""
        self._t0 = time.monotonic()
        self._eta = None
        self._done, self._total = 0, int(total)
        self.note = note
        self.bar.setRange(0, max(int(total), 0))
        self.bar.setValue(0)
        self.timer.start(1000)
        self.tick()

    def report(self, done: int, total: int | None = None, eta_s: float | None = None,
               note: str | None = None) -> None:
        """The job reports ``done`` of ``total`` units (and its own ETA, if it has one)."""
        if self._t0 is None:
            self.start(total or 0)
        if total is not None:
            self._total = int(total)
            self.bar.setMaximum(max(int(total), 0))
        self._done = int(done)
        self.bar.setValue(min(self._done, self.bar.maximum()))
        self._eta = None if eta_s is None else (float(eta_s), time.monotonic())
        if note is not None:
            self.note = note
        self.tick()

    def eta_s(self) -> float | None:
        """The time left, s (None while unknown)."""
        if self._t0 is None:
            return None
        now = time.monotonic()
        if self._eta is not None:
            eta, at = self._eta
            return max(eta - (now - at), 0.0)
        if self._done > 0 and self._total > self._done:
            return (now - self._t0) * (self._total - self._done) / self._done
        return None

    def elapsed_s(self) -> float:
        return 0.0 if self._t0 is None else time.monotonic() - self._t0

    def tick(self) -> None:
        if self._t0 is None:
            return
        text = f"{_clock(self.elapsed_s())} elapsed, {eta_text(self.eta_s())}"
        self.label.setText(f"{self.note}{'; ' if self.note else ''}{text}")

    def finish(self, text: str | None = None, *, ok: bool | None = None) -> None:
        """The job ended: the clock stops and the ETA goes.

        Parameters
        ----------
        text : str, optional
            What the label then says. None (``finish()``): the job completed, the label
            says how long it took and the bar keeps its count; a text (``""`` too):
            the job failed or stopped, the bar is emptied (no count, no percentage)
            and the label shows ``text``.
        ok : bool, optional
            Whether the job completed (default: ``text is None``).
        """
        ok = text is None if ok is None else ok
        took = self.elapsed_s()
        self.timer.stop()
        self._t0, self._eta = None, None
        self.note = ""
        if ok:
            self.label.setText(text or f"finished in {_clock(took)}")
            return
        self.bar.setRange(0, 1)
        self.bar.reset()  # no value: the bar shows no text
        self.label.setText(text or "")


class RunControls:
    """Start / Pause / Abort buttons of a panel running a procedure under a
    :class:`instrument.acquisition.runner.RunControl` (``self.control``), which pauses and aborts it
    between steps. Mixed into the panel's class."""

    def _make_controls(self, start_text: str, start) -> list[QPushButton]:
        from instrument.acquisition.runner import RunControl

        self.control = RunControl()
        self.start_button = QPushButton(start_text)
        self.start_button.clicked.connect(start)
        self.pause_button = QPushButton("Pause")
        self.pause_button.clicked.connect(self.toggle_pause)
        self.abort_button = QPushButton("Abort")
        self.abort_button.clicked.connect(self.abort)
        return [self.start_button, self.pause_button, self.abort_button]

    def _new_control(self):
        from instrument.acquisition.runner import RunControl

        self.control = RunControl()
        return self.control

    def _set_running(self, running: bool) -> None:
        self.start_button.setEnabled(not running)
        self.pause_button.setEnabled(running)
        self.abort_button.setEnabled(running)
        self.pause_button.setText("Pause")

    def toggle_pause(self) -> None:
        """Pause before the next step, or continue."""
        if self.control.paused:
            self.control.resume()
            self.pause_button.setText("Pause")
        else:
            self.control.pause()
            self.pause_button.setText("Continue")

    def abort(self) -> None:
        """Stop before the next step (the data so far is kept)."""
        self.control.abort("aborted by the operator (GUI)")

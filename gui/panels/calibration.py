"""Calibration panel: dark/flat, PSF sweep, PSF grid, angular response and SLM LUT with
their parameters, overall progress with elapsed time and ETA, pause / abort / resume,
and each frame shown as it is taken.

The parameters are the routine's typed model, from which the ``calibrate`` command's
options are generated too (:func:`gui.jobs.routine_options`, remembered between
sessions); the form's texts become the model, which builds the plan
(:func:`calibration_routines.bench_jobs.build_plan`), and the run is
:class:`instrument.acquisition.runner.Runner` in the bench process, controlled through a
:class:`~instrument.acquisition.runner.RunControl`. The bench is given back as it was (camera
settings, stage positions, LEDs, the live stream). A run that ends aborted or failed
keeps its data and says how to resume it.
"""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QScrollArea,
    QStackedWidget,
    QVBoxLayout,
    QWidget,
)

from ..fields import remember, wheel_needs_focus
from ..jobs import (
    ROUTINES,
    check_values,
    default_run_path,
    resume_plan,
    routine_options,
    run_plan,
)
from ..logpane import announce_job
from ..messages import operator_text
from ..session import Session
from ..workers import DEVICE_NICE, Job, readable_error
from .common import FrameView, JobProgress, RunControls

__all__ = ["CalibrationPanel"]


class CalibrationPanel(RunControls, QWidget):
    """See the module docstring."""

    def __init__(self, session: Session, parent=None) -> None:
        super().__init__(parent)
        self.session = session
        self.job: Job | None = None
        self.last_path: str | None = None
        self.result = None
        self.events: list = []
        self.light_frames = True
        self.labels: dict[str, str] = {}
        layout = QHBoxLayout(self)
        left = QVBoxLayout()
        top = QHBoxLayout()
        top.addWidget(QLabel("routine:"))
        self.routine = QComboBox()
        self.routine.setObjectName("calibration.routine")
        self.routine.addItems(ROUTINES)
        wheel_needs_focus(self.routine)
        top.addWidget(self.routine, 1)
        left.addLayout(top)
        self.forms = QStackedWidget()
        self.fields: dict[str, dict[str, QWidget]] = {}
        #: Each field's help under it: shown when the parameter box is tall enough
        #: (:meth:`_fit_hints`; always in the field's tooltip).
        self._hints: list[QLabel] = []
        for routine in ROUTINES:
            page = QWidget()
            form = QFormLayout(page)
            fields: dict[str, QWidget] = {}
            for opt in routine_options(routine):
                if opt.is_flag:
                    w: QWidget = QCheckBox()
                elif opt.choices:
                    w = QComboBox()
                    w.addItems([str(c) for c in opt.choices])
                    w.setCurrentText(str(opt.default))
                    wheel_needs_focus(w)
                else:
                    w = QLineEdit("" if opt.default in (None, ...) else str(opt.default))
                    w.setPlaceholderText("default")
                w.setToolTip(opt.help)
                w.setObjectName(f"{routine}{opt.flag}")
                remember(w, f"calibrate/{routine}/{opt.flag[2:]}")
                name = opt.flag[2:].replace("-", " ")
                self.labels[opt.flag] = name
                label = QLabel(f"{name}:")
                label.setToolTip(opt.help)
                hint = QLabel(opt.help)
                hint.setWordWrap(True)
                hint.setStyleSheet("color: #555; font-size: 11px;")
                box = QVBoxLayout()
                box.setSpacing(0)
                box.addWidget(w)
                if opt.help:
                    box.addWidget(hint)
                    self._hints.append(hint)
                form.addRow(label, box)
                fields[opt.flag] = w
            self.fields[routine] = fields
            self.forms.addWidget(page)
        self.routine.currentIndexChanged.connect(self.forms.setCurrentIndex)
        remember(self.routine, "calibrate/routine")
        self.forms.setCurrentIndex(self.routine.currentIndex())
        scroll = self.params = QScrollArea()
        scroll.setWidgetResizable(True)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setWidget(self.forms)
        scroll.viewport().installEventFilter(self)
        left.addWidget(scroll, 1)
        out = QHBoxLayout()
        out.addWidget(QLabel("run store:"))
        self.out = QLineEdit()
        self.out.setObjectName("calibration.out")
        self.out.setPlaceholderText("default out/runs/ROUTINE-TIME.zarr")
        out.addWidget(self.out, 1)
        left.addLayout(out)
        buttons = QHBoxLayout()
        self.resume_button = QPushButton("Resume run")
        self.resume_button.setObjectName("calibration.resume")
        self.resume_button.clicked.connect(self.resume)
        for b in [*self._make_controls("Start", self.start), self.resume_button]:
            buttons.addWidget(b)
        self.start_button.setObjectName("calibration.start")
        self.pause_button.setObjectName("calibration.pause")
        self.abort_button.setObjectName("calibration.abort")
        left.addLayout(buttons)
        self.progress = JobProgress("frames")
        left.addWidget(self.progress)
        self.status = QLabel("")
        self.status.setWordWrap(True)
        left.addWidget(self.status)
        layout.addLayout(left, 2)
        self.view = FrameView("frames as they are taken (DN)", histogram_hz=2.0,
                              name="calibration-frame")
        self.view.metadata = self._frame_metadata
        layout.addWidget(self.view, 3)
        self._set_running(False)

    #: The parameter box's least height (px) at which each field's help shows under
    #: it: below (a 1366x768 screen's dock is about 95 px), one field and a half
    #: showed at a time; without the help lines, three or more do.
    HINTS_MIN_HEIGHT_PX = 240

    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt's name)
        """The parameter box resized: :meth:`_fit_hints`."""
        from PySide6.QtCore import QEvent

        if obj is self.params.viewport() and event.type() == QEvent.Type.Resize:
            self._fit_hints(event.size().height())
        return super().eventFilter(obj, event)

    def _fit_hints(self, height_px: int) -> None:
        """Show each field's help line under it only when the parameter box is at least
        :data:`HINTS_MIN_HEIGHT_PX` tall (the help stays in each field's tooltip)."""
        show = height_px >= self.HINTS_MIN_HEIGHT_PX
        if self._hints and self._hints[0].isHidden() == show:
            for hint in self._hints:
                hint.setVisible(show)

    # -- state ---------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self.job is not None and self.job.running

    def _set_running(self, running: bool) -> None:
        super()._set_running(running)
        self.resume_button.setEnabled(not running and self.last_path is not None and (
            self.result is None or self.result.status != "complete"))

    def _values(self, routine: str) -> dict:
        out = {}
        for flag, w in self.fields[routine].items():
            if isinstance(w, QCheckBox):
                out[flag] = w.isChecked()
            elif isinstance(w, QComboBox):
                out[flag] = w.currentText()
            else:
                out[flag] = w.text().strip()
        return out

    def _launch(self, fn, total: int = 0, detail: str = "") -> Job:
        self.events = []
        self.result = None
        announce_job("calibration run", detail)
        self.job = Job(fn, self._new_control(), name="calibration", nice=DEVICE_NICE)
        self.job.progress.connect(self.on_event)
        self.job.succeeded.connect(self.on_result)
        self.job.failed.connect(self.on_failed)
        self._set_running(True)
        self.progress.start(total)
        return self.job.start()

    def _frame_metadata(self) -> dict:
        out = {"kind": "calibration frame", "routine": self.routine.currentText(),
               "run": self.last_path, "parameters": self._values(self.routine.currentText())}
        if self.session.connected:
            out["device_settings"] = self.session.service.settings_snapshot()
        return out

    # -- actions -------------------------------------------------------------------------
    def start(self) -> Job | None:
        """Build the routine's plan and run it into a new store (on a worker)."""
        routine = self.routine.currentText()
        self.status.setStyleSheet("")
        if not self.session.connected:
            self._say("no bench is connected; press Connect on the Devices panel", error=True)
            return None
        values = self._values(routine)
        try:
            check_values(routine, values)
        except Exception as exc:  # noqa: BLE001 (shown, never raised)
            self._say(readable_error(exc, self.labels), error=True)
            return None
        path = self.out.text().strip() or default_run_path(routine)
        self.last_path = path
        self.light_frames = True
        self.status.setText(f"running {routine} into {path}")
        return self._launch(lambda job, control: run_plan(job, self.session, routine, values,
                                                          path, control),
                            detail=f"{routine} into {path}")

    def resume(self) -> Job | None:
        """Resume the last run (:meth:`instrument.acquisition.runner.Runner.resume`)."""
        path = self.last_path
        if path is None:
            return None
        self.status.setText(f"resuming {path}")
        return self._launch(lambda job, control: resume_plan(job, self.session, path, control),
                            detail=f"resuming {path}")

    # -- results -------------------------------------------------------------------------
    def _say(self, text: str, *, error: bool = False) -> None:
        from ..logpane import gui_log

        self.status.setStyleSheet("color: #b00020;" if error else "")
        self.status.setText(text)
        (gui_log.warning if error else gui_log.info)("%s", text)

    def on_event(self, e) -> None:
        """Show a :class:`instrument.acquisition.runner.RunEvent` (or the plan's size, first)."""
        if isinstance(e, dict) and e.get("kind") == "planned":
            self.light_frames = bool(e["light_frames"])
            self.progress.start(int(e["total"]))
            self._say(f"{self.status.text()}: {e['total']} frames")
            return
        self.events.append(e.kind)
        point = "" if e.point is None else f"point {e.point + 1}/{e.points_total}"
        self.progress.report(e.frames_done, e.frames_total, eta_s=e.eta_s, note=point)
        if e.kind in ("paused", "resumed", "reconnecting", "reconnected", "retrying"):
            self._say(f"{e.kind}: {operator_text(e.message)}")
        tag = getattr(e, "tag", None)
        if e.last_frame is not None and (tag != "dark" or not self.light_frames):
            # frames with light (PSFs, flats, gratings) as they are taken; dark frames
            # only in a run of dark frames
            self.view.setImage(e.last_frame, autoLevels=True)
            self.view.setTitle(f"frame {e.frames_done} of {e.frames_total}: "
                               f"{point}, {tag or 'frame'} (DN)")

    def on_result(self, result) -> None:
        """A run ended: complete, aborted or failed (data kept, how to resume)."""
        self.result = result
        self._set_running(False)
        self.progress.finish(ok=result.status == "complete")
        if result.status == "complete":
            self._say(f"calibration run complete: {result.path}; the camera, stages and LEDs "
                      "are as before the run")
            return
        where = (f"at point {result.points_done + 1} of {result.points_total}"
                 if result.points_done < result.points_total else
                 f"after all {result.points_total} points (computing the products)")
        pending = "".join(f"\nnot resuming? then first: {a}" for a in result.pending_actions)
        error = operator_text(str(result.error), self.labels)
        self._say(f"calibration run {result.status} {where}: {error}\nThe data so far is kept in "
                  f"{result.path}; press Resume run to go on from there{pending}", error=True)

    def on_failed(self, text: str) -> None:
        """The run could not start or stopped with an error outside the runner."""
        self._set_running(False)
        self.progress.finish("")
        self._say(text, error=True)


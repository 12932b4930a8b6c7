"""Calibration panel: dark/flat, PSF sweep, PSF grid, angular response and SLM LUT with
their parameters, a progress bar with ETA, pause / abort / resume, and each frame
shown as it is taken.

The parameters are the ``calibrate`` command's options (:func:`gui.jobs.routine_options`),
the plan is the one the command builds (:func:`gui.jobs.build_plan`), and the run is
:class:`instrument.runner.Runner` on a worker, controlled through a
:class:`~instrument.runner.RunControl`. A run that ends aborted or failed keeps its
data and says how to resume it (the Resume button, or the command line).
"""

from __future__ import annotations

from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QProgressBar,
    QPushButton,
    QStackedWidget,
    QVBoxLayout,
    QWidget,
)

from ..jobs import ROUTINES, build_plan, default_run_path, resume_plan, routine_options, run_plan
from ..session import Session
from ..workers import Job, readable_error
from .common import FrameView, RunControls

__all__ = ["CalibrationPanel"]


def _eta(seconds) -> str:
    if seconds is None:
        return "ETA -"
    m, s = divmod(int(round(seconds)), 60)
    return f"ETA {m} min {s:02d} s" if m else f"ETA {s} s"


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
        layout = QHBoxLayout(self)
        left = QVBoxLayout()
        top = QHBoxLayout()
        top.addWidget(QLabel("routine:"))
        self.routine = QComboBox()
        self.routine.addItems(ROUTINES)
        top.addWidget(self.routine, 1)
        left.addLayout(top)
        self.forms = QStackedWidget()
        self.fields: dict[str, dict[str, QWidget]] = {}
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
                else:
                    w = QLineEdit("" if opt.default is None else str(opt.default))
                    w.setPlaceholderText("default")
                w.setToolTip(f"{opt.flag}: {opt.help}")
                w.setObjectName(f"{routine}{opt.flag}")
                label = QLabel(f"{opt.flag[2:]}:")
                label.setToolTip(opt.help)
                hint = QLabel(opt.help)
                hint.setWordWrap(True)
                hint.setStyleSheet("color: #555; font-size: 11px;")
                box = QVBoxLayout()
                box.setSpacing(0)
                box.addWidget(w)
                if opt.help:
                    box.addWidget(hint)
                form.addRow(label, box)
                fields[opt.flag] = w
            self.fields[routine] = fields
            self.forms.addWidget(page)
        self.routine.currentIndexChanged.connect(self.forms.setCurrentIndex)
        left.addWidget(self.forms)
        out = QHBoxLayout()
        out.addWidget(QLabel("run store:"))
        self.out = QLineEdit()
        self.out.setPlaceholderText("default out/runs/ROUTINE-TIME.zarr")
        out.addWidget(self.out, 1)
        left.addLayout(out)
        buttons = QHBoxLayout()
        self.resume_button = QPushButton("Resume run")
        self.resume_button.clicked.connect(self.resume)
        for b in [*self._make_controls("Start", self.start), self.resume_button]:
            buttons.addWidget(b)
        left.addLayout(buttons)
        self.progress = QProgressBar()
        self.progress.setFormat("%v / %m frames")
        left.addWidget(self.progress)
        self.eta = QLabel("")
        left.addWidget(self.eta)
        self.status = QLabel("")
        self.status.setWordWrap(True)
        left.addWidget(self.status)
        left.addStretch(1)
        layout.addLayout(left, 2)
        self.view = FrameView("frames as they are taken (DN)", histogram_hz=2.0)
        layout.addWidget(self.view, 3)
        self._set_running(False)

    # -- state ---------------------------------------------------------------------------
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

    def _launch(self, fn, *args) -> Job:
        self.events = []
        self.result = None
        self.job = Job(fn, *args, self._new_control(), name="calibration")
        self.job.progress.connect(self.on_event)
        self.job.succeeded.connect(self.on_result)
        self.job.failed.connect(self.on_failed)
        self._set_running(True)
        return self.job.start()

    # -- actions -------------------------------------------------------------------------
    def start(self) -> Job | None:
        """Build the routine's plan and run it into a new store (on a worker)."""
        routine = self.routine.currentText()
        self.status.setStyleSheet("")
        if not self.session.connected:
            self.status.setText("no bench is connected; press Connect on the Devices panel")
            return None
        try:
            plan = build_plan(self.session.bench, routine, self._values(routine))
        except Exception as exc:  # noqa: BLE001 (shown, never raised)
            self._say(readable_error(exc), error=True)
            return None
        path = self.out.text().strip() or default_run_path(routine)
        self.last_path = path
        total = sum(len(p.tags) for p in plan.points())
        self.light_frames = any(t != "dark" for p in plan.points() for t in p.tags)
        self.progress.setRange(0, total)
        self.progress.setValue(0)
        self._say(f"running {routine} into {path}")
        return self._launch(lambda job, control: run_plan(job, self.session, plan, path,
                                                          control))

    def resume(self) -> Job | None:
        """Resume the last run (:meth:`instrument.runner.Runner.resume`)."""
        path = self.last_path
        if path is None:
            return None
        self._say(f"resuming {path}")
        return self._launch(lambda job, control: resume_plan(job, self.session, path, control))

    # -- results -------------------------------------------------------------------------
    def _say(self, text: str, *, error: bool = False) -> None:
        self.status.setStyleSheet("color: #b00020;" if error else "")
        self.status.setText(text)

    def on_event(self, e) -> None:
        """Show a :class:`instrument.runner.RunEvent`."""
        self.events.append(e.kind)
        self.progress.setMaximum(e.frames_total)
        self.progress.setValue(e.frames_done)
        point = "" if e.point is None else f"point {e.point + 1}/{e.points_total}, "
        self.eta.setText(f"{point}{e.elapsed_s:.0f} s elapsed, {_eta(e.eta_s)}")
        if e.kind in ("paused", "resumed", "reconnecting", "reconnected", "retrying"):
            self._say(f"{e.kind}: {e.message}")
        tag = getattr(e, "tag", None)
        if e.last_frame is not None and (tag != "dark" or not self.light_frames):
            # frames with light (PSFs, flats, gratings) as they are taken; dark frames
            # only in a run of dark frames
            self.view.setImage(e.last_frame, autoLevels=True)
            self.view.setTitle(f"frame {e.frames_done} of {e.frames_total}: "
                               f"{point.rstrip(', ')}, {tag or 'frame'} (DN)")

    def on_result(self, result) -> None:
        """A run ended: complete, aborted or failed (data kept, how to resume)."""
        self.result = result
        self._set_running(False)
        if result.status == "complete":
            self._say(f"complete: {result.path}")
            return
        where = (f"at point {result.points_done + 1} of {result.points_total}"
                 if result.points_done < result.points_total else
                 f"after all {result.points_total} points (computing the products)")
        bench = "" if self.session.bench_path is None else f" {self.session.bench_path}"
        sim = " --simulate" if self.session.simulate else ""
        pending = "".join(f"\nnot resuming? then first: {a}" for a in result.pending_actions)
        self._say(f"{result.status} {where}: {result.error}\nThe data so far is kept; press "
                  f"Resume run, or run `diffuserlab calibrate resume {result.path}{bench}{sim}`"
                  f"{pending}", error=True)

    def on_failed(self, text: str) -> None:
        """The run could not start or stopped with an error outside the runner."""
        self._set_running(False)
        self._say(text, error=True)

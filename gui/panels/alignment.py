"""Alignment panel: the SLM-mask alignment with spot feedback, watched as it runs.

Shows the spot efficiency of every reading (against the reading number, coloured by
step), the mask stage's current pose, the per-section offsets as the 3 x 5 map of
the SLM's sections (and, after the verify step, each section's efficiency against
the aligned simulation) and each step's state. The procedure is
:class:`calibration_routines.mask_alignment.MaskAligner` on a worker
(:func:`gui.jobs.run_alignment`), paused and aborted through its
:class:`~instrument.acquisition.runner.RunControl`; a finished record can be opened too
(:func:`calibration_routines.mask_alignment.load_alignment`).
"""

from __future__ import annotations

import datetime as _dt

import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QCheckBox,
    QFileDialog,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from ..fields import read, remember, store, wheel_needs_focus
from ..jobs import ALIGNMENT_STEPS, run_alignment
from ..logpane import announce_job, job_ended
from ..session import Session
from ..workers import DEVICE_NICE, Job
from .common import JobProgress, RunControls

__all__ = ["AlignmentPanel"]

#: The section grid of the alignment (rows, columns).
GRID = (3, 5)
#: Readings a whole alignment takes on the simulated bench (``align mask --simulate``,
#: 3 frames per reading: 1360 with the focus steps, 1046 without), the ETA's guess
#: until an alignment on this machine has finished (its count is remembered then).
EXPECTED_READINGS = {True: 1360, False: 1046}
_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
            "#bcbd22", "#17becf", "#7f7f7f")


class AlignmentPanel(RunControls, QWidget):
    """See the module docstring."""

    def __init__(self, session: Session, parent=None) -> None:
        super().__init__(parent)
        self.session = session
        self.job: Job | None = None
        self.readings: list[tuple[int, float, str]] = []
        self._out = ""
        layout = QHBoxLayout(self)
        left = QVBoxLayout()
        form = QGridLayout()
        form.addWidget(QLabel("record folder:"), 0, 0)
        self.out = QLineEdit()
        self.out.setPlaceholderText("default out/align/mask-TIME.align")
        form.addWidget(self.out, 0, 1, 1, 3)
        form.addWidget(QLabel("mask seed:"), 1, 0)
        self.seed = remember(QLineEdit(), "align/mask-seed")
        self.seed.setPlaceholderText("simulated: the virtual mask's")
        form.addWidget(self.seed, 1, 1)
        form.addWidget(QLabel("frames per reading:"), 1, 2)
        self.frames = QSpinBox()
        self.frames.setRange(1, 20)
        self.frames.setValue(3)
        self.frames.setObjectName("align.frames")
        wheel_needs_focus(self.frames)
        remember(self.frames, "align/frames")
        form.addWidget(self.frames, 1, 3)
        self.focus = QCheckBox("focus and tip/tilt (stage z, tip, tilt)")
        self.focus.setChecked(True)
        self.focus.setObjectName("align.focus")
        remember(self.focus, "align/focus")
        form.addWidget(self.focus, 2, 0, 1, 4)
        left.addLayout(form)
        buttons = QHBoxLayout()
        self.open_button = QPushButton("Open record...")
        self.open_button.clicked.connect(self._browse)
        for b in [*self._make_controls("Start alignment", self.start), self.open_button]:
            buttons.addWidget(b)
        left.addLayout(buttons)
        self.start_button.setObjectName("align.start")
        self.abort_button.setObjectName("align.abort")
        self.progress = JobProgress("readings")
        left.addWidget(self.progress)
        steps = QGroupBox("steps")
        grid = QGridLayout(steps)
        self.step_labels: dict[str, QLabel] = {}
        for i, name in enumerate(ALIGNMENT_STEPS):
            grid.addWidget(QLabel(f"{i}. {name}"), i, 0)
            self.step_labels[name] = QLabel("waiting")
            grid.addWidget(self.step_labels[name], i, 1)
        left.addWidget(steps)
        self.pose = QLabel("mask stage pose: -")
        self.pose.setWordWrap(True)
        left.addWidget(self.pose)
        self.message = QLabel("")
        self.message.setWordWrap(True)
        left.addWidget(self.message)
        left.addStretch(1)
        layout.addLayout(left, 2)
        right = QVBoxLayout()
        self.plot = pg.PlotWidget(title="spot efficiency per reading")
        self.plot.setLabel("bottom", "reading")
        self.plot.setLabel("left", "spot efficiency eta")
        self.plot.addLegend(offset=(10, 10), brush=pg.mkBrush(0, 0, 0, 170))
        self.curves: dict[str, pg.PlotDataItem] = {}
        self.plot.setMinimumHeight(170)
        right.addWidget(self.plot, 2)
        sections = QGroupBox("per-section offsets (mask px, x / y) and eta / aligned simulation")
        self.section_grid = QGridLayout(sections)
        self.cells: list[QLabel] = []
        for r in range(GRID[0]):
            for c in range(GRID[1]):
                cell = QLabel(f"section {r * GRID[1] + c}\n-")
                cell.setAlignment(Qt.AlignmentFlag.AlignCenter)
                cell.setMinimumSize(64, 40)
                cell.setStyleSheet("border: 1px solid #999; background: #f4f4f4;")
                self.section_grid.addWidget(cell, r, c)
                self.cells.append(cell)
        right.addWidget(sections, 1)
        layout.addLayout(right, 3)
        self._set_running(False)

    def _set_running(self, running: bool) -> None:
        super()._set_running(running)
        self.open_button.setEnabled(not running)

    @property
    def running(self) -> bool:
        return self.job is not None and self.job.running

    def _readings_key(self) -> str:
        return f"align/readings-focus-{int(self.focus.isChecked())}"

    def expected_readings(self) -> int:
        """Readings the whole alignment is expected to take: the last finished one's on
        this machine with the same focus setting, else :data:`EXPECTED_READINGS`."""
        stored = read(self._readings_key())
        try:
            return max(int(stored), 1)
        except (TypeError, ValueError):
            return EXPECTED_READINGS[self.focus.isChecked()]

    # -- actions -------------------------------------------------------------------------
    def start(self) -> Job | None:
        """Run the alignment into a new record folder (on a worker)."""
        if not self.session.connected:
            self.message.setText("no bench is connected; press Connect on the Devices panel")
            return None
        out = self.out.text().strip() or f"out/align/mask-{_dt.datetime.now():%Y%m%d-%H%M%S}.align"
        self.readings = []
        for label in self.step_labels.values():
            label.setText("waiting")
        self.message.setText(f"aligning; record {out}")
        announce_job("mask alignment", f"record {out}")
        self._out = out
        self.progress.start(self.expected_readings(), note="about")
        self.job = Job(run_alignment, self.session, out, self._new_control(),
                       mask_seed=self.seed.text(), frames=self.frames.value(),
                       focus=self.focus.isChecked(), name="alignment",
                       nice=DEVICE_NICE)
        self.job.progress.connect(self.on_progress)
        self.job.succeeded.connect(self.on_report)
        self.job.failed.connect(self.on_failed)
        self._set_running(True)
        return self.job.start()

    def _browse(self) -> None:
        path = QFileDialog.getExistingDirectory(self, "alignment record")
        if path:
            self.open_record(path)

    def open_record(self, path: str) -> None:
        """Show a finished (or stopped) alignment record."""
        from calibration_routines.mask_alignment import load_alignment

        from ..jobs import section_summary

        try:
            rec = load_alignment(path)
        except (OSError, ValueError) as exc:
            self.message.setText(str(exc))
            return
        self.readings = []
        for entry in rec["captures"]:
            self.on_progress({"kind": "reading", "eta": entry.get("eta"),
                              "pose": entry.get("pose"), "step": entry.get("step")})
        self.on_progress({"kind": "event", "step": "", "message": f"record {path}: "
                          f"{rec.get('status')}", "done": list(rec.get("steps", {})),
                          "steps": section_summary(rec.get("steps", {}))})

    # -- display -------------------------------------------------------------------------
    def on_progress(self, p: dict) -> None:
        if p["kind"] == "reading":
            step = str(p.get("step") or "?")
            self.readings.append((len(self.readings) + 1, float(p.get("eta") or 0.0), step))
            if step not in self.curves:
                colour = _COLOURS[len(self.curves) % len(_COLOURS)]
                self.curves[step] = self.plot.plot([], [], pen=None, symbol="o", symbolSize=5,
                                                   symbolBrush=colour, symbolPen=None, name=step)
            xs = [n for n, _, s in self.readings if s == step]
            ys = [e for _, e, s in self.readings if s == step]
            self.curves[step].setData(xs, ys)
            self._mark_running(step)
            if self.job is not None and self.job.running:
                n = len(self.readings)
                self.progress.report(n, max(n + 1, self.progress.bar.maximum()),
                                     note=f"step {step}")
            pose = p.get("pose") or {}
            self.pose.setText("mask stage pose: " + ", ".join(
                f"{a} {v:+.4f} {'mm' if a in ('x', 'y', 'z') else 'deg'}"
                for a, v in pose.items()))
            return
        done = set(p.get("done", ()))
        current = p.get("step")
        for name, label in self.step_labels.items():
            if name in done:
                label.setText("done")
        self._mark_running(current or "")
        if p.get("message"):
            self.message.setText(f"[{current}] {p['message']}" if current else p["message"])
        self._show_sections(p.get("steps", {}))

    def _mark_running(self, step: str) -> None:
        """Show ``step`` (or the step it is a part of: ``focus_check`` is ``focus``)
        running; a step running before it is done now (one step runs at a time)."""
        name = next((n for n in ALIGNMENT_STEPS if step == n or step.startswith(n + "_")),
                    None)
        if name is None or self.step_labels[name].text() == "done":
            return
        for other, label in self.step_labels.items():
            if other != name and label.text() == "running":
                label.setText("done")
        self.step_labels[name].setText("running")

    def _show_sections(self, summary: dict) -> None:
        offsets = summary.get("offsets_px")
        ratios = summary.get("eta_ratio")
        for j, cell in enumerate(self.cells):
            lines = [f"section {j}"]
            if offsets and j < len(offsets):
                lines.append(f"{offsets[j][0]:+.2f} / {offsets[j][1]:+.2f}")
            if ratios and j < len(ratios):
                lines.append(f"eta {ratios[j]:.2f}")
                good = ratios[j] >= 0.8
                cell.setStyleSheet("border: 1px solid #999; background: "
                                   f"{'#d8f0d8' if good else '#f8d8d8'};")
            cell.setText("\n".join(lines if len(lines) > 1 else lines + ["-"]))

    def on_report(self, report: dict) -> None:
        self._set_running(False)
        store(self._readings_key(), len(self.readings))
        self.progress.report(len(self.readings), len(self.readings))
        self.progress.finish()
        s = report.get("summary", {})
        passed = report["steps"]["verify"]["passed"]
        t = s.get("translation_px", (0.0, 0.0))
        text = (f"completed ({'passed' if passed else 'NOT passed'}): translation "
                f"{t[0]:+.3f}, {t[1]:+.3f} mask px, rotation "
                f"{s.get('theta_rad', 0.0) * 1e3:+.3f} mrad, {s.get('captures')} frames")
        self.message.setText(text)
        pose = s.get("stage_pose") or {}
        where = ", ".join(f"{a} {v:+.4f} {'mm' if a in ('x', 'y', 'z') else 'deg'}"
                          for a, v in pose.items())
        job_ended("mask alignment", f"{text}; the mask stage stays at {where or 'its pose'}; "
                  f"record {self._out}", ok=passed)

    def on_failed(self, text: str) -> None:
        self._set_running(False)
        self.progress.finish("")
        self.message.setText(f"alignment stopped: {text}\nThe record keeps every reading "
                             "taken; start a new alignment to try again.")
        job_ended("mask alignment", f"stopped: {text}; the mask stage is back where it was; "
                  f"record {self._out} keeps every reading", ok=False)
        for label in self.step_labels.values():
            if label.text() == "running":
                label.setText("stopped")

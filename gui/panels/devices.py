"""Device panel: connect / disconnect, each device's status and settings, stage jog and
go-to, the LED picker on the array's geometry, the SLM pattern picker.

Every device call runs in a :class:`~gui.workers.Job`; values are validated by the
device interfaces (:meth:`drivers.base.Device.apply_settings`), whose message shows
under the device when one is refused.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, QTimer
from PySide6.QtWidgets import (
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QScrollArea,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from ..device_settings import SETTINGS, limits_text, parse_value, value_text
from ..session import SCENES, Session
from ..workers import Job
from .common import error_label

__all__ = ["DevicePanel", "DeviceBox"]


class DeviceBox(QGroupBox):
    """One device: status, settings (unit, limits, Apply) and its kind's controls."""

    def __init__(self, device, parent=None) -> None:
        super().__init__(f"{device.device_id} ({device.kind}, {type(device).__name__})", parent)
        self.device = device
        self.jobs: list[Job] = []
        layout = QVBoxLayout(self)
        self.status = QLabel("")
        self.status.setWordWrap(True)
        layout.addWidget(self.status)
        form = QFormLayout()
        self.fields: dict[str, QLineEdit] = {}
        values = device.settings()
        for name, (label, unit) in SETTINGS.get(device.kind, {}).items():
            edit = QLineEdit(value_text(values[name]))
            edit.setCursorPosition(0)
            edit.setObjectName(f"{device.device_id}.{name}")
            edit.returnPressed.connect(lambda n=name: self.apply(n))
            row = QHBoxLayout()
            row.addWidget(edit, 1)
            button = QPushButton("Apply")
            button.clicked.connect(lambda _=False, n=name: self.apply(n))
            row.addWidget(button)
            cell = QVBoxLayout()
            cell.setSpacing(1)
            cell.addLayout(row)
            limits = QLabel(f"limits: {limits_text(device, name)}")
            limits.setWordWrap(True)
            limits.setStyleSheet("color: #555; font-size: 11px;")
            cell.addWidget(limits)
            form.addRow(f"{label}{f' ({unit})' if unit else ''}:", cell)
            self.fields[name] = edit
        layout.addLayout(form)
        if device.kind == "stage":
            layout.addWidget(self._stage_controls())
        elif device.kind == "led_array":
            layout.addWidget(self._led_controls())
        elif device.kind == "slm":
            layout.addWidget(self._slm_controls())
        self.error = error_label()
        layout.addWidget(self.error)

    # -- jobs ----------------------------------------------------------------------------
    def run(self, fn, *args, done=None, failed=None) -> Job:
        """Run ``fn(*args)`` on a worker; a refusal shows in :attr:`error`."""
        self.jobs = [j for j in self.jobs if j.running]
        job = Job(lambda job: fn(*args), name=f"device-{self.device.device_id}")
        job.failed.connect(self.error.setText)
        job.succeeded.connect(lambda _: self.error.setText(""))
        if done is not None:
            job.succeeded.connect(done)
        if failed is not None:
            job.failed.connect(failed)
        self.jobs.append(job)
        return job.start()

    def apply(self, name: str) -> Job:
        """Apply the text of setting ``name`` through the device interface."""
        edit = self.fields[name]
        edit.setModified(False)
        return self.run(self.device.apply_settings, {name: parse_value(edit.text())},
                        done=lambda _: self.refresh_settings(),
                        failed=lambda _: edit.setModified(True))  # the refused text stays

    def refresh_settings(self) -> None:
        """Show the device's current settings (fields being edited are left alone)."""
        values = self.device.settings()
        for name, edit in self.fields.items():
            if not edit.hasFocus() and not edit.isModified():
                edit.setText(value_text(values[name]))
                edit.setCursorPosition(0)

    def show_status(self, status: dict) -> None:
        """Show a :meth:`drivers.base.Device.status` dict (from the poller)."""
        skip = {"device_id", "kind", "driver"}
        parts = []
        for key, value in status.items():
            if key in skip:
                continue
            if isinstance(value, float):
                value = f"{value:.4g}"
            elif isinstance(value, dict):
                value = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                                  for k, v in value.items())
            parts.append(f"{key}: {value}")
        self.status.setText("; ".join(parts))
        if "positions" in status and hasattr(self, "positions"):
            for axis, label in self.positions.items():
                label.setText(f"{status['positions'][axis]:.4f}")

    # -- stage ---------------------------------------------------------------------------
    def _stage_controls(self) -> QWidget:
        from drivers.stage import AXIS_UNITS

        box = QWidget()
        grid = QGridLayout(box)
        grid.setContentsMargins(0, 0, 0, 0)
        for col, head in enumerate(("axis", "position", "jog step", "", "", "go to", "")):
            if not head:
                continue
            grid.addWidget(QLabel(f"<b>{head}</b>"), 0, col)
        self.positions: dict[str, QLabel] = {}
        self.jog_steps: dict[str, QDoubleSpinBox] = {}
        self.targets: dict[str, QLineEdit] = {}
        travel = self.device.travel
        for row, axis in enumerate(self.device.axes, start=1):
            unit = AXIS_UNITS[axis]
            grid.addWidget(QLabel(f"{axis} ({unit})"), row, 0)
            self.positions[axis] = QLabel("-")
            grid.addWidget(self.positions[axis], row, 1)
            step = QDoubleSpinBox()
            step.setMaximumWidth(120)
            step.setDecimals(4)
            step.setRange(0.0001, float(travel[axis][1] - travel[axis][0]))
            step.setValue(1.0 if unit == "mm" else 0.1)
            step.setSuffix(f" {unit}")
            self.jog_steps[axis] = step
            grid.addWidget(step, row, 2)
            for col, sign in ((3, -1), (4, +1)):
                b = QPushButton("-" if sign < 0 else "+")
                b.setFixedWidth(34)
                b.setObjectName(f"{self.device.device_id}.jog.{axis}{'-+'[sign > 0]}")
                b.clicked.connect(lambda _=False, a=axis, s=sign: self.jog(a, s))
                grid.addWidget(b, row, col)
            target = QLineEdit()
            target.setMaximumWidth(90)
            target.setPlaceholderText(f"{unit}")
            target.setObjectName(f"{self.device.device_id}.goto.{axis}")
            self.targets[axis] = target
            grid.addWidget(target, row, 5)
            go = QPushButton("Go")
            go.setFixedWidth(40)
            go.clicked.connect(lambda _=False, a=axis: self.go_to(a))
            grid.addWidget(go, row, 6)
        stop = QPushButton("Stop")
        stop.clicked.connect(lambda: self.run(self.device.stop))
        grid.addWidget(stop, len(self.device.axes) + 1, 0)
        return box

    def jog(self, axis: str, sign: int) -> Job:
        """Move ``axis`` by one jog step in direction ``sign``."""
        return self.run(self.device.move_by, {axis: sign * self.jog_steps[axis].value()})

    def go_to(self, axis: str) -> Job:
        """Move ``axis`` to the go-to field's value (the stage checks its limits)."""
        return self.run(self.device.move_to, {axis: parse_value(self.targets[axis].text())})

    # -- LED array -----------------------------------------------------------------------
    def _led_controls(self) -> QWidget:
        from drivers.led_array import PATTERNS

        box = QWidget()
        layout = QVBoxLayout(box)
        layout.setContentsMargins(0, 0, 0, 0)
        pos = self.device.positions_mm
        self.led_plot = pg.PlotWidget()
        self.led_plot.setMinimumHeight(260)
        self.led_plot.setAspectLocked(True)
        self.led_plot.setLabel("bottom", "x", units="mm")
        self.led_plot.setLabel("left", "y", units="mm")
        self.led_plot.setTitle("LEDs (click one to light it alone)")
        self.led_points = pg.ScatterPlotItem(pos[:, 0], pos[:, 1], size=9,
                                             data=np.arange(len(pos)))
        self.led_points.sigClicked.connect(self._led_clicked)
        self.led_plot.addItem(self.led_points)
        layout.addWidget(self.led_plot)
        row = QHBoxLayout()
        self.pattern = QComboBox()
        self.pattern.addItems(PATTERNS)
        row.addWidget(QLabel("pattern:"))
        row.addWidget(self.pattern)
        show = QPushButton("Show pattern")
        show.clicked.connect(lambda: self.run(self.device.set_pattern, self.pattern.currentText(),
                                              done=lambda _: self.show_lit()))
        row.addWidget(show)
        off = QPushButton("All off")
        off.clicked.connect(lambda: self.run(self.device.all_off, done=lambda _: self.show_lit()))
        row.addWidget(off)
        layout.addLayout(row)
        self.show_lit()
        return box

    def _led_clicked(self, _item, points, *_) -> None:
        if len(points):
            self.light_led(int(points[0].data()))

    def light_led(self, index: int) -> Job:
        """Light LED ``index`` alone at the array's brightness and colour settings."""
        dev = self.device
        return self.run(lambda: dev.set_leds([index], dev.colour, dev.brightness),
                        done=lambda _: self.show_lit())

    def show_lit(self) -> None:
        lit = self.device.lit()
        brushes = [pg.mkBrush("#ffb000") if i in lit else pg.mkBrush("#30303080")
                   for i in range(self.device.n_leds)]
        self.led_points.setBrush(brushes)

    # -- SLM -----------------------------------------------------------------------------
    def _slm_controls(self) -> QWidget:
        box = QWidget()
        row = QHBoxLayout(box)
        row.setContentsMargins(0, 0, 0, 0)
        self.slm_pattern = QComboBox()
        self.slm_pattern.addItems(["flat (zero phase)", "blazed grating", "random phase"])
        row.addWidget(QLabel("pattern:"))
        row.addWidget(self.slm_pattern)
        self.slm_period = QSpinBox()
        self.slm_period.setRange(2, 512)
        self.slm_period.setValue(8)
        self.slm_period.setSuffix(" px period")
        row.addWidget(self.slm_period)
        show = QPushButton("Show on SLM")
        show.clicked.connect(self.show_slm_pattern)
        row.addWidget(show)
        return box

    def show_slm_pattern(self) -> Job:
        """Show the chosen phase pattern (:meth:`drivers.slm.Slm.show_phase`)."""
        from calibration_routines.mask_alignment import blazed_phase

        dev = self.device
        rows, cols = dev.resolution
        choice = self.slm_pattern.currentIndex()
        if choice == 0:
            phase = np.zeros((rows, cols))
        elif choice == 1:
            phase = blazed_phase((rows, cols), (cols / self.slm_period.value(), 0.0))
        else:
            phase = np.random.default_rng(0).uniform(0, 2 * np.pi, (rows, cols))
        return self.run(dev.show_phase, phase)


class DevicePanel(QWidget):
    """Connect / disconnect and one :class:`DeviceBox` per device of the session."""

    def __init__(self, session: Session, parent=None) -> None:
        super().__init__(parent)
        self.session = session
        self.boxes: dict[str, DeviceBox] = {}
        outer = QVBoxLayout(self)
        bar = QHBoxLayout()
        self.connect_button = QPushButton("Connect")
        self.connect_button.clicked.connect(self.toggle_connection)
        bar.addWidget(self.connect_button)
        self.scene = QComboBox()
        self.scene.addItems(SCENES)
        self.scene.setToolTip("the virtual bench's moving scene in front of the camera")
        self.scene.activated.connect(lambda _: self._set_scene())
        self.scene_label = QLabel("virtual bench scene:")
        bar.addWidget(self.scene_label)
        bar.addWidget(self.scene)
        bar.addStretch(1)
        self.state = QLabel("not connected")
        bar.addWidget(self.state)
        outer.addLayout(bar)
        self.error = error_label()
        outer.addWidget(self.error)
        self.area = QScrollArea()
        self.area.setWidgetResizable(True)
        self.area.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.inner = QWidget()
        self.inner_layout = QVBoxLayout(self.inner)
        self.inner_layout.addStretch(1)
        self.area.setWidget(self.inner)
        outer.addWidget(self.area, 1)
        session.changed.connect(self.rebuild)
        self.poll_job: Job | None = None
        self.timer = QTimer(self)
        self.timer.timeout.connect(self.poll)
        self.timer.start(1000)
        self.rebuild()

    def toggle_connection(self) -> None:
        self.error.setText("")
        if self.session.connected:
            self.session.disconnect_bench()
        else:
            self.state.setText("connecting ...")
            self.connect_button.setEnabled(False)
            def failed(text: str) -> None:
                self.error.setText(text)
                self.state.setText("not connected")
                self.connect_button.setEnabled(True)

            job = self.session.connect_bench(on_error=failed)
            job.succeeded.connect(lambda _: self.connect_button.setEnabled(True))

    def _set_scene(self) -> None:
        if self.session.is_virtual:
            self.session.set_scene(self.scene.currentText(), on_error=self.error.setText)

    def rebuild(self) -> None:
        """One box per device when the set of open devices changed."""
        devices = dict(self.session.bench.devices) if self.session.connected else {}
        self.connect_button.setText("Disconnect" if devices else "Connect")
        if devices:
            self.connect_button.setEnabled(True)
        virtual = self.session.is_virtual or (not devices and self.session.simulate)
        self.scene.setVisible(virtual)
        self.scene_label.setVisible(virtual)
        self.scene.setCurrentText(self.session.scene_name)
        if list(devices) == list(self.boxes) and all(
                self.boxes[k].device is d for k, d in devices.items()):
            return
        for box in self.boxes.values():
            box.setParent(None)
            box.deleteLater()
        self.boxes = {}
        for index, (dev_id, dev) in enumerate(devices.items()):
            box = DeviceBox(dev)
            self.inner_layout.insertWidget(index, box)
            self.boxes[dev_id] = box
        self.state.setText(f"{len(devices)} devices open" if devices else "not connected")

    def poll(self) -> None:
        """Read every device's status on a worker (once a second, never overlapping)."""
        if not self.boxes or (self.poll_job is not None and self.poll_job.running):
            return
        devices = {k: b.device for k, b in self.boxes.items()}

        def read(job: Job) -> dict:
            return {k: d.status() for k, d in devices.items()}

        self.poll_job = Job(read, name="device-status")
        self.poll_job.succeeded.connect(self._show_status)
        self.poll_job.start()

    def _show_status(self, statuses: dict) -> None:
        for dev_id, status in statuses.items():
            if dev_id in self.boxes:
                box = self.boxes[dev_id]
                box.show_status(status)
                if status.get("is_open") and not status.get("disconnected"):
                    box.refresh_settings()

"""Device panel: connect / disconnect, each device's state, settings, presets and
Reconnect, stage jog, go-to and stored positions, the LED picker on the array's
geometry, the SLM pattern picker.

Each box holds a device's id and its :class:`~instrument.bench.bench_service.DeviceInfo`;
every command goes to the bench's typed service (``session.service``,
:class:`~instrument.bench.bench_service.BenchService`) in a :class:`~gui.workers.Job`; values
are validated by the device interfaces (:meth:`drivers.base.Device.apply_settings`),
whose message shows under the device when one is refused. Statuses, settings and
positions are pushed by the bench process when they change
(:class:`~instrument.bench.bench_service.BenchEvent`, read there once a second; no poll from
here) and shown as named fields (:mod:`gui.device_status`); the ``statuses`` signal
hands them to the window's status area. Presets (a device's
settings under a name) and stored stage positions belong to the bench file and are
kept between sessions (:mod:`gui.fields`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QComboBox,
    QFormLayout,
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

from ..device_settings import parse_value, rows, summarized, value_text
from ..device_status import STATE_COLOURS, device_state, status_fields
from ..fields import bench_key, load_json, store_json, wheel_needs_focus
from ..session import SCENES, Session
from ..workers import DEVICE_NICE, Job, readable_error
from .common import error_label
from .stage import MotionQueue, StageControls

__all__ = ["DevicePanel", "DeviceBox"]


_BRUSHES: list = []


def _led_brushes():
    """The LED map's two brushes (lit, dark), made once."""
    if not _BRUSHES:
        _BRUSHES.extend([pg.mkBrush("#ffb000"), pg.mkBrush("#30303080")])
    return _BRUSHES


@dataclass
class PolledDevice:
    """One device as the bench process last pushed it (a ``status`` event): its
    ``status()``, and for an open device its ``settings()`` and ``setting_values()``
    (None when not read)."""

    status: dict
    settings: dict | None = None
    values: dict | None = None


class DeviceBox(QGroupBox):
    """One device: state and Reconnect, status fields, settings (unit, limits, Apply),
    presets, and its kind's controls.

    Parameters
    ----------
    device : instrument.bench.bench_service.DeviceInfo
    service : instrument.bench.bench_process.BenchClient
        The bench's typed service (the commands go there by the device's id).
    bench : str
        The bench's settings group (:func:`gui.fields.bench_key`).
    """

    def __init__(self, device, service, bench: str = "bench/default", parent=None) -> None:
        super().__init__(f"{device.name} ({device.kind}, {device.driver_name})", parent)
        self.device, self.service, self.name = device, service, device.name
        #: The device's kind (read once: the window shows it at every poll).
        self.kind = device.kind
        self.bench = bench
        self.jobs: list[Job] = []
        self.last_status: dict = {}
        layout = QVBoxLayout(self)
        head = QHBoxLayout()
        self.state = QLabel("open")
        self.state.setObjectName(f"{device.name}.state")
        head.addWidget(self.state, 1)
        self.reconnect_button = QPushButton("Reconnect")
        self.reconnect_button.setObjectName(f"{device.name}.reconnect")
        self.reconnect_button.setToolTip("close the device, open it again and re-apply its "
                                         "settings (after a cable or power problem)")
        self.reconnect_button.clicked.connect(self.reconnect)
        head.addWidget(self.reconnect_button)
        layout.addLayout(head)
        self.status_form = QFormLayout()
        self.status_labels: dict[str, QLabel] = {}
        layout.addLayout(self.status_form)
        form = QFormLayout()
        self.fields: dict[str, QLineEdit] = {}
        self.rows = {row.name: row for row in rows(device)}  # from the declarations
        self.limit_labels: dict[str, QLabel] = {}
        values = service.setting_values(device.name)
        for name, spec in self.rows.items():
            edit = QLineEdit(value_text(values.get(name), name, spec.spec))
            edit.setCursorPosition(0)
            edit.setObjectName(f"{device.name}.{name}")
            edit.setToolTip(spec.tooltip)
            row = QHBoxLayout()
            row.addWidget(edit, 1)
            if summarized(values.get(name)):  # a lookup table: shown as a summary
                edit.setToolTip(f"{spec.tooltip}; shown as its count and range: its "
                                "calibration sets it, or type the whole list to replace it")
            if spec.read_only:
                edit.setReadOnly(True)
            else:
                edit.returnPressed.connect(lambda n=name: self.apply(n))
                button = QPushButton("Apply")
                button.setObjectName(f"{device.name}.{name}.apply")
                button.clicked.connect(lambda _=False, n=name: self.apply(n))
                row.addWidget(button)
            cell = QVBoxLayout()
            cell.setSpacing(1)
            cell.addLayout(row)
            limits = QLabel(f"limits: {spec.limits}" if spec.limits else "")
            limits.setObjectName(f"{device.name}.{name}.limits")
            limits.setWordWrap(True)
            limits.setStyleSheet("color: #555; font-size: 11px;")
            cell.addWidget(limits)
            form.addRow(f"{spec.title}:", cell)
            self.fields[name] = edit
            self.limit_labels[name] = limits
        layout.addLayout(form)
        if self.fields:
            layout.addLayout(self._preset_controls())
        self.queue: MotionQueue | None = None
        self.stage: StageControls | None = None
        self.error = error_label()
        if device.kind == "stage":
            self.queue = MotionQueue(service, device.name)
            self.queue.failed.connect(self.error.setText)
            self.stage = StageControls(device, self.queue, bench, self.error.setText)
            layout.addWidget(self.stage)
        elif device.kind == "led_array":
            layout.addWidget(self._led_controls())
        elif device.kind == "slm":
            layout.addWidget(self._slm_controls())
        layout.addWidget(self.error)

    # -- jobs ----------------------------------------------------------------------------
    def run(self, fn, *args, done=None, failed=None) -> Job:
        """Run ``fn(*args)`` on a worker; a refusal shows in :attr:`error`."""
        self.jobs = [j for j in self.jobs if j.running]
        job = Job(lambda job: fn(*args), name=f"device-{self.name}",
                  owner=self, nice=DEVICE_NICE)
        job.failed.connect(self.error.setText)
        job.succeeded.connect(lambda _: self.error.setText(""))
        if done is not None:
            job.succeeded.connect(done)
        if failed is not None:
            job.failed.connect(failed)
        self.jobs.append(job)
        return job.start()

    def apply(self, name: str) -> Job | None:
        """Apply the text of setting ``name`` through the device interface (a time
        takes its unit: ``20 ms``)."""
        edit = self.fields[name]
        spec = self.rows[name].spec
        typed = edit.text().strip()
        try:
            value = parse_value(typed, name, spec,
                                self.device.info.get(spec.per) if spec.per else None)
        except ValueError as exc:
            self.error.setText(readable_error(exc))
            return None
        edit.setModified(False)
        return self.run(self.service.apply_settings, self.name, {name: value},
                        done=lambda values: self.refresh_settings(values=values),
                        failed=lambda text: self._refused(name, typed, text))

    def _refused(self, name: str, typed: str, text: str) -> None:
        """A refused value: the field goes back to what the device holds (the field
        shows the device, never a value it refused), and the message says both."""
        self.refresh_settings(force=(name,))
        held = self.fields[name].text()
        self.error.setText(f"{self.rows[name].label} {typed!r} refused: {text}; the device "
                           f"keeps {self.rows[name].label} {held}")

    def reconnect(self) -> Job:
        """Close and open the device again, its settings re-applied
        (:meth:`drivers.base.Device.reconnect`)."""
        self.state.setText("reconnecting ...")
        return self.run(self.service.reconnect, self.name,
                        done=lambda values: self.refresh_settings(values=values))

    def refresh_settings(self, force: tuple[str, ...] = (), values: dict | None = None) -> None:
        """Show the device's current settings (fields being edited are left alone,
        except those named in ``force``; a device that went away meanwhile is left as
        shown: its state says so); ``values``: its ``setting_values()`` as the bench
        process pushed or returned them, else read here."""
        from drivers.errors import DeviceError
        from instrument.bench.bench_service import BenchServiceError

        if values is None:
            try:
                values = self.service.setting_values(self.name)
            except (DeviceError, BenchServiceError):
                return
        for name, edit in self.fields.items():
            if name in force or (not edit.hasFocus() and not edit.isModified()):
                edit.setText(value_text(values.get(name), name, self.rows[name].spec))
                edit.setModified(False)
                edit.setCursorPosition(0)

    def show_status(self, status: dict, settings: dict | None = None) -> None:
        """Show a :meth:`drivers.base.Device.status` dict and the ``settings()`` read with
        it (as the bench process pushed them; None: not read, the device gone) as
        fields."""
        self.last_status = status
        state = device_state(status)
        if state in ("disconnected", "closed"):
            settings = None
        colour = STATE_COLOURS.get(state, "#000")
        text = "DISCONNECTED: press Reconnect" if state == "disconnected" else state
        self.state.setText(f'<b style="color:{colour}">{text}</b>')
        rows = status_fields(self.kind, status, settings)[1:]
        for label, value in rows:
            if label not in self.status_labels:
                widget = QLabel(value)
                widget.setWordWrap(True)
                self.status_form.addRow(f"{label}:", widget)
                self.status_labels[label] = widget
            self.status_labels[label].setText(value)
        if self.stage is not None and isinstance(status.get("positions"), dict):
            self.stage.show_positions(status["positions"])

    def bench_down(self) -> None:
        """The bench process ended: the box shows so and takes no command (Reconnect
        included) until the bench is restarted."""
        self.state.setText(f'<b style="color:{STATE_COLOURS["closed"]}">'
                           "bench process stopped</b>")
        self.setEnabled(False)

    # -- presets ---------------------------------------------------------------------------
    @property
    def _preset_key(self) -> str:
        return f"{self.bench}/presets/{self.name}"

    def presets(self) -> dict[str, dict]:
        """``{name: settings}`` saved for this device on this bench."""
        return load_json(self._preset_key, {})

    def _preset_controls(self) -> QFormLayout:
        form = QFormLayout()
        row = QHBoxLayout()
        self.preset = QComboBox()
        self.preset.setObjectName(f"{self.name}.preset")
        self.preset.setMinimumWidth(110)
        wheel_needs_focus(self.preset)
        self.preset.addItems(list(self.presets()))
        row.addWidget(self.preset, 1)
        apply = QPushButton("Apply")
        apply.setToolTip("apply the saved settings")
        apply.clicked.connect(lambda: self.apply_preset(self.preset.currentText()))
        row.addWidget(apply)
        delete = QPushButton("Delete")
        delete.clicked.connect(lambda: self.delete_preset(self.preset.currentText()))
        row.addWidget(delete)
        form.addRow("preset:", row)
        save_row = QHBoxLayout()
        self.preset_name = QLineEdit()
        self.preset_name.setPlaceholderText("name for the current settings")
        self.preset_name.setObjectName(f"{self.name}.preset-name")
        self.preset_name.returnPressed.connect(lambda: self.save_preset(self.preset_name.text()))
        save_row.addWidget(self.preset_name, 1)
        save = QPushButton("Save as preset")
        save.clicked.connect(lambda: self.save_preset(self.preset_name.text()))
        save_row.addWidget(save)
        form.addRow("", save_row)
        return form

    def save_preset(self, name: str) -> None:
        """Save the device's current settings (those the panel edits) as ``name``."""
        name = name.strip()
        if not name:
            self.error.setText("type a name for the preset, then press Save as preset")
            return
        values = self.service.settings(self.name)
        presets = self.presets()
        presets[name] = {k: values[k] for k in self.fields
                         if k in values and not self.rows[k].read_only}
        store_json(self._preset_key, presets)
        self.preset_name.clear()
        self._show_presets(name)

    def apply_preset(self, name: str) -> Job | None:
        """Apply the saved settings ``name`` (validated by the device first)."""
        preset = self.presets().get(name)
        if preset is None:
            self.error.setText("choose a saved preset (or save the settings as one first)")
            return None
        return self.run(self.service.apply_settings, self.name, preset,
                        done=lambda values: self.refresh_settings(values=values))

    def delete_preset(self, name: str) -> None:
        presets = self.presets()
        if presets.pop(name, None) is not None:
            store_json(self._preset_key, presets)
        self._show_presets()

    def _show_presets(self, current: str | None = None) -> None:
        self.preset.clear()
        self.preset.addItems(list(self.presets()))
        if current:
            self.preset.setCurrentText(current)

    # -- LED array -----------------------------------------------------------------------
    def _led_controls(self) -> QWidget:
        from drivers.led_array import PATTERNS

        box = QWidget()
        layout = QVBoxLayout(box)
        layout.setContentsMargins(0, 0, 0, 0)
        pos = self.device.led_positions_mm
        self.led_plot = pg.PlotWidget()
        self.led_plot.setMinimumHeight(260)
        self.led_plot.setAspectLocked(True)
        self.led_plot.setLabel("bottom", "x", units="mm")
        self.led_plot.setLabel("left", "y", units="mm")
        self.led_plot.setTitle("LEDs (click one to light it alone)")
        # the wheel scrolls the Devices panel; it zooms the map once the map is clicked
        wheel_needs_focus(self.led_plot)
        self.led_points = pg.ScatterPlotItem(pos[:, 0], pos[:, 1], size=9,
                                             data=np.arange(len(pos)))
        # a click anywhere on the map lights the nearest LED (the circles are ~8 px
        # with ~4 px between them: a click between two did nothing)
        self.led_plot.scene().sigMouseClicked.connect(self._map_clicked)
        self.led_plot.addItem(self.led_points)
        layout.addWidget(self.led_plot)
        row = QHBoxLayout()
        self.pattern = QComboBox()
        self.pattern.addItems(PATTERNS)
        wheel_needs_focus(self.pattern)
        row.addWidget(QLabel("pattern:"))
        row.addWidget(self.pattern)
        show = QPushButton("Show pattern")
        show.clicked.connect(lambda: self.run(self.service.show, self.name,
                                              self.pattern.currentText(), done=self.show_lit))
        row.addWidget(show)
        off = QPushButton("All off")
        off.setObjectName(f"{self.name}.all-off")
        off.clicked.connect(lambda: self.run(self.service.show, self.name, "off",
                                             done=self.show_lit))
        row.addWidget(off)
        layout.addLayout(row)
        self.show_lit()
        return box

    def _map_clicked(self, event) -> None:
        """A left click on the LED map: the nearest LED lit (:meth:`nearest_led`), or
        a line saying the click was off the array."""
        from PySide6.QtCore import Qt

        view = self.led_plot.getPlotItem().vb
        if (event.button() != Qt.MouseButton.LeftButton
                or not view.sceneBoundingRect().contains(event.scenePos())):
            return
        where = view.mapSceneToView(event.scenePos())
        index = self.nearest_led(where.x(), where.y())
        if index is None:
            self.error.setText(f"no LED near x {where.x():.1f}, y {where.y():.1f} mm: "
                               "click on or between the LEDs of the map")
            return
        self.light_led(index)

    def nearest_led(self, x_mm: float, y_mm: float) -> int | None:
        """The index of the LED nearest ``(x_mm, y_mm)`` on the map, or None when it
        lies farther than the array's LED spacing from every LED (off the array)."""
        pos = np.asarray(self.device.led_positions_mm, float)
        distance = np.hypot(pos[:, 0] - x_mm, pos[:, 1] - y_mm)
        index = int(np.argmin(distance))
        return index if distance[index] <= self._led_spacing_mm() else None

    def _led_spacing_mm(self) -> float:
        """The median distance from each LED to its nearest neighbour, mm."""
        if not hasattr(self, "_spacing_mm"):
            pos = np.asarray(self.device.led_positions_mm, float)
            if len(pos) < 2:
                self._spacing_mm = float("inf")
            else:
                d = np.hypot(*(pos[:, None, :] - pos[None, :, :]).transpose(2, 0, 1))
                np.fill_diagonal(d, np.inf)
                self._spacing_mm = float(np.median(d.min(axis=1)))
        return self._spacing_mm

    def light_led(self, index: int) -> Job:
        """Light LED ``index`` alone at the array's brightness and colour settings."""
        return self.run(self.service.show, self.name, [int(index)], done=self.show_lit)

    def show_lit(self, lit: dict | None = None) -> None:
        """Colour the lit LEDs on the map (``lit``: ``{index: look}`` as the bench
        returned it, else read; only when the set changed; two brushes shared by every
        point: a fresh QBrush per point and call kept ~6000 references per call alive
        in pyqtgraph's scatter plot)."""
        if lit is None:
            try:
                lit = self.service.lit(self.name)
            except Exception:  # noqa: BLE001 (disconnected: the state line says so)
                lit = {}
        lit = {int(i) for i in lit}
        if lit == getattr(self, "_lit_shown", None):
            return
        self._lit_shown = lit
        on, off = _led_brushes()
        self.led_points.setBrush([on if i in lit else off
                                  for i in range(len(self.device.led_positions_mm))])

    # -- SLM -----------------------------------------------------------------------------
    def _slm_controls(self) -> QWidget:
        box = QWidget()
        row = QHBoxLayout(box)
        row.setContentsMargins(0, 0, 0, 0)
        self.slm_pattern = QComboBox()
        self.slm_pattern.addItems(["flat (zero phase)", "blazed grating", "random phase"])
        wheel_needs_focus(self.slm_pattern)
        row.addWidget(QLabel("pattern:"))
        row.addWidget(self.slm_pattern)
        self.slm_period = QSpinBox()
        self.slm_period.setRange(2, 512)
        self.slm_period.setValue(8)
        self.slm_period.setSuffix(" px period")
        wheel_needs_focus(self.slm_period)
        row.addWidget(self.slm_period)
        show = QPushButton("Show on SLM")
        show.clicked.connect(self.show_slm_pattern)
        row.addWidget(show)
        return box

    def show_slm_pattern(self) -> Job:
        """Show the chosen phase pattern (:meth:`drivers.slm.Slm.show_phase`)."""
        from calibration_routines.mask_alignment import blazed_phase

        rows, cols = self.device.resolution
        choice = self.slm_pattern.currentIndex()
        if choice == 0:
            phase = np.zeros((rows, cols))
        elif choice == 1:
            phase = blazed_phase((rows, cols), (cols / self.slm_period.value(), 0.0))
        else:
            phase = np.random.default_rng(0).uniform(0, 2 * np.pi, (rows, cols))
        return self.run(self.service.show, self.name, phase)


class DevicePanel(QWidget):
    """Connect / disconnect and one :class:`DeviceBox` per device of the session.

    Signals
    -------
    statuses(dict)
        ``{device id: PolledDevice}`` each time the bench process pushed a device's
        status (the window's status area shows them).
    """

    statuses = Signal(dict)

    def __init__(self, session: Session, parent=None) -> None:
        super().__init__(parent)
        self.session = session
        self.boxes: dict[str, DeviceBox] = {}
        self.last_statuses: dict[str, dict] = {}
        outer = QVBoxLayout(self)
        bar = QHBoxLayout()
        self.connect_button = QPushButton("Connect")
        self.connect_button.setObjectName("connect")
        self.connect_button.clicked.connect(self.toggle_connection)
        bar.addWidget(self.connect_button)
        self.scene = QComboBox()
        self.scene.addItems(SCENES)
        self.scene.setToolTip("the virtual bench's moving scene in front of the camera")
        self.scene.activated.connect(lambda _: self._set_scene())
        wheel_needs_focus(self.scene)
        self.scene_label = QLabel("virtual bench scene:")
        bar.addWidget(self.scene_label)
        bar.addWidget(self.scene)
        bar.addStretch(1)
        outer.addLayout(bar)
        self.state = QLabel("not connected")  # a line of its own, wrapped: never clipped
        self.state.setObjectName("device-count")
        self.state.setWordWrap(True)
        outer.addWidget(self.state)
        self.lost_box = self._lost_controls()
        outer.addWidget(self.lost_box)
        from .bench_jobs import BenchJobs

        self.bench_jobs = BenchJobs(session)  # the bench's address and every client's jobs
        outer.addWidget(self.bench_jobs)
        keys = QHBoxLayout()
        keys.addWidget(QLabel("arrow keys move:"))
        self.arrow_stage = QComboBox()
        self.arrow_stage.setToolTip("the stage the arrow keys jog (x, y; Page Up/Down: z) "
                                    "when no text field has the focus")
        wheel_needs_focus(self.arrow_stage)
        keys.addWidget(self.arrow_stage, 1)
        outer.addLayout(keys)
        self.error = error_label()
        outer.addWidget(self.error)
        self.area = QScrollArea()
        self.area.setWidgetResizable(True)
        self.area.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAsNeeded)
        self.inner = QWidget()
        self.inner_layout = QVBoxLayout(self.inner)
        self.inner_layout.addStretch(1)
        self.area.setWidget(self.inner)
        outer.addWidget(self.area, 1)
        session.changed.connect(self.rebuild)
        session.device_event.connect(self.on_event)
        self.rebuild()

    @property
    def bench_key(self) -> str:
        return bench_key(self.session.bench_path, self.session.simulate)

    def _lost_controls(self) -> QWidget:
        """What shows when the bench process ended unasked: why, and Restart bench."""
        box = QWidget()
        box.setObjectName("bench-lost")
        row = QHBoxLayout(box)
        row.setContentsMargins(0, 0, 0, 0)
        self.lost_label = QLabel("")
        self.lost_label.setObjectName("bench-lost.text")
        self.lost_label.setWordWrap(True)
        self.lost_label.setStyleSheet("color: #c00020; font-weight: bold;")
        row.addWidget(self.lost_label, 1)
        self.restart_button = QPushButton("Restart bench")
        self.restart_button.setObjectName("restart-bench")
        self.restart_button.setToolTip("start a new bench process and open the bench "
                                       "file's devices again")
        self.restart_button.clicked.connect(self.restart_bench)
        row.addWidget(self.restart_button, 0, Qt.AlignmentFlag.AlignTop)
        box.setVisible(False)
        return box

    def restart_bench(self) -> Job:
        """Start a new bench process and open the devices again (after the bench
        process ended unasked)."""
        self.error.setText("")
        self.restart_button.setEnabled(False)
        self.restart_button.setText("restarting ...")

        def failed(text: str) -> None:
            self.error.setText(text)
            self.restart_button.setEnabled(True)
            self.restart_button.setText("Restart bench")

        self._opening = self.session.connect_bench(on_error=failed)
        return self._opening

    def toggle_connection(self) -> None:
        self.error.setText("")
        opening = getattr(self, "_opening", None)
        if opening is not None and opening.running:  # the button reads Cancel
            opening.cancel()  # the bench's opens stop within 0.1 s, homing included
            self.state.setText("cancelling ...")
            self.connect_button.setEnabled(False)
        elif self.session.connected:
            self.session.disconnect_bench()
        else:
            self.state.setText("connecting ...")
            self.connect_button.setText("Cancel")

            def failed(text: str) -> None:
                self.error.setText(text)
                self.state.setText("not connected")
                self.connect_button.setText("Connect")
                self.connect_button.setEnabled(True)

            self._opening = self.session.connect_bench(
                on_error=failed, on_open=lambda: self.connect_button.setEnabled(True))

    def _set_scene(self) -> None:
        if self.session.is_virtual:
            self.session.set_scene(self.scene.currentText(), on_error=self.error.setText)

    def rebuild(self) -> None:
        """One box per device when the set of open devices changed; while the bench
        process is down (:attr:`gui.session.Session.lost`) the boxes stay, disabled
        (their Reconnect included), and Restart bench is the one action offered."""
        lost = self.session.lost
        self.lost_box.setVisible(lost is not None)
        self.connect_button.setVisible(lost is None)
        if lost is not None:
            self.lost_label.setText(lost)
            for box in self.boxes.values():
                box.bench_down()
            self.state.setText("bench process stopped")
            return
        self.restart_button.setEnabled(True)
        self.restart_button.setText("Restart bench")
        devices = dict(self.session.devices)
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
        self.last_statuses = {}
        for index, (dev_id, dev) in enumerate(devices.items()):
            box = DeviceBox(dev, self.session.service, self.bench_key)
            self.inner_layout.insertWidget(index, box)
            self.boxes[dev_id] = box
        self.arrow_stage.clear()
        self.arrow_stage.addItems([k for k, b in self.boxes.items()
                                   if b.stage is not None and "x" in b.device.axes])
        known = {k: PolledDevice(d["status"], d["settings"], d["values"])
                 for k, d in self.session.device_states.items() if k in self.boxes}
        if known:  # pushed before the boxes were built
            self._show_status(known)
        self._show_count()

    def _show_count(self) -> None:
        n = len(self.boxes)
        if not n:
            self.state.setText("not connected")
            return
        states = [device_state(self.last_statuses.get(k, {"is_open": True}))
                  for k in self.boxes]
        bad = [k for k, s in zip(self.boxes, states, strict=True)
               if s in ("disconnected", "closed")]
        text = f"{n} devices: {n - len(bad)} open"
        if bad:
            text += f', <b style="color:#c00020">{len(bad)} disconnected ({", ".join(bad)})</b>'
        self.state.setText(text)

    def stage_box(self) -> DeviceBox | None:
        """The box of the stage the arrow keys move."""
        return self.boxes.get(self.arrow_stage.currentText())

    def stop_all_motion(self) -> list[Job]:
        """Stop every stage now (queued moves dropped)."""
        return [b.queue.stop() for b in self.boxes.values() if b.queue is not None]

    def on_event(self, event) -> None:
        """Show what the bench process pushed (a
        :class:`~instrument.bench.bench_service.BenchEvent`) in the device's box."""
        box = self.boxes.get(event.device)
        if box is None or self.session.lost is not None:
            return
        if event.kind == "status":
            data = event.data
            self._show_status({event.device: PolledDevice(data["status"], data["settings"],
                                                          data["values"])})
        elif event.kind == "settings":
            box.refresh_settings(values=event.data)
        elif event.kind == "positions" and box.stage is not None:
            box.stage.show_positions(event.data)

    def _show_status(self, polled: dict[str, PolledDevice]) -> None:
        for dev_id, p in polled.items():
            if dev_id in self.boxes:
                box = self.boxes[dev_id]
                box.show_status(p.status, p.settings)
                if p.values is not None:
                    box.refresh_settings(values=p.values)
        self.last_statuses.update({k: p.status for k, p in polled.items()})
        self._show_count()
        self.statuses.emit(polled)

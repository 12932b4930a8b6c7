"""The operator application: one window, one dock per panel, settings kept between sessions.

``diffuserlab gui [BENCH.toml] [--simulate]`` calls :func:`main`. The window holds a
:class:`~gui.session.Session` and the panels (``gui/panels/``): Devices on the left,
the Live view beside the task panels (Calibration, Alignment, Record, Results) and
the Log, each a dock the operator can move, float or tabify. The status bar keeps one
field per device (its state, red when disconnected) and a Stop-motion button. The
layout, the window's geometry, the last bench file and every field are stored with
:class:`PySide6.QtCore.QSettings` (:mod:`gui.fields`) and restored on the next start.

Keyboard: F5 starts or stops the live stream, F6 snaps a frame, Esc stops every
stage, Ctrl+Q quits; the arrow keys jog the chosen stage in x and y (Page Up/Down in
z) when no text field has the focus. Closing the window (or switching bench files)
while a run, a recording, an alignment or a batch is under way asks first; on yes,
the jobs are stopped and finished (the recording's summary written, its lock
released) before the devices close.
"""

from __future__ import annotations

import logging
import sys
import time

import pyqtgraph as pg
from PySide6.QtCore import QEvent, QObject, Qt, QTimer
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import (
    QAbstractItemView,
    QAbstractSpinBox,
    QApplication,
    QComboBox,
    QDockWidget,
    QFileDialog,
    QLabel,
    QLineEdit,
    QMainWindow,
    QMessageBox,
    QPlainTextEdit,
    QPushButton,
    QSlider,
    QTextEdit,
)

from .binding import BindingLeakError, check_binding
from .colorleak import install as install_color_fix
from .device_status import STATE_COLOURS, device_state, status_line
from .fields import flush, settings
from .gcthread import pin_to_gui_thread
from .logpane import LogPane, gui_log
from .memory import configure_allocator
from .panels.common import PanelScroll
from .session import Session
from .workers import settle_heap

__all__ = ["SWITCH_INTERVAL_S", "MainWindow", "configure", "main", "settings"]

log = logging.getLogger(__name__)

#: The interpreter's thread switch interval in the GUI process, s (Python's default is
#: 5 ms): the GUI thread takes the GIL back from busy workers (live reconstruction,
#: the virtual bench's rendering) sooner; measured with ``python -m soak.benchmark``.
SWITCH_INTERVAL_S = 0.0005

#: Dock titles, in tab order.
PANELS = ("Devices", "Live view", "Calibration", "Alignment", "Record", "Results", "Log")
#: Version of the stored dock layout (a layout stored by an older window is not
#: restored: the default layout is shown instead).
LAYOUT_VERSION = 2
#: The window's size at its first start (no stored geometry), px, on a screen with room
#: for it and its frame (:data:`FRAME_ROOM_PX`); on a smaller screen it opens maximized:
#: at the screen's available geometry, inside it.
FIRST_SIZE_PX = (1500, 950)
#: Room left around :data:`FIRST_SIZE_PX` for the window manager's frame and title, px.
FRAME_ROOM_PX = 40
#: Longest wait for the jobs to finish when the window closes, s.
CLOSE_TIMEOUT_S = 120.0
#: Arrow keys and the (axis, direction) they jog.
ARROW_KEYS = {Qt.Key.Key_Right: ("x", +1), Qt.Key.Key_Left: ("x", -1),
              Qt.Key.Key_Up: ("y", +1), Qt.Key.Key_Down: ("y", -1),
              Qt.Key.Key_PageUp: ("z", +1), Qt.Key.Key_PageDown: ("z", -1)}
#: Widgets that keep the arrow keys for themselves when they have the focus.
_EDITORS = (QLineEdit, QAbstractSpinBox, QComboBox, QSlider, QAbstractItemView,
            QPlainTextEdit, QTextEdit)


class _ArrowJog(QObject):
    """Application event filter: arrow keys jog the chosen stage (see the module
    docstring)."""

    def __init__(self, window: MainWindow) -> None:
        super().__init__(window)
        self.window = window

    def eventFilter(self, obj, event):  # noqa: N802 (Qt's name)
        if event.type() != QEvent.Type.KeyPress or event.key() not in ARROW_KEYS:
            return False
        if event.modifiers() not in (Qt.KeyboardModifier.NoModifier,
                                     Qt.KeyboardModifier.KeypadModifier):
            return False
        app = QApplication.instance()
        focus = app.focusWidget()
        if isinstance(focus, _EDITORS) or app.activeModalWidget() is not None:
            return False
        active = app.activeWindow()
        if active is not self.window and (active is None or active.parent() is not self.window):
            return False
        return self.window.arrow_jog(*ARROW_KEYS[event.key()])


class MainWindow(QMainWindow):
    """The window: a session and its panels as docks (see the module docstring).

    Parameters
    ----------
    session : Session
    """

    def __init__(self, session: Session) -> None:
        super().__init__()
        from .panels.alignment import AlignmentPanel
        from .panels.calibration import CalibrationPanel
        from .panels.devices import DevicePanel
        from .panels.live import LivePanel
        from .panels.record import RecordPanel
        from .panels.results import ResultsPanel

        self.session = session
        self._closing = False
        self._ready_to_close = False
        self.setWindowTitle(self._title())
        self.setDockOptions(QMainWindow.DockOption.AllowTabbedDocks
                            | QMainWindow.DockOption.AnimatedDocks)
        self.log_pane = LogPane()
        self.log_pane.install()
        self.devices = DevicePanel(session)
        self.live = LivePanel(session)
        self.calibration = CalibrationPanel(session)
        self.alignment = AlignmentPanel(session)
        self.record = RecordPanel(session, live_panel=self.live)
        self.results = ResultsPanel()
        self.record.result_ready.connect(self.show_result)
        self.live.psf_chosen.connect(self.record.take_psf)
        self.docks: dict[str, QDockWidget] = {}
        widgets = (self.devices, self.live, self.calibration, self.alignment, self.record,
                   self.results, self.log_pane)
        for title, widget in zip(PANELS, widgets, strict=True):
            dock = QDockWidget(title, self)
            dock.setObjectName(f"dock-{title}")
            if title in ("Devices", "Live view", "Log"):
                dock.setWidget(widget)
            else:  # a small screen scrolls a task panel instead of pushing the window off it
                dock.setWidget(PanelScroll(widget))
            self.docks[title] = dock
        self._default_layout()
        self._menus()
        self._status_area()
        session.message.connect(self.say)
        session.prompt.connect(self.ask)
        session.changed.connect(self._rebuild_status)
        self.devices.statuses.connect(self._show_statuses)
        self.arrows = _ArrowJog(self)
        QApplication.instance().installEventFilter(self.arrows)
        self.restore()

    def _title(self) -> str:
        bench = self.session.bench_path or "built-in simulated bench"
        return f"DiffuserLab - {bench}{' (simulated)' if self.session.simulate else ''}"

    def _default_layout(self) -> None:
        """Devices on the left; the Live view on top of the right side, beside (above)
        the task panels and the log, so the camera stays in view during a run."""
        d = self.docks
        self.devices.setMinimumWidth(540)
        self.addDockWidget(Qt.DockWidgetArea.LeftDockWidgetArea, d["Devices"])
        self.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, d["Live view"])
        self.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, d["Calibration"])
        self.splitDockWidget(d["Live view"], d["Calibration"], Qt.Orientation.Vertical)
        for title in ("Alignment", "Record", "Results", "Log"):
            self.tabifyDockWidget(d["Calibration"], d[title])
        d["Calibration"].raise_()
        self.resizeDocks([d["Live view"], d["Calibration"]], [480, 420],
                         Qt.Orientation.Vertical)
        self.resizeDocks([d["Devices"], d["Live view"]], [560, 940],
                         Qt.Orientation.Horizontal)

    def _menus(self) -> None:
        menu = self.menuBar().addMenu("&File")
        menu.addAction("Open bench file...", self.choose_bench)
        quit_action = QAction("Quit", self)
        quit_action.setShortcut(QKeySequence("Ctrl+Q"))
        quit_action.triggered.connect(self.close)
        menu.addAction(quit_action)
        acquire = self.acquire_menu = self.menuBar().addMenu("&Acquire")
        for text, key, slot in (("Start / stop live", "F5", self.live.toggle_stream),
                                ("Snap a frame", "F6", self.live.snap),
                                ("Stop all motion", "Esc", self.stop_all_motion)):
            action = QAction(text, self)
            action.setShortcut(QKeySequence(key))
            action.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
            action.triggered.connect(slot)
            acquire.addAction(action)
            self.addAction(action)
        view = self.menuBar().addMenu("&Panels")
        for dock in self.docks.values():
            view.addAction(dock.toggleViewAction())

    def _status_area(self) -> None:
        self.device_labels: dict[str, QLabel] = {}
        self.stop_button = QPushButton("Stop motion (Esc)")
        self.stop_button.setObjectName("stop-motion")
        self.stop_button.setStyleSheet("color: #b00020; font-weight: bold;")
        self.stop_button.clicked.connect(self.stop_all_motion)
        self.statusBar().addPermanentWidget(self.stop_button)
        self._rebuild_status()

    def _rebuild_status(self) -> None:
        devices = list(self.session.devices)
        if list(self.device_labels) == devices:
            return
        for label in self.device_labels.values():
            self.statusBar().removeWidget(label)
            label.deleteLater()
        self.device_labels = {}
        for dev_id in devices:
            label = QLabel(f"{dev_id}: open")
            label.setObjectName(f"status.{dev_id}")
            label.setStyleSheet("padding: 0 6px;")
            self.statusBar().insertPermanentWidget(len(self.device_labels), label)
            self.device_labels[dev_id] = label

    def _show_statuses(self, polled: dict) -> None:
        """The status bar's line per device, from the statuses the bench process pushed
        (:class:`gui.panels.devices.PolledDevice`)."""
        if not self.session.connected:
            return
        for dev_id, p in polled.items():
            label = self.device_labels.get(dev_id)
            box = self.devices.boxes.get(dev_id)
            if label is None or box is None:
                continue
            state = device_state(p.status)
            values = p.settings if state not in ("disconnected", "closed") else None
            colour = STATE_COLOURS.get(state, "#000")
            label.setText(f'<span style="color:{colour}">'
                          f'{status_line(dev_id, box.kind, p.status, values)}</span>')

    # -- messages and prompts ----------------------------------------------------------------
    def say(self, text: str) -> None:
        """A line in the status bar and the log pane."""
        self.statusBar().showMessage(text, 15000)
        gui_log.info("%s", text)

    def show_result(self, path: str, product: str | None = None) -> None:
        """Open ``path`` (a run's ``product``) in the Results panel, brought to the front."""
        self.results.open(path, product)
        self.docks["Results"].raise_()

    def ask(self, action: str, message: str, reply) -> None:
        """A plan's operator prompt (real bench): Done or Stop; asked and answered in
        the log."""
        gui_log.warning("the run asks: %s", message)
        box = QMessageBox(QMessageBox.Icon.Question, "operator action", message,
                          QMessageBox.StandardButton.Ok | QMessageBox.StandardButton.Abort,
                          self)
        box.button(QMessageBox.StandardButton.Ok).setText("Done")
        box.button(QMessageBox.StandardButton.Abort).setText("Stop the run")

        def answered(code: int) -> None:
            ok = code == QMessageBox.StandardButton.Ok
            gui_log.info("operator answered %s: %s", "Done" if ok else "Stop the run", action)
            try:
                reply(ok)
            except OSError as exc:  # the bench process is gone (disconnected, ended): its
                # run ended with it, there is no one left to answer
                gui_log.warning("the answer to '%s' was not delivered: the bench process is "
                                "gone (%s)", message, type(exc).__name__)

        box.finished.connect(answered)
        box.open()

    # -- actions -------------------------------------------------------------------------------
    def stop_all_motion(self) -> None:
        """Stop every stage now (Esc)."""
        jobs = self.devices.stop_all_motion()
        if jobs:
            self.say(f"stop: {len(jobs)} stage(s) stopped")

    def arrow_jog(self, axis: str, sign: int) -> bool:
        """Jog the chosen stage's ``axis`` one step (an arrow key); True if it moved."""
        box = self.devices.stage_box()
        if box is None or box.stage is None or axis not in box.device.axes:
            return False
        box.stage.jog(axis, sign)
        return True

    def busy_jobs(self) -> list[str]:
        """What would be lost or cut short by closing now (runs, recordings, batches)."""
        out = []
        if self.record.recording:
            out.append("a video recording")
        if self.calibration.running:
            out.append("a calibration run")
        if self.alignment.running:
            out.append("the mask alignment")
        if self.record.batch_running:
            out.append("a batch reconstruction")
        out += self.devices.bench_jobs.others()  # a notebook's recording, named with its owner
        return out

    def confirm(self, title: str, text: str) -> bool:
        """Ask the operator (Yes / No); tests replace this."""
        answer = QMessageBox.question(self, title, text, QMessageBox.StandardButton.Yes
                                      | QMessageBox.StandardButton.No,
                                      QMessageBox.StandardButton.No)
        return answer == QMessageBox.StandardButton.Yes

    def _confirm_stop(self, what: str) -> bool:
        busy = self.busy_jobs()
        if not busy:
            return True
        ok = self.confirm(what, f"{', '.join(busy).capitalize()} is under way. Stop "
                          f"{'it' if len(busy) == 1 else 'them'} and {what.lower()}? What "
                          "was acquired so far is kept.")
        gui_log.info("%s while %s: %s", what, ", ".join(busy), "yes" if ok else "no")
        return ok

    def stop_jobs(self) -> None:
        """Ask every job to stop (abort runs, stop the recording, cancel the batch)."""
        self.session.closing = True
        if self.session.job is not None:  # a bench still opening stops (homing included)
            self.session.job.cancel()
        self.calibration.control.abort("the GUI is closing")
        self.alignment.control.abort("the GUI is closing")
        self.record.cancel()
        self.live.stop_reconstruction()

    def _jobs_running(self) -> list:
        jobs = [self.record.record_job, self.record.batch_job, self.calibration.job,
                self.alignment.job, self.live.job]
        return [j for j in jobs if j is not None and j.running]

    def choose_bench(self) -> None:
        """Pick another bench file (asks first while a job runs; takes effect at the next
        Connect)."""
        path = QFileDialog.getOpenFileName(self, "bench file", "", "bench files (*.toml)")[0]
        if not path or not self._confirm_stop("Switch bench files"):
            return

        def switch() -> None:
            self.session.closing = False
            if self.session.connected:
                self.session.disconnect_bench()
            self.session.bench_path = path
            self.setWindowTitle(self._title())

        if self.busy_jobs():
            self.stop_jobs()
            self._when_idle(switch)
        else:
            switch()

    def _when_idle(self, then, deadline: float | None = None) -> None:
        """Call ``then()`` once no job runs (polled on the event loop, never blocking it);
        after :data:`CLOSE_TIMEOUT_S` regardless, naming what still ran."""
        deadline = time.monotonic() + CLOSE_TIMEOUT_S if deadline is None else deadline
        running = self._jobs_running()
        if running and time.monotonic() < deadline:
            self.statusBar().showMessage(
                "finishing: " + ", ".join(j.name for j in running) + " ...")
            QTimer.singleShot(100, lambda: self._when_idle(then, deadline))
            return
        if running:
            log.warning("still running after %.0f s: %s", CLOSE_TIMEOUT_S,
                        ", ".join(j.name for j in running))
        then()

    # -- persistence ---------------------------------------------------------------------------
    def restore(self) -> None:
        """Window geometry and dock layout of the last session (floating docks brought
        in front of the window once it shows)."""
        s = settings()
        geometry, state = s.value("window/geometry"), s.value("window/state")
        if geometry is None or not self.restoreGeometry(geometry):
            self.first_geometry()
        if state is not None:
            self.restoreState(state, LAYOUT_VERSION)

    def first_geometry(self) -> None:
        """The first start's size: :data:`FIRST_SIZE_PX`, placed by the window manager
        (centring it by hand put the bottom of a 1500x950 window and its title bar
        under a 1000 px screen's edge), or maximized (the screen's available geometry,
        the screen less its panels) when the screen is smaller: a 1366x768 laptop shows
        the whole window. (The offscreen platform, which draws for no screen, keeps
        :data:`FIRST_SIZE_PX`.)"""
        screen = self.screen() or QApplication.primaryScreen()
        width, height = FIRST_SIZE_PX
        if screen is None or QApplication.platformName() == "offscreen":
            self.resize(width, height)  # no screen anyone sees: the tests' drawing size
            return
        room = screen.availableGeometry()
        if (room.width() < width + FRAME_ROOM_PX
                or room.height() < height + FRAME_ROOM_PX):
            self.resize(min(width, room.width()), min(height, room.height()))
            self.move(room.topLeft())
            self.setWindowState(self.windowState() | Qt.WindowState.WindowMaximized)
            return
        self.resize(width, height)  # placed by the window manager, as it places any window

    def showEvent(self, event) -> None:  # noqa: N802 (Qt's name)
        super().showEvent(event)
        QTimer.singleShot(0, self.raise_floating_docks)

    def raise_floating_docks(self) -> None:
        """Floating docks in front of the main window (a restored one opened behind it)."""
        for dock in self.docks.values():
            if dock.isFloating() and dock.isVisible():
                dock.raise_()
                dock.activateWindow()

    def save(self) -> None:
        """Store the geometry, dock layout and bench file, and write every stored
        change (:func:`gui.fields.flush`; the window is closing)."""
        flush()
        s = settings()
        s.setValue("window/geometry", self.saveGeometry())
        s.setValue("window/state", self.saveState(LAYOUT_VERSION))
        if self.session.bench_path is not None:
            s.setValue("bench/last_file", self.session.bench_path)
        s.setValue("bench/simulate", self.session.simulate)
        s.sync()

    def closeEvent(self, event) -> None:  # noqa: N802 (Qt's name)
        if self._ready_to_close:
            self.log_pane.uninstall()
            QApplication.instance().removeEventFilter(self.arrows)
            super().closeEvent(event)
            return
        event.ignore()
        if self._closing or not self._confirm_stop("Quit"):
            return
        self._closing = True
        self.save()
        self.stop_jobs()
        self._when_idle(self._close_bench)

    def _close_bench(self) -> None:
        def closed() -> None:
            self._ready_to_close = True
            self.close()

        self.statusBar().showMessage("closing the devices ...")
        if self.session.disconnect_bench(then=closed) is None:
            # no bench: closed on the next pass (a close() inside the close being
            # refused here is ignored by Qt, and the window stayed open)
            QTimer.singleShot(0, closed)

    def shutdown(self) -> None:
        """Stop the jobs that hold the bench and close it, waiting here (scripts and
        tests; the window's own close does this without blocking the event loop)."""
        self.stop_jobs()
        for job in self._jobs_running():
            job.wait(CLOSE_TIMEOUT_S)
        job = self.session.disconnect_bench()
        if job is not None:
            job.wait(10.0)
        self.log_pane.uninstall()
        QApplication.instance().removeEventFilter(self.arrows)


def configure() -> None:
    """Process-wide settings of the GUI: row-major images, the thread switch interval,
    colours that do not leak references (:mod:`gui.colorleak`)."""
    pg.setConfigOptions(imageAxisOrder="row-major")
    install_color_fix()
    sys.setswitchinterval(SWITCH_INTERVAL_S)


def main(bench: str | None = None, *, simulate: bool = False, seed: int = 0,
         scene: str = "beads-flow", connect: bool = True) -> int:
    """Run the GUI until its window closes; returns the exit status.

    Parameters
    ----------
    bench : str, optional
        Bench TOML file; default the last one used (QSettings), or with ``simulate``
        the built-in simulated bench.
    simulate : bool
        The real-time virtual bench (no hardware).
    seed : int
        Seed of the virtual bench.
    scene : str
        ``simulate``: the moving scene in front of the camera (:data:`gui.session.SCENES`).
    connect : bool
        Connect to the bench at start.

    Raises
    ------
    gui.binding.BindingLeakError
        The installed PySide6 leaks references (the window would abort within minutes).
    """
    import faulthandler

    configure_allocator()  # before Qt and the workers start their threads (their heaps)
    faulthandler.enable()  # a crash in Qt or a C extension prints every thread's stack
    app = QApplication.instance() or QApplication(sys.argv[:1])
    app._collector = pin_to_gui_thread(app)  # Qt objects in cycles die on the GUI thread
    app.setOrganizationName("DiffuserLab")
    app.setApplicationName("gui")
    try:
        check_binding()
    except BindingLeakError as exc:
        QMessageBox.critical(None, "DiffuserLab", str(exc))
        raise
    configure()
    if bench is None and not simulate:
        bench = settings().value("bench/last_file")
        if bench is None:
            QMessageBox.critical(None, "DiffuserLab", "No bench file: start with `diffuserlab "
                                 "gui BENCH.toml`, or `diffuserlab gui --simulate` for the "
                                 "built-in simulated bench.")
            return 2
    window = MainWindow(Session(bench, simulate=simulate, seed=seed, scene=scene))
    settle_heap()  # the libraries and the window, out of the collector's full passes
    window.show()
    if connect:
        window.devices.toggle_connection()
    return app.exec()

"""The operator application: one window, one dock per panel, settings kept between sessions.

``diffuserlab gui [BENCH.toml] [--simulate]`` calls :func:`main`. The window holds a
:class:`~gui.session.Session` and the panels (``gui/panels/``): Devices, Live view,
Calibration, Alignment, Record and Results, each a dock the operator can move, float
or tabify; the layout, the window's geometry and the last bench file are stored with
:class:`PySide6.QtCore.QSettings` (organisation ``DiffuserLab``, application ``gui``)
and restored on the next start.
"""

from __future__ import annotations

import logging
import os
import sys

import pyqtgraph as pg
from PySide6.QtCore import QSettings, Qt
from PySide6.QtWidgets import (
    QApplication,
    QDockWidget,
    QFileDialog,
    QMainWindow,
    QMessageBox,
)

from .binding import BindingLeakError, check_binding
from .session import Session

__all__ = ["SWITCH_INTERVAL_S", "MainWindow", "configure", "main", "settings"]

log = logging.getLogger(__name__)

#: The interpreter's thread switch interval in the GUI process, s (Python's default is
#: 5 ms): the GUI thread takes the GIL back from busy workers (live reconstruction,
#: the virtual bench's rendering) sooner; measured with ``python -m gui.benchmark``.
SWITCH_INTERVAL_S = 0.0005

#: Dock titles, in tab order.
PANELS = ("Devices", "Live view", "Calibration", "Alignment", "Record", "Results")


def settings() -> QSettings:
    """The GUI's persistent settings (``DIFFUSERLAB_GUI_SETTINGS``: an INI file instead
    of the user's, for tests)."""
    path = os.environ.get("DIFFUSERLAB_GUI_SETTINGS")
    if path:
        return QSettings(path, QSettings.Format.IniFormat)
    return QSettings("DiffuserLab", "gui")


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
        self.setWindowTitle(self._title())
        self.setDockOptions(QMainWindow.DockOption.AllowTabbedDocks
                            | QMainWindow.DockOption.AnimatedDocks)
        self.devices = DevicePanel(session)
        self.live = LivePanel(session)
        self.calibration = CalibrationPanel(session)
        self.alignment = AlignmentPanel(session)
        self.record = RecordPanel(session, live_panel=self.live)
        self.results = ResultsPanel()
        self.record.result_ready.connect(self.show_result)
        self.docks: dict[str, QDockWidget] = {}
        widgets = (self.devices, self.live, self.calibration, self.alignment, self.record,
                   self.results)
        for title, widget in zip(PANELS, widgets, strict=True):
            dock = QDockWidget(title, self)
            dock.setObjectName(f"dock-{title}")
            dock.setWidget(widget)
            self.docks[title] = dock
        self.devices.setMinimumWidth(560)
        self.addDockWidget(Qt.DockWidgetArea.LeftDockWidgetArea, self.docks["Devices"])
        self.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, self.docks["Live view"])
        for title in PANELS[2:]:
            self.tabifyDockWidget(self.docks["Live view"], self.docks[title])
        self.docks["Live view"].raise_()
        menu = self.menuBar().addMenu("&File")
        menu.addAction("Open bench file...", self.choose_bench)
        menu.addAction("Quit", self.close)
        view = self.menuBar().addMenu("&Panels")
        for dock in self.docks.values():
            view.addAction(dock.toggleViewAction())
        session.message.connect(lambda text: self.statusBar().showMessage(text, 15000))
        session.prompt.connect(self.ask)
        self.resize(1500, 900)
        self.restore()

    def _title(self) -> str:
        bench = self.session.bench_path or "built-in simulated bench"
        return f"DiffuserLab - {bench}{' (simulated)' if self.session.simulate else ''}"

    def show_result(self, path: str, product: str | None = None) -> None:
        """Open ``path`` (a run's ``product``) in the Results panel, brought to the front."""
        self.results.open(path, product)
        self.docks["Results"].raise_()

    def choose_bench(self) -> None:
        """Pick another bench file (takes effect at the next Connect)."""
        path = QFileDialog.getOpenFileName(self, "bench file", "", "bench files (*.toml)")[0]
        if path:
            if self.session.connected:
                self.session.disconnect_bench()
            self.session.bench_path = path
            self.setWindowTitle(self._title())

    def ask(self, action: str, message: str, reply) -> None:
        """A plan's operator prompt (real bench): Done or Stop."""
        box = QMessageBox(QMessageBox.Icon.Question, "operator action", message,
                          QMessageBox.StandardButton.Ok | QMessageBox.StandardButton.Abort,
                          self)
        box.button(QMessageBox.StandardButton.Ok).setText("Done")
        box.button(QMessageBox.StandardButton.Abort).setText("Stop the run")
        box.finished.connect(lambda code: reply(code == QMessageBox.StandardButton.Ok))
        box.open()

    # -- persistence -----------------------------------------------------------------------
    def restore(self) -> None:
        """Window geometry and dock layout of the last session."""
        s = settings()
        geometry, state = s.value("window/geometry"), s.value("window/state")
        if geometry is not None:
            self.restoreGeometry(geometry)
        if state is not None:
            self.restoreState(state)

    def save(self) -> None:
        """Store the geometry, dock layout and bench file."""
        s = settings()
        s.setValue("window/geometry", self.saveGeometry())
        s.setValue("window/state", self.saveState())
        if self.session.bench_path is not None:
            s.setValue("bench/last_file", self.session.bench_path)
        s.setValue("bench/simulate", self.session.simulate)
        s.sync()

    def closeEvent(self, event) -> None:  # noqa: N802 (Qt's name)
        self.save()
        self.shutdown()
        super().closeEvent(event)

    def shutdown(self) -> None:
        """Stop the jobs that hold the bench (abort runs, stop live), then close it."""
        self.calibration.control.abort("the GUI is closing")
        self.alignment.control.abort("the GUI is closing")
        self.record.cancel()
        self.live.stop_reconstruction()
        job = self.session.disconnect_bench()
        if job is not None:
            job.wait(10.0)


def configure() -> None:
    """Process-wide settings of the GUI: row-major images, the thread switch interval."""
    pg.setConfigOptions(imageAxisOrder="row-major")
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
    """
    app = QApplication.instance() or QApplication(sys.argv[:1])
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
    window.show()
    if connect:
        window.devices.toggle_connection()
    return app.exec()

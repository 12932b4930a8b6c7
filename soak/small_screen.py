"""The window on a laptop's screen: its first start, and the bench process killed.

``python -m soak.small_screen OUT_DIR`` (under an X display with a window manager, e.g.
the 1366x768 Xvfb of ``tests/gui/test_small_screen.py``) opens the window on the
built-in simulated bench with no stored settings, prints its frame geometry and the
screen's available geometry as one JSON line (``geometry: {...}``), connects, starts
the stream, kills the bench process (SIGKILL) and, once the window says so, saves
``gui-bench-stopped.png`` (the window as the X server shows it, Restart bench in
view) and prints a second line (``bench-stopped: {...}``). Nothing is restarted.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import tempfile
from pathlib import Path

from gui.workers import wait_until

from .screenshots import _settle

__all__ = ["main"]


def _rect(r) -> list[int]:
    return [r.x(), r.y(), r.width(), r.height()]


def main(argv: list[str] | None = None) -> int:
    """Run the two steps (see the module docstring); returns the exit status."""
    argv = sys.argv[1:] if argv is None else argv
    out = Path(argv[0] if argv else ".")
    out.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("DIFFUSERLAB_GUI_SETTINGS",
                          str(Path(tempfile.mkdtemp(prefix="gui-small-")) / "gui.ini"))
    from PySide6.QtWidgets import QApplication

    from gui.app import MainWindow, configure
    from gui.session import Session

    app = QApplication.instance() or QApplication(sys.argv[:1])
    configure()
    w = MainWindow(Session(None, simulate=True, scene="none"))
    w.show()
    wait_until(app, lambda: w.isVisible() and w.windowHandle() is not None
               and w.windowHandle().isExposed(), 60.0, "the window to show")
    _settle(app, 1.5)  # the window manager's frame and maximize
    screen = w.screen()
    print("geometry: " + json.dumps({
        "platform": app.platformName(), "frame": _rect(w.frameGeometry()),
        "window": _rect(w.geometry()), "available": _rect(screen.availableGeometry()),
        "screen": _rect(screen.geometry())}), flush=True)
    try:
        w.devices.toggle_connection()
        wait_until(app, lambda: w.session.connected, 120.0, "the bench to open")
        w.live.toggle_stream()
        wait_until(app, lambda: w.session.streaming and w.session.frames_seen > 0, 60.0,
                   "the stream")
        pid = w.session.service._manager._process.pid
        os.kill(pid, signal.SIGKILL)
        wait_until(app, lambda: w.devices.restart_button.isVisible(), 60.0,
                   "the window to say the bench process stopped")
        w.docks["Devices"].raise_()
        w.raise_()
        _settle(app, 1.0)
        path = out / "gui-bench-stopped.png"
        if not app.primaryScreen().grabWindow(w.winId()).save(str(path)):
            raise RuntimeError(f"could not write {path}")
        button = w.devices.restart_button
        corner = button.mapTo(w, button.rect().bottomRight())
        print("bench-stopped: " + json.dumps({
            "png": str(path), "said": w.devices.lost_label.text(),
            "restart_in_window": w.rect().contains(corner)}), flush=True)
    finally:
        w.shutdown()
    return 0


if __name__ == "__main__":
    from gui.cli import exit_now

    exit_now(main())

"""The SLM window process: a frameless full-screen Qt window on one screen, showing
8-bit gray images pixel for pixel. Started by :class:`drivers.slm_window.FullscreenSlm`
as ``python -m drivers.slm_window_app SCREEN ROWS COLS`` (never imported by the driver:
Qt runs in this process only, so the caller needs no Qt event loop of its own).

Protocol on stdin/stdout (one JSON object per line; images as raw bytes):

- on start the process writes ``{"ready": {...screen facts...}}`` or ``{"error": "..."}``
  and exits;
- ``{"show": ID}`` followed by ``ROWS * COLS`` bytes (uint8, row-major): the image is
  painted unscaled at the window's origin, with R = G = B, then flushed to the window
  system; the process answers ``{"shown": ID}``;
- ``{"quit": true}`` or the end of stdin closes the window and exits;
- the screen disappearing (a monitor unplugged) writes ``{"error": "..."}`` and exits.

Pixel-exactness: the window must have the screen's size at a device pixel ratio of 1
and a colour depth of 24 bits or more (checked at start); the image is converted to
``QImage.Format_RGB32`` by replicating the gray value, which involves no dithering,
scaling or colour management.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time

import numpy as np

# pixel-exact: no scaling of the window by Qt's high-DPI logic
os.environ["QT_ENABLE_HIGHDPI_SCALING"] = "0"
os.environ["QT_SCALE_FACTOR"] = "1"
os.environ.setdefault("QT_QPA_PLATFORM", "xcb")

from PySide6 import QtCore, QtGui, QtWidgets  # noqa: E402 (after the environment)


def _write(obj: dict) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def _gray_to_rgb32(gray: np.ndarray) -> np.ndarray:
    """``(rows, cols)`` uint8 -> uint32 0xFFgggggg (Format_RGB32, R = G = B = gray)."""
    g = gray.astype(np.uint32)
    return np.ascontiguousarray(0xFF000000 | (g << 16) | (g << 8) | g)


class _Window(QtWidgets.QWidget):
    """Frameless window that paints its image at (0, 0), unscaled."""

    def __init__(self, rows: int, cols: int) -> None:
        super().__init__(None, QtCore.Qt.FramelessWindowHint | QtCore.Qt.WindowStaysOnTopHint)
        self.setAttribute(QtCore.Qt.WA_OpaquePaintEvent)
        self.setAttribute(QtCore.Qt.WA_NoSystemBackground)
        self.setCursor(QtCore.Qt.BlankCursor)
        self._pixels = _gray_to_rgb32(np.zeros((rows, cols), np.uint8))
        self._image = self._qimage(self._pixels)

    @staticmethod
    def _qimage(pixels: np.ndarray) -> QtGui.QImage:
        rows, cols = pixels.shape
        return QtGui.QImage(pixels.data, cols, rows, 4 * cols, QtGui.QImage.Format_RGB32)

    def set_gray(self, gray: np.ndarray) -> None:
        self._pixels = _gray_to_rgb32(gray)  # kept alive: the QImage shares its memory
        self._image = self._qimage(self._pixels)
        self.repaint()  # paints and flushes now, not at the next event-loop turn

    def paintEvent(self, event: QtGui.QPaintEvent) -> None:  # noqa: N802 (Qt's name)
        painter = QtGui.QPainter(self)
        painter.setCompositionMode(QtGui.QPainter.CompositionMode_Source)
        painter.drawImage(0, 0, self._image)
        painter.end()


class _Reader(QtCore.QObject):
    """Reads commands from stdin on its own thread; hands images to the GUI thread."""

    image = QtCore.Signal(int, object)
    finished = QtCore.Signal()

    def __init__(self, rows: int, cols: int) -> None:
        super().__init__()
        self._size = rows * cols
        self._shape = (rows, cols)

    def run(self) -> None:
        stdin = sys.stdin.buffer
        try:
            while True:
                line = stdin.readline()
                if not line:
                    break
                msg = json.loads(line)
                if "show" not in msg:
                    break
                data = stdin.read(self._size)
                if len(data) != self._size:
                    break
                gray = np.frombuffer(data, np.uint8).reshape(self._shape)
                self.image.emit(int(msg["show"]), gray)
        finally:
            self.finished.emit()


#: Seconds the window may take to be mapped and exposed by the X server: a pattern
#: painted before that is not on screen (a loaded machine answered "shown" to a first
#: pattern while the screen was still black).
EXPOSE_TIMEOUT_S = 10.0


def _wait_exposed(app: QtWidgets.QApplication, window: QtWidgets.QWidget,
                  timeout_s: float) -> bool:
    """Process events until ``window`` is exposed (mapped and visible on its screen),
    then paint it; False after ``timeout_s``."""
    handle = window.windowHandle()
    deadline = time.monotonic() + timeout_s
    waited = False
    while handle is None or not handle.isExposed():
        if time.monotonic() > deadline:
            return False
        waited = True
        app.processEvents(QtCore.QEventLoop.AllEvents, 50)
        time.sleep(0.005)
        handle = window.windowHandle()
    if waited:
        window.repaint()
    return True


def main(argv: list[str]) -> int:
    """Run the window: ``argv = [screen, rows, cols]``; returns the exit status."""
    screen_index, rows, cols = (int(v) for v in argv)
    app = QtWidgets.QApplication(["diffuserlab-slm"])
    screens = app.screens()
    if not 0 <= screen_index < len(screens):
        _write({"error": f"screen {screen_index} does not exist: the display has "
                f"{len(screens)} screen(s) ({[s.name() for s in screens]})"})
        return 2
    screen = screens[screen_index]
    geo = screen.geometry()
    facts = {"screen": screen_index, "name": screen.name(), "x": geo.x(), "y": geo.y(),
             "width": geo.width(), "height": geo.height(), "depth": screen.depth(),
             "device_pixel_ratio": screen.devicePixelRatio(), "refresh_hz": screen.refreshRate(),
             "platform": app.platformName(), "n_screens": len(screens)}
    problem = None
    if (geo.height(), geo.width()) != (rows, cols):
        problem = f"screen {screen_index} is {geo.height()} x {geo.width()} (rows x cols)"
    elif screen.devicePixelRatio() != 1.0:
        problem = f"screen {screen_index} has a device pixel ratio of {screen.devicePixelRatio()}"
    elif screen.depth() < 24:
        problem = f"screen {screen_index} has a colour depth of {screen.depth()} bits"
    if problem:
        _write({"error": problem, "facts": facts})
        return 2
    window = _Window(rows, cols)
    window.setScreen(screen)
    window.setGeometry(geo)
    window.showFullScreen()
    window.setGeometry(geo)  # no window manager (a bare X screen): place it ourselves
    window.repaint()
    app.processEvents()
    if not _wait_exposed(app, window, EXPOSE_TIMEOUT_S):
        _write({"error": f"the SLM window was not mapped on screen {screen_index} within "
                f"{EXPOSE_TIMEOUT_S:g} s (the X server or window manager did not show it)",
                "facts": facts})
        return 2

    def on_removed(gone: QtGui.QScreen) -> None:
        if gone is screen:
            _write({"error": f"screen {screen_index} ({facts['name']}) was removed"})
            app.exit(3)

    app.screenRemoved.connect(on_removed)
    reader = _Reader(rows, cols)

    def show(pattern_id: int, gray: np.ndarray) -> None:
        if not _wait_exposed(app, window, EXPOSE_TIMEOUT_S):  # hidden since (unmapped)
            _write({"error": f"the SLM window is not on screen {screen_index}: pattern "
                    f"{pattern_id} was not shown"})
            return
        window.set_gray(gray)
        app.sync()  # the X server has processed the drawing before we answer
        _write({"shown": pattern_id})

    reader.image.connect(show, QtCore.Qt.QueuedConnection)
    reader.finished.connect(app.quit, QtCore.Qt.QueuedConnection)
    thread = threading.Thread(target=reader.run, daemon=True, name="slm-stdin")
    _write({"ready": facts})
    thread.start()
    return app.exec()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

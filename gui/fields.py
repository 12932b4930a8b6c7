"""Nothing typed twice: the GUI's settings, and fields remembered across sessions.

:func:`settings` is the GUI's :class:`PySide6.QtCore.QSettings` (organisation
``DiffuserLab``, application ``gui``; ``DIFFUSERLAB_GUI_SETTINGS`` names an INI file
instead, for tests). :func:`remember` ties a field (line edit, combo box, spin box,
check box) to a key there: the field shows the stored value when the panel is built
and stores every change. :func:`bench_key` scopes values to one bench file (stored
stage positions and device presets belong to a bench).

Changes are stored with :func:`store` and written to the file by a thread of their
own, :data:`WRITE_DELAY_S` after the last change (and by :func:`flush` when the window
closes): a ``QSettings`` written on the GUI thread syncs its file there on the next
pass of the event loop, and a sync calls ``fdatasync`` twice (its lock file and the
file). In an hour of live view on the development machine (a virtual disk) the only
two stalls of the GUI thread over 100 ms (130 and 257 ms) came as a key reached a
remembered field. :func:`read` sees a stored value at once, written or not.

The writer never syncs a ``QSettings`` on the disk: PySide6 keeps the interpreter's
lock through ``QSettings.sync()``, so a sync that waits for a busy disk stops every
Python thread, the GUI thread's slots included (measured beside two disk writers: a
ticker thread stalled exactly as long as each sync, up to 93 ms, where ``os.fsync``
stalled it 10-14 ms; in run H4's operator day a 4.4 s freeze, faulthandler's look
showing the writer in ``sync``). It lets ``QSettings`` write the INI text to a staging
copy in memory-backed ``/dev/shm`` (no disk wait), then puts that text in place with
Python's I/O (``os.fsync`` and the rename release the lock), under an advisory lock
file beside the settings file (one writer at a time, across processes).
"""

from __future__ import annotations

import atexit
import json
import os
import threading
import time
from typing import Any

from PySide6.QtCore import QCoreApplication, QEvent, QObject, QSettings, Qt
from PySide6.QtWidgets import (
    QAbstractScrollArea,
    QAbstractSpinBox,
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFileDialog,
    QGraphicsView,
    QLineEdit,
    QSpinBox,
    QWidget,
)

__all__ = ["WRITE_DELAY_S", "bench_key", "choose_psf_path", "flush", "load_json", "read",
           "remember", "settings", "store", "store_json", "wheel_needs_focus"]

#: Seconds after the last change when the settings writer writes the file.
WRITE_DELAY_S = 0.5

_cache: dict[str | None, QSettings] = {}
_MISSING = object()


class _Writer:
    """The settings writer: pending values, and the thread that writes them."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.flushing = threading.Lock()
        self.pending: dict[tuple[str | None, str], Any] = {}
        #: Values this process wrote, as read() gives them (module docstring).
        self.written: dict[tuple[str | None, str], Any] = {}
        self.wake = threading.Event()
        self.thread: threading.Thread | None = None

    def put(self, path: str | None, key: str, value: Any) -> None:
        with self.lock:
            self.pending[(path, key)] = value
            if self.thread is None or not self.thread.is_alive():
                self.thread = threading.Thread(target=self._run, name="settings-writer",
                                               daemon=True)
                self.thread.start()
        self.wake.set()

    def _run(self) -> None:
        while True:
            self.wake.wait()
            while self.wake.is_set():  # until the changes pause for WRITE_DELAY_S
                self.wake.clear()
                time.sleep(WRITE_DELAY_S)
            self.flush()

    def flush(self) -> None:
        with self.flushing:
            with self.lock:
                items = dict(self.pending)
            if not items:
                return
            by_file: dict[str | None, dict[str, Any]] = {}
            for (path, key), value in items.items():
                by_file.setdefault(path, {})[key] = value
            for path, values in by_file.items():
                _write_settings(_file_name(path), values)
            with self.lock:
                for k, value in items.items():
                    if self.pending.get(k, _MISSING) is value:
                        del self.pending[k]
                        # read() keeps seeing it: the cached QSettings has not read the
                        # file written behind its back (QSettings.sync re-reads it)
                        self.written[k] = value

    def get(self, path: str | None, key: str) -> Any:
        with self.lock:
            value = self.pending.get((path, key), _MISSING)
            return self.written.get((path, key), _MISSING) if value is _MISSING else value


def _file_name(path: str | None) -> str:
    """The settings file's name: ``path``, else the GUI's default QSettings file."""
    return path if path else QSettings("DiffuserLab", "gui").fileName()


def _write_settings(file_name: str, values: dict[str, Any]) -> None:
    """Set ``values`` in the INI settings file ``file_name``: ``QSettings`` edits a
    copy in memory, :func:`instrument.atomic.update_file` puts it in place under the
    file's lock (module docstring)."""
    from instrument.atomic import update_file

    def edit(scratch) -> None:
        q = QSettings(str(scratch), QSettings.Format.IniFormat)
        for key, value in values.items():
            q.setValue(key, value)
        q.sync()  # in memory: no disk wait under the interpreter's lock
        status = q.status()
        del q
        if status != QSettings.Status.NoError:
            raise OSError(f"the settings could not be written to {scratch} ({status})")

    update_file(file_name, edit)


_writer = _Writer()
atexit.register(_writer.flush)


def _path() -> str | None:
    return os.environ.get("DIFFUSERLAB_GUI_SETTINGS") or None


def store(key: str, value: Any) -> None:
    """Store ``value`` under ``key``: :func:`read` returns it at once; the settings
    writer's thread writes it to the file (module docstring). Returns at once."""
    _writer.put(_path(), key, value)


def read(key: str, default: Any = None) -> Any:
    """The value stored under ``key`` (a change not yet written included), else
    ``default``."""
    value = _writer.get(_path(), key)
    if value is _MISSING:
        return settings().value(key, default)
    return value


def flush() -> None:
    """Write every stored change to the file now, on the calling thread (the window's
    close; tests)."""
    _writer.flush()


def settings() -> QSettings:
    """The GUI's persistent settings (one object per settings file in the process)."""
    path = os.environ.get("DIFFUSERLAB_GUI_SETTINGS") or None
    s = _cache.get(path)
    if s is None:
        s = (QSettings(path, QSettings.Format.IniFormat) if path
             else QSettings("DiffuserLab", "gui"))
        _cache[path] = s
    return s


def remember(widget: QWidget, key: str) -> QWidget:
    """Show the value stored under ``fields/KEY`` in ``widget`` and store each change.

    Parameters
    ----------
    widget : QLineEdit, QComboBox, QSpinBox, QDoubleSpinBox or QCheckBox
    key : str
        E.g. ``"live/psf"``.

    Returns
    -------
    QWidget
        ``widget`` (for chaining).
    """
    name = f"fields/{key}"
    stored = read(name)
    if isinstance(widget, QLineEdit):
        if stored is not None:
            widget.setText(str(stored))
            widget.setCursorPosition(0)
        widget.textChanged.connect(lambda text: store(name, text))
    elif isinstance(widget, QComboBox):
        if stored is not None:
            text = str(stored)
            if widget.isEditable() or widget.findText(text) >= 0:
                widget.setCurrentText(text)
        widget.currentTextChanged.connect(lambda text: store(name, text))
    elif isinstance(widget, QCheckBox):
        if stored is not None:
            widget.setChecked(str(stored).lower() in ("true", "1"))
        widget.toggled.connect(lambda on: store(name, bool(on)))
    elif isinstance(widget, QSpinBox | QDoubleSpinBox):
        if stored is not None:
            try:
                widget.setValue(type(widget.value())(float(stored)))
            except (TypeError, ValueError):
                pass
        widget.valueChanged.connect(lambda value: store(name, value))
    else:
        raise TypeError(f"cannot remember a {type(widget).__name__}")
    return widget


def choose_psf_path(parent: QWidget, file_title: str = "PSF image or stack") -> str:
    """Ask for a PSF: a run store's folder, else (cancelled) a file titled
    ``file_title``; the path chosen, or ``""`` when both dialogs were cancelled."""
    return QFileDialog.getExistingDirectory(parent, "PSF run store") or \
        QFileDialog.getOpenFileName(parent, file_title)[0]


def bench_key(bench_path: str | None, simulate: bool) -> str:
    """The settings group of one bench: its file (or the built-in simulated bench)."""
    where = os.path.abspath(bench_path) if bench_path else "built-in"
    return "bench/" + (where + (" simulated" if simulate else "")).replace("/", "|")


def load_json(key: str, default: Any) -> Any:
    """A JSON value stored under ``key`` (``default`` if none or unreadable)."""
    text = read(key)
    if text is None:
        return default
    try:
        return json.loads(str(text))
    except ValueError:
        return default


def store_json(key: str, value: Any) -> None:
    """Store ``value`` (JSON-able) under ``key``."""
    store(key, json.dumps(value))


class _WheelNeedsFocus(QObject):
    """Event filter: a wheel event over an unfocused field (its parent object, or a
    plot whose viewport is filtered) goes to the field's parent (the scroll area behind
    scrolls) instead of changing the field's value or zooming the plot."""

    def eventFilter(self, obj, event):  # noqa: N802 (Qt's name)
        owner = self.parent()
        if event.type() == QEvent.Type.Wheel and not owner.hasFocus():
            # to the scroll area behind, directly: an event sent (not spontaneous) is not
            # passed on from parent to parent as the X server's own is
            area = owner.parentWidget()
            while area is not None and not isinstance(area, QAbstractScrollArea):
                area = area.parentWidget()
            if area is not None:
                QCoreApplication.sendEvent(area.viewport(), event)
            return True
        return False


def wheel_needs_focus(widget: QAbstractSpinBox | QComboBox | QGraphicsView) -> QWidget:
    """Let ``widget`` take the mouse wheel only when it has the focus (clicked or tabbed
    to), so scrolling a panel over it never changes its value; a plot in a scrolling
    panel (a :class:`QGraphicsView`, e.g. pyqtgraph's PlotWidget) zooms only once it
    was clicked."""
    widget.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
    target = widget.viewport() if isinstance(widget, QGraphicsView) else widget
    target.installEventFilter(_WheelNeedsFocus(widget))
    return widget

"""Nothing typed twice: the GUI's settings, and fields remembered across sessions.

:func:`settings` is the GUI's :class:`PySide6.QtCore.QSettings` (organisation
``DiffuserLab``, application ``gui``; ``DIFFUSERLAB_GUI_SETTINGS`` names an INI file
instead, for tests). :func:`remember` ties a field (line edit, combo box, spin box,
check box) to a key there: the field shows the stored value when the panel is built
and stores every change. :func:`bench_key` scopes values to one bench file (stored
stage positions and device presets belong to a bench).
"""

from __future__ import annotations

import json
import os
from typing import Any

from PySide6.QtCore import QCoreApplication, QEvent, QObject, QSettings, Qt
from PySide6.QtWidgets import (
    QAbstractScrollArea,
    QAbstractSpinBox,
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QGraphicsView,
    QLineEdit,
    QSpinBox,
    QWidget,
)

__all__ = ["bench_key", "load_json", "remember", "settings", "store_json",
           "wheel_needs_focus"]

_cache: dict[str | None, QSettings] = {}


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
    s = settings()
    name = f"fields/{key}"
    stored = s.value(name)
    if isinstance(widget, QLineEdit):
        if stored is not None:
            widget.setText(str(stored))
            widget.setCursorPosition(0)
        widget.textChanged.connect(lambda text: s.setValue(name, text))
    elif isinstance(widget, QComboBox):
        if stored is not None:
            text = str(stored)
            if widget.isEditable() or widget.findText(text) >= 0:
                widget.setCurrentText(text)
        widget.currentTextChanged.connect(lambda text: s.setValue(name, text))
    elif isinstance(widget, QCheckBox):
        if stored is not None:
            widget.setChecked(str(stored).lower() in ("true", "1"))
        widget.toggled.connect(lambda on: s.setValue(name, bool(on)))
    elif isinstance(widget, QSpinBox | QDoubleSpinBox):
        if stored is not None:
            try:
                widget.setValue(type(widget.value())(float(stored)))
            except (TypeError, ValueError):
                pass
        widget.valueChanged.connect(lambda value: s.setValue(name, value))
    else:
        raise TypeError(f"cannot remember a {type(widget).__name__}")
    return widget


def bench_key(bench_path: str | None, simulate: bool) -> str:
    """The settings group of one bench: its file (or the built-in simulated bench)."""
    where = os.path.abspath(bench_path) if bench_path else "built-in"
    return "bench/" + (where + (" simulated" if simulate else "")).replace("/", "|")


def load_json(key: str, default: Any) -> Any:
    """A JSON value stored under ``key`` (``default`` if none or unreadable)."""
    text = settings().value(key)
    if text is None:
        return default
    try:
        return json.loads(str(text))
    except ValueError:
        return default


def store_json(key: str, value: Any) -> None:
    """Store ``value`` (JSON-able) under ``key``."""
    settings().setValue(key, json.dumps(value))


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

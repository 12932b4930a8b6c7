"""The log pane: operator prompts, warnings and errors of the session, in the window.

:class:`QtLogHandler` is a :class:`logging.Handler` on the root logger that hands the
records an operator should see (warnings and errors of every logger, and the GUI's
own information lines: connections, prompts and their answers, refusals shown in a
panel) to the GUI thread through a queued Qt signal; :class:`LogPane` shows them with
their time and level. A warning repeated with every frame (the automatic TV weight's
"too coarse" note, once per frame of a batch) shows once per job: the pane counts the
repeats of a message until :meth:`LogPane.new_job` starts the next job's count.
"""

from __future__ import annotations

import logging
import time

from PySide6.QtCore import QObject, Signal
from PySide6.QtGui import QTextCursor
from PySide6.QtWidgets import (
    QCheckBox,
    QHBoxLayout,
    QPlainTextEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

__all__ = ["LogPane", "QtLogHandler", "announce_job", "gui_log", "job_ended", "job_events"]

#: The logger of the GUI's own lines (what the operator did and was told).
gui_log = logging.getLogger("gui.operator")

#: Lines the pane keeps (older ones scroll away).
MAX_LINES = 5000


class _Bridge(QObject):
    record = Signal(object)


class _JobEvents(QObject):
    started = Signal(str)


#: ``job_events.started(name)`` when a long job starts (:func:`announce_job`); the log
#: pane starts counting repeated warnings afresh.
job_events = _JobEvents()


def announce_job(name: str, detail: str = "") -> None:
    """A long job (a run, a recording, a batch, an alignment) starts: a line in the
    log (``"NAME started: DETAIL"``, e.g. where it writes) and a fresh count of repeated
    warnings."""
    job_events.started.emit(name)
    gui_log.info("%s started%s", name, f": {detail}" if detail else "")


def job_ended(name: str, outcome: str, *, ok: bool = True) -> None:
    """A long job ended: its outcome and where its output is (``"NAME OUTCOME"``; a
    failure or a stop as a warning)."""
    (gui_log.info if ok else gui_log.warning)("%s %s", name, outcome)


class QtLogHandler(logging.Handler):
    """A logging handler whose records arrive on the GUI thread through
    ``handler.bridge.record(object)``.

    Emitting from any thread is safe: the signal is queued to the GUI thread.
    """

    def __init__(self, level: int = logging.INFO) -> None:
        super().__init__(level)
        self.bridge = _Bridge()

    def filter(self, record: logging.LogRecord) -> bool:  # noqa: A003 (logging's name)
        return record.levelno >= logging.WARNING or record.name.startswith("gui")

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.bridge.record.emit(record)
        except RuntimeError:  # the pane is gone (window closed)
            pass


class LogPane(QWidget):
    """The session's history of prompts, warnings and errors (see the module docstring).

    Attributes
    ----------
    lines : list of str
        The lines shown, oldest first: the last :data:`MAX_LINES` (up to 10 % more
        between trims), as the text view keeps them, so a day-long session's pane
        does not grow.
    repeats : dict
        ``{(logger, message template): times seen}`` in the current job.
    """

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.lines: list[str] = []
        self.repeats: dict[tuple[str, str], int] = {}
        layout = QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        self.text = QPlainTextEdit()
        self.text.setReadOnly(True)
        self.text.setMaximumBlockCount(MAX_LINES)
        self.text.setObjectName("log-text")
        layout.addWidget(self.text, 1)
        bar = QHBoxLayout()
        self.info = QCheckBox("show information lines")
        self.info.setChecked(True)
        bar.addWidget(self.info)
        bar.addStretch(1)
        clear = QPushButton("Clear")
        clear.clicked.connect(self.clear)
        bar.addWidget(clear)
        layout.addLayout(bar)
        self.handler = QtLogHandler()
        self.handler.bridge.record.connect(self.add_record)
        job_events.started.connect(self.new_job)

    def install(self) -> None:
        """Attach the handler to the root logger (warnings of every library reach it)."""
        root = logging.getLogger()
        if self.handler not in root.handlers:
            root.addHandler(self.handler)
        if root.level > logging.INFO or root.level == logging.NOTSET:
            root.setLevel(logging.INFO)

    def uninstall(self) -> None:
        logging.getLogger().removeHandler(self.handler)

    def new_job(self, name: str) -> None:
        """A long job starts: its warnings show once each again (:func:`announce_job`
        writes its line)."""
        self.repeats.clear()

    def add_record(self, record: logging.LogRecord) -> None:
        """Show ``record`` (a repeat of a warning in this job is counted, not shown)."""
        if record.levelno < logging.WARNING and not self.info.isChecked():
            return
        try:
            message = record.getMessage()
        except (TypeError, ValueError):
            message = str(record.msg)
        # a library's warning repeats with other numbers (its template is the key); the
        # GUI's own lines ("%s" filled with what happened) are each their own
        key = (record.name, message if record.name.startswith("gui") else str(record.msg))
        seen = self.repeats.get(key, 0)
        self.repeats[key] = seen + 1
        if seen and record.levelno < logging.ERROR:
            return
        stamp = time.strftime("%H:%M:%S", time.localtime(record.created))
        level = {logging.WARNING: "warning", logging.ERROR: "error",
                 logging.CRITICAL: "error"}.get(record.levelno, "")
        if not record.name.startswith("gui"):  # the library's words for code, in the GUI's
            from .messages import operator_text

            message = operator_text(message)
        if record.exc_info and record.levelno >= logging.ERROR:
            message += " (traceback in the terminal log)"
        line = f"{stamp} {level + ': ' if level else ''}{message}"
        self.lines.append(line)
        if len(self.lines) > MAX_LINES + MAX_LINES // 10:
            del self.lines[:-MAX_LINES]
        # every line with its colour: a plain line after a coloured one took its colour
        colour = {"warning": "#a06000", "error": "#b00020"}.get(level, "#000000")
        self.text.moveCursor(QTextCursor.MoveOperation.End)
        self.text.appendHtml(f'<span style="color:{colour}">{_escape(line)}</span>')

    def clear(self) -> None:
        self.text.clear()
        self.lines.clear()


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")

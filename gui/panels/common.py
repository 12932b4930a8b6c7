"""What several panels share: an image view, an error line, run controls."""

from __future__ import annotations

import pyqtgraph as pg
from PySide6.QtWidgets import QLabel, QPushButton

__all__ = ["RunControls", "error_label", "image_view"]


def image_view(title: str) -> pg.ImageView:
    """An image view with its histogram and level control, titled."""
    view = pg.ImageView(view=pg.PlotItem(title=title))
    view.ui.roiBtn.hide()
    view.ui.menuBtn.hide()
    view.setMinimumSize(320, 260)
    return view


def error_label() -> QLabel:
    """A wrapped, red label for the messages of refused actions."""
    label = QLabel("")
    label.setWordWrap(True)
    label.setStyleSheet("color: #b00020;")
    return label


class RunControls:
    """Start / Pause / Abort buttons of a panel running a procedure under a
    :class:`instrument.runner.RunControl` (``self.control``), which pauses and aborts it
    between steps. Mixed into the panel's class."""

    def _make_controls(self, start_text: str, start) -> list[QPushButton]:
        from instrument.runner import RunControl

        self.control = RunControl()
        self.start_button = QPushButton(start_text)
        self.start_button.clicked.connect(start)
        self.pause_button = QPushButton("Pause")
        self.pause_button.clicked.connect(self.toggle_pause)
        self.abort_button = QPushButton("Abort")
        self.abort_button.clicked.connect(self.abort)
        return [self.start_button, self.pause_button, self.abort_button]

    def _new_control(self):
        from instrument.runner import RunControl

        self.control = RunControl()
        return self.control

    def _set_running(self, running: bool) -> None:
        self.start_button.setEnabled(not running)
        self.pause_button.setEnabled(running)
        self.abort_button.setEnabled(running)
        self.pause_button.setText("Pause")

    def toggle_pause(self) -> None:
        """Pause before the next step, or continue."""
        if self.control.paused:
            self.control.resume()
            self.pause_button.setText("Pause")
        else:
            self.control.pause()
            self.pause_button.setText("Continue")

    def abort(self) -> None:
        """Stop before the next step (the data so far is kept)."""
        self.control.abort("aborted by the operator (GUI)")

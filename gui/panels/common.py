"""What several panels share: an image view, an error line, run controls."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtWidgets import QGraphicsView, QLabel, QPushButton

__all__ = ["FrameView", "RunControls", "error_label"]


class FrameView(pg.GraphicsLayoutWidget):
    """An image with axes and a title, beside its histogram and level control.

    Lighter than :class:`pyqtgraph.ImageView` for video: :meth:`setImage` only swaps the
    image (levels from the image when asked), and the histogram, which costs more than
    the image, is recomputed at most ``histogram_hz`` times per second (None: with
    every image).

    Attributes
    ----------
    image : ndarray or None
        The image shown.
    item : pyqtgraph.ImageItem
    plot : pyqtgraph.PlotItem
    histogram : pyqtgraph.HistogramLUTItem
    """

    def __init__(self, title: str, *, histogram_hz: float | None = None,
                 axes=("column (px)", "row (px)"), parent=None) -> None:
        super().__init__(parent)
        self.plot = self.addPlot()
        self.setTitle(title)
        self.plot.setLabel("bottom", axes[0])
        self.plot.setLabel("left", axes[1])
        self.plot.setAspectLocked(True)
        self.plot.invertY(True)
        self.item = pg.ImageItem()
        self.plot.addItem(self.item)
        self.histogram = pg.HistogramLUTItem()
        self.histogram.setImageItem(self.item)
        self.item.sigImageChanged.disconnect(self.histogram.imageChanged)
        self.addItem(self.histogram)
        # repaint only what changed (pyqtgraph repaints the whole view by default)
        self.setViewportUpdateMode(QGraphicsView.ViewportUpdateMode.MinimalViewportUpdate)
        self.image = None
        self._period_s = 0.0 if histogram_hz is None else 1.0 / histogram_hz
        self._last_histogram = -1e9
        self.setMinimumSize(320, 260)

    def setTitle(self, title: str) -> None:  # noqa: N802 (Qt's style)
        self.plot.setTitle(title, size="10pt")

    def setImage(self, image, autoLevels: bool = True) -> None:  # noqa: N802, N803
        """Show ``image`` (rows, cols); ``autoLevels``: levels from its 0.1 and 99.9
        percentiles (the histogram range follows). In video mode (``histogram_hz``)
        levels and histogram follow at most that often; between, the image is swapped
        alone, and the view is re-ranged only when the image's shape changes (every
        other part of the plot then stays as drawn)."""
        import time

        now = time.monotonic()
        due = now - self._last_histogram >= self._period_s
        reshaped = self.image is None or np.shape(self.image) != np.shape(image)
        self.image = image
        if autoLevels and (due or reshaped):
            lo, hi = np.percentile(image[::4, ::4], (0.1, 99.9))
            levels = (float(lo), float(hi) if hi > lo else float(lo) + 1.0)
            self.item.setImage(image, levels=levels)
            self.histogram.setLevels(*levels)
        else:
            self.item.setImage(image, autoLevels=False)
        if reshaped:
            self.plot.vb.autoRange(padding=0.02)
            self.plot.vb.disableAutoRange()
        if due or reshaped:
            self._last_histogram = now
            self.histogram.imageChanged(autoLevel=False, autoRange=autoLevels)


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

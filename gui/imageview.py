"""The image view of every panel, with the tools an operator expects from Micro-Manager
or napari: pixel readout, ROI statistics, line profile, auto levels, level lock,
colormap and "Save snapshot".

:class:`FrameView` is an image on a :class:`pyqtgraph.PlotItem` (axes in pixels, y
down) beside a :class:`pyqtgraph.HistogramLUTItem`, with a tool bar. The tools are
pyqtgraph's own: a :class:`pyqtgraph.RectROI` whose pixels give the statistics, a
:class:`pyqtgraph.LineSegmentROI` whose :meth:`~pyqtgraph.ROI.getArrayRegion` is the
profile, the histogram's level region, :func:`pyqtgraph.colormap.get` maps. A
snapshot is the image shown, as a TIFF (tifffile) whose JSON description holds its
metadata: the view's title, levels, colormap and ROI, the time, and what the panel
adds (device settings, the reconstruction's parameters, the run and frame).

For video, and for a run's frames stepped through with a slider, the view is light:
:meth:`FrameView.setImage` swaps the image and recomputes levels, histogram and ROI
statistics at most ``histogram_hz`` times a second; the last image of a burst gets its
own at the end of the period (a timer), so the view never rests on stale levels.

An image larger than the view on screen is drawn from every ``step``-th pixel of every
``step``-th row (:mod:`gui.display_grid`: image pixels per screen pixel, rounded down;
redrawn when the operator zooms or the view is resized), so a large sensor's frame costs
what the screen shows. :attr:`FrameView.image` stays the full-resolution array: the
pixel readout, the ROI statistics, the line profile, the levels and the snapshot read
it, through :attr:`FrameView.pixels`, the full-resolution pixel grid in the plot.
"""

from __future__ import annotations

import datetime as _dt
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QRectF, QTimer, Signal
from PySide6.QtWidgets import (
    QComboBox,
    QFileDialog,
    QGraphicsView,
    QHBoxLayout,
    QLabel,
    QToolBar,
    QVBoxLayout,
    QWidget,
)

from .display_grid import block_any, display_step
from .logpane import gui_log
from .workers import Job

__all__ = ["COLORMAPS", "LEVEL_MODES", "SNAPSHOT_FOLDER", "FrameView", "image_statistics"]

#: Where snapshots go unless the operator chose another folder (created when needed).
SNAPSHOT_FOLDER = "out/snapshots"
#: Colormaps offered (pyqtgraph's bundled maps; "grey" is the plain ramp).
COLORMAPS = ("grey", "viridis", "inferno", "magma", "plasma", "cividis", "turbo")
#: Automatic level modes: ``{label: (low percentile, high percentile)}``; 0/100 is min/max.
LEVEL_MODES = {"min/max": (0.0, 100.0), "0.1-99.9 %": (0.1, 99.9), "1-99 %": (1.0, 99.0),
               "5-95 %": (5.0, 95.0)}
#: The ROI statistics refresh at most this often on video, Hz.
ROI_HZ = 4.0
#: How long a note such as "snapshot saved" stays under the image (and in the window's
#: status bar), ms; the log pane keeps it.
NOTE_MS = 8000


def image_statistics(pixels: np.ndarray) -> dict[str, float]:
    """Mean, standard deviation, minimum, maximum, sum and count of ``pixels``.

    Parameters
    ----------
    pixels : ndarray
        Any shape; NaN pixels are left out.

    Returns
    -------
    dict
        ``{"mean", "std", "min", "max", "sum", "pixels"}`` (floats; NaN and 0 pixels
        for an empty selection).
    """
    a = np.asarray(pixels, np.float64).ravel()
    a = a[np.isfinite(a)]
    if not a.size:
        return {"mean": float("nan"), "std": float("nan"), "min": float("nan"),
                "max": float("nan"), "sum": 0.0, "pixels": 0}
    return {"mean": float(a.mean()), "std": float(a.std()), "min": float(a.min()),
            "max": float(a.max()), "sum": float(a.sum()), "pixels": int(a.size)}


class FrameView(QWidget):
    """An image with axes, histogram and the operator's tools (see the module docstring).

    Parameters
    ----------
    title : str
    histogram_hz : float, optional
        Video mode: levels, histogram and ROI statistics follow at most this often, and
        the newest image gets them at the end of the period (None: with every image).
    axes : (str, str)
        Axis labels (bottom, left).
    name : str
        Stem of the snapshot's default file name.

    Attributes
    ----------
    image : ndarray or None
        The image shown, at full resolution.
    item : pyqtgraph.ImageItem
        What is drawn: :attr:`image`, or every ``display_step``-th pixel of it.
    display_step : int
        The stride :attr:`item` is drawn at (1: every pixel).
    pixels : pyqtgraph.ImageItem
        :attr:`image`'s full-resolution pixel grid in the plot (never drawn): the ROI
        and the profile map to :attr:`image` through it.
    mask_item : pyqtgraph.ImageItem
        The overlay :meth:`mark` draws (the live view's saturated pixels).
    plot : pyqtgraph.PlotItem
    histogram : pyqtgraph.HistogramLUTItem
    roi : pyqtgraph.RectROI
        The statistics ROI (shown when the ROI tool is on).
    line : pyqtgraph.LineSegmentROI
        The profile line (shown when the profile tool is on).
    readout : QLabel
        The pixel under the cursor.
    stats : QLabel
        The ROI's statistics.
    metadata : callable or None
        ``metadata() -> dict`` added to a snapshot's description (set by the panel).

    Signals
    -------
    snapshot_saved(str)
        The path of a snapshot written.
    """

    snapshot_saved = Signal(str)

    def __init__(self, title: str, *, histogram_hz: float | None = None,
                 axes=("column (px)", "row (px)"), name: str = "image", parent=None) -> None:
        super().__init__(parent)
        self.name = name
        self.metadata: Callable[[], dict] | None = None
        self.image: np.ndarray | None = None
        self._title = title
        self._period_s = 0.0 if histogram_hz is None else 1.0 / histogram_hz
        self._last_histogram = -1e9
        self._last_roi = -1e9
        self._setting_levels = False
        self._follow = True
        self._catch_up = QTimer(self)
        self._catch_up.setSingleShot(True)
        self._catch_up.timeout.connect(self._refresh_levels)
        self.jobs: list[Job] = []
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(2)
        self.toolbar = QToolBar()
        self.toolbar.setStyleSheet("QToolBar { spacing: 2px; }")
        layout.addWidget(self.toolbar)
        self.glw = pg.GraphicsLayoutWidget()
        self.glw.setMinimumHeight(140)
        layout.addWidget(self.glw, 3)
        self.plot = self.glw.addPlot()
        self.setTitle(title)
        self.plot.setLabel("bottom", axes[0])
        self.plot.setLabel("left", axes[1])
        self.plot.setAspectLocked(True)
        self.plot.invertY(True)
        self.item = pg.ImageItem(axisOrder="row-major")
        self.plot.addItem(self.item)
        self.display_step = 1
        self.pixels = pg.ImageItem(axisOrder="row-major")
        self.pixels.setVisible(False)  # a coordinate grid only (left out of auto range)
        self.plot.addItem(self.pixels)
        self.mask_item = pg.ImageItem(axisOrder="row-major")
        self.mask_item.setZValue(10)
        self.plot.addItem(self.mask_item)
        self._mask: tuple[np.ndarray, tuple[int, int, int, int]] | None = None
        self._drawing = False
        self.plot.vb.sigRangeChanged.connect(self._view_changed)
        self.plot.vb.sigResized.connect(self._view_changed)
        self.histogram = pg.HistogramLUTItem()
        self.histogram.setImageItem(self.item)
        self.item.sigImageChanged.disconnect(self.histogram.imageChanged)
        self.histogram.region.sigRegionChangeFinished.connect(self._levels_dragged)
        self.glw.addItem(self.histogram)
        # repaint only what changed (pyqtgraph repaints the whole view by default)
        self.glw.setViewportUpdateMode(QGraphicsView.ViewportUpdateMode.MinimalViewportUpdate)
        self.roi = pg.RectROI((0, 0), (20, 20), pen=pg.mkPen("#00d0ff", width=2))
        self.roi.setZValue(20)
        self.roi.sigRegionChanged.connect(lambda *_: self._update_roi(force=True))
        self.line = pg.LineSegmentROI([(0, 0), (20, 20)], pen=pg.mkPen("#ffd000", width=2))
        self.line.setZValue(20)
        self.line.sigRegionChanged.connect(lambda *_: self._update_profile())
        self.profile_plot = pg.PlotWidget()
        self.profile_plot.setLabel("bottom", "distance along the line (px)")
        self.profile_plot.setMinimumHeight(70)
        self.profile_plot.setMaximumHeight(140)
        self.profile_curve = self.profile_plot.plot([], [], pen=pg.mkPen("#d09000", width=2))
        self.profile_plot.hide()
        layout.addWidget(self.profile_plot, 1)
        info = QHBoxLayout()
        self.readout = QLabel("")
        self.readout.setMinimumWidth(170)
        self.stats = QLabel("")
        self.stats.setWordWrap(True)
        info.addWidget(self.readout)
        info.addWidget(self.stats, 1)
        layout.addLayout(info)
        self._make_tools()
        self.glw.scene().sigMouseMoved.connect(self._mouse_moved)
        self.setMinimumSize(240, 200)

    # -- the tool bar ----------------------------------------------------------------------
    def _make_tools(self) -> None:
        tb = self.toolbar
        self.roi_action = tb.addAction("ROI", self.show_roi)
        self.roi_action.setCheckable(True)
        self.roi_action.setToolTip("a rectangle whose pixels' statistics show below the image")
        self.profile_action = tb.addAction("Profile", self.show_profile)
        self.profile_action.setCheckable(True)
        self.profile_action.setToolTip("a line whose profile shows below the image")
        tb.addSeparator()
        self.auto_action = tb.addAction("Auto", self.auto_levels)
        self.auto_action.setToolTip("auto levels: from the image now, in the mode beside "
                                    "(and unlocked)")
        self.level_mode = QComboBox()
        self.level_mode.addItems(list(LEVEL_MODES))
        self.level_mode.setCurrentText("0.1-99.9 %")
        self.level_mode.setToolTip("automatic levels: the image's min/max, or percentiles")
        self.level_mode.activated.connect(lambda _: self.auto_levels())
        tb.addWidget(self.level_mode)
        self.lock_action = tb.addAction("Lock")
        self.lock_action.setCheckable(True)
        self.lock_action.setToolTip("lock the levels: new images keep them (dragging the "
                                    "histogram's region locks them too)")
        tb.addSeparator()
        self.colormap = QComboBox()
        self.colormap.addItems(COLORMAPS)
        self.colormap.setToolTip("colormap")
        self.colormap.currentTextChanged.connect(self.set_colormap)
        tb.addWidget(self.colormap)
        self.snapshot_action = tb.addAction("Snapshot...", self.choose_snapshot)
        self.snapshot_action.setToolTip("save a snapshot: the image shown as a TIFF with its "
                                        "metadata (device settings, time, reconstruction "
                                        "parameters)")

    @property
    def levels_locked(self) -> bool:
        """True while new images keep the current levels."""
        return self.lock_action.isChecked()

    def lock_levels(self, locked: bool = True) -> None:
        """Keep (or let follow) the levels for new images."""
        self.lock_action.setChecked(bool(locked))

    def levels(self) -> tuple[float, float]:
        """The levels (black, white) in the image's units."""
        lo, hi = self.item.getLevels() if self.item.getLevels() is not None else (0.0, 1.0)
        return float(lo), float(hi)

    def _levels_of(self, image: np.ndarray) -> tuple[float, float]:
        lo_p, hi_p = LEVEL_MODES[self.level_mode.currentText()]
        step = max(1, int(np.ceil(np.sqrt(image.size / 65536))))  # at most ~65536 pixels
        sample = image[::step, ::step]
        finite = sample[np.isfinite(sample)] if sample.dtype.kind == "f" else sample
        if not np.size(finite):
            return 0.0, 1.0
        if (lo_p, hi_p) == (0.0, 100.0):
            lo, hi = float(np.min(finite)), float(np.max(finite))
        else:
            lo, hi = (float(v) for v in np.percentile(finite, (lo_p, hi_p)))
        return lo, (hi if hi > lo else lo + 1.0)

    def _set_levels(self, levels: tuple[float, float]) -> None:
        self._setting_levels = True
        try:
            self.item.setLevels(levels)
            self.histogram.setLevels(*levels)
        finally:
            self._setting_levels = False

    def _levels_dragged(self, *_) -> None:
        if not self._setting_levels:  # the operator moved the histogram's region
            self.lock_levels(True)

    def auto_levels(self) -> None:
        """Levels from the image shown, in the chosen mode; new images follow again."""
        self.lock_levels(False)
        if self.image is not None:
            self._set_levels(self._levels_of(self.image))
            self._histogram(auto_range=True)

    def set_colormap(self, name: str) -> None:
        """Show the image through colormap ``name`` (:data:`COLORMAPS`)."""
        if name not in COLORMAPS:
            raise ValueError(f"colormap {name!r}: use one of {', '.join(COLORMAPS)}")
        if self.colormap.currentText() != name:
            self.colormap.setCurrentText(name)  # comes back here through the signal
            return
        cmap = pg.ColorMap(None, [(0, 0, 0), (255, 255, 255)]) if name == "grey" else \
            pg.colormap.get(name)
        self.histogram.gradient.setColorMap(cmap)

    # -- image -----------------------------------------------------------------------------
    def setTitle(self, title: str) -> None:  # noqa: N802 (Qt's style)
        self._title = title
        self.plot.setTitle(title, size="10pt")

    def title(self) -> str:
        return self._title

    def clear(self) -> None:
        """Show nothing."""
        self._catch_up.stop()
        self.item.clear()
        self.mark(None)
        self.image = None

    def setImage(self, image, autoLevels: bool = True) -> None:  # noqa: N802, N803
        """Show ``image`` (rows, cols).

        ``autoLevels``: levels from the image in the chosen mode (:data:`LEVEL_MODES`)
        unless they are locked. In video mode (``histogram_hz``) levels, histogram and
        ROI statistics follow at most that often: between, the image is swapped alone
        and the newest one gets them when the period ends. The view is re-ranged only
        when the image's shape changes. An image larger than the view on screen is drawn
        at a stride (:attr:`display_step`); :attr:`image` keeps it whole.
        """
        now = time.monotonic()
        due = now - self._last_histogram >= self._period_s
        reshaped = self.image is None or np.shape(self.image) != np.shape(image)
        self.image = image
        self._follow = autoLevels and not self.levels_locked
        if reshaped:
            self.view_all()
        else:
            self._draw(self.display_step)
        if due or reshaped:
            self._catch_up.stop()
            self._refresh_levels()
        else:
            self._update_roi()
            if not self._catch_up.isActive():
                wait_s = self._last_histogram + self._period_s - now
                self._catch_up.start(max(1, int(np.ceil(1e3 * wait_s))))
        if self.profile_action.isChecked():
            self._update_profile()

    def view_all(self) -> None:
        """Range the view on the whole image (*View All*): a new result is shown whole,
        not at the last one's zoom."""
        if self.image is None:
            return
        rows, cols = np.shape(self.image)[:2]
        pad = 1.04  # autoRange's padding of 0.02 each side
        self._draw(display_step((pad * cols, pad * rows), self._view_px()))
        self._drawing = True
        try:
            self.plot.vb.autoRange(padding=0.02)
            self.plot.vb.disableAutoRange()
        finally:
            self._drawing = False
        self._view_changed()

    def _view_px(self) -> tuple[float, float]:
        ratio = self.glw.devicePixelRatioF()
        return self.plot.vb.width() * ratio, self.plot.vb.height() * ratio

    def _step_now(self) -> int:
        (x0, x1), (y0, y1) = self.plot.vb.viewRange()
        return display_step((x1 - x0, y1 - y0), self._view_px())

    def _draw(self, step: int) -> None:
        """Hand pyqtgraph :attr:`image` at ``step`` (the levels follow before the paint),
        placed over the full-resolution grid, with the mark's overlay."""
        self._drawing = True
        try:
            self.display_step = step
            shown = self.image if step == 1 else self.image[::step, ::step]
            self.item.setImage(shown, autoLevels=False)
            rows, cols = shown.shape[:2]
            self.item.setRect(QRectF(0, 0, cols * step, rows * step))
            if self._mask is not None:
                self._draw_mask()
        finally:
            self._drawing = False

    def _view_changed(self, *_) -> None:
        """Zoomed, panned or resized: draw again when the stride changes."""
        if self._drawing or self.image is None:
            return
        step = self._step_now()
        if step != self.display_step:
            self._draw(step)

    def mark(self, mask: np.ndarray | None, rgba: tuple[int, int, int, int] = (255, 0, 0,
                                                                                255)) -> None:
        """Colour the pixels of :attr:`image` where ``mask`` is set (an overlay on the
        grid the image is drawn at: a block is coloured when any of its pixels is);
        None or an empty mask removes the overlay.

        Parameters
        ----------
        mask : ndarray of bool, (rows, cols), or None
            :attr:`image`'s shape.
        rgba : tuple of 4 int
            The colour, 0-255.
        """
        if mask is None or not mask.any():
            if self._mask is not None:
                self.mask_item.clear()
            self._mask = None
            return
        self._mask = (mask, tuple(rgba))
        self._draw_mask()

    def _draw_mask(self) -> None:
        mask, rgba = self._mask
        on_grid = block_any(mask, self.display_step)
        overlay = np.zeros(on_grid.shape + (4,), np.uint8)
        overlay[on_grid] = rgba
        self.mask_item.setImage(overlay, autoLevels=False)
        self.mask_item.setTransform(self.item.transform())

    def _refresh_levels(self) -> None:
        """Levels (unless locked or not asked for), histogram and ROI statistics of the
        image shown: with each image, or in video mode at most once a period (the
        newest image of a burst at the period's end)."""
        if self.image is None:
            return
        self._last_histogram = time.monotonic()
        follow = self._follow and not self.levels_locked
        if follow:
            self._set_levels(self._levels_of(self.image))
        self._histogram(auto_range=follow)
        self._update_roi(force=True)

    def _histogram(self, auto_range: bool) -> None:
        self._setting_levels = True
        try:
            self.histogram.imageChanged(autoLevel=False, autoRange=auto_range)
        finally:
            self._setting_levels = False

    # -- pixel readout ---------------------------------------------------------------------
    def _mouse_moved(self, pos) -> None:
        if self.image is None or not self.plot.sceneBoundingRect().contains(pos):
            self.readout.setText("")
            return
        p = self.plot.vb.mapSceneToView(pos)  # image pixels, whatever the drawn stride
        self.readout.setText(self.pixel_text(p.x(), p.y()))

    def pixel_text(self, x: float, y: float) -> str:
        """``"x 12, y 40: 1023"``: the pixel at image coordinates (x = column, y = row),
        or ``""`` outside the image."""
        if self.image is None:
            return ""
        col, row = int(np.floor(x)), int(np.floor(y))
        rows, cols = self.image.shape[:2]
        if not (0 <= row < rows and 0 <= col < cols):
            return ""
        v = self.image[row, col]
        value = (f"{v:.5g}" if np.ndim(v) == 0 and np.issubdtype(np.asarray(v).dtype,
                                                                   np.floating)
                 else str(v.tolist() if np.ndim(v) else v))
        return f"x {col}, y {row}: {value}"

    # -- ROI and profile -------------------------------------------------------------------
    def show_roi(self, on: bool | None = None) -> None:
        """Show (or hide) the statistics ROI; placed over the image's centre quarter the
        first time."""
        on = self.roi_action.isChecked() if on is None else bool(on)
        self.roi_action.setChecked(on)
        if on and self.roi.scene() is None:
            self.plot.addItem(self.roi)
            if self.image is not None:
                rows, cols = self.image.shape[:2]
                self.roi.setPos((cols / 4, rows / 4), finish=False)
                self.roi.setSize((cols / 2, rows / 2), finish=False)
        elif not on and self.roi.scene() is not None:
            self.plot.removeItem(self.roi)
            self.stats.setText("")
        self._update_roi(force=True)

    def roi_statistics(self) -> dict[str, float] | None:
        """Statistics of the ROI's pixels (:func:`image_statistics`) and its bounds
        (``x``, ``y``, ``width``, ``height`` in px); None when the ROI is off."""
        if not self.roi_action.isChecked() or self.image is None or self.roi.scene() is None:
            return None
        pixels = self.roi.getArrayRegion(self.image, self.pixels, order=0)
        out = image_statistics(pixels)
        (x, y), (w, h) = self.roi.pos(), self.roi.size()
        out.update(x=float(x), y=float(y), width=float(w), height=float(h))
        return out

    def _update_roi(self, force: bool = False) -> None:
        now = time.monotonic()
        if not self.roi_action.isChecked() or (not force and self._period_s
                                                and now - self._last_roi < 1.0 / ROI_HZ):
            return
        self._last_roi = now
        s = self.roi_statistics()
        if s is None:
            return
        self.stats.setText(
            f"ROI {s['width']:.0f} x {s['height']:.0f} px at ({s['x']:.0f}, {s['y']:.0f}): "
            f"mean {s['mean']:.5g}, std {s['std']:.4g}, min {s['min']:.5g}, max "
            f"{s['max']:.5g}, sum {s['sum']:.5g}")

    def show_profile(self, on: bool | None = None) -> None:
        """Show (or hide) the profile line and its plot; across the image's middle the
        first time."""
        on = self.profile_action.isChecked() if on is None else bool(on)
        self.profile_action.setChecked(on)
        if on and self.line.scene() is None:
            self.plot.addItem(self.line)
            if self.image is not None:
                rows, cols = self.image.shape[:2]
                self.set_line((cols * 0.1, rows / 2), (cols * 0.9, rows / 2))
        elif not on and self.line.scene() is not None:
            self.plot.removeItem(self.line)
        self.profile_plot.setVisible(on)
        self._update_profile()

    def profile(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(distance_px, values)`` along the profile line; None when it is off."""
        if not self.profile_action.isChecked() or self.image is None or \
                self.line.scene() is None:
            return None
        # LineSegmentROI maps (x, y) to the data's axes itself: x is the column axis of
        # a row-major image (pyqtgraph swaps them only for the rectangular ROIs)
        values = np.asarray(self.line.getArrayRegion(self.image, self.pixels, axes=(1, 0),
                                                     order=1), np.float64)
        return np.arange(values.size, dtype=np.float64), values  # samples 1 px apart

    def set_line(self, start: tuple[float, float], end: tuple[float, float]) -> None:
        """Place the profile line from ``start`` to ``end`` (x = column, y = row)."""
        h0, h1 = self.line.getHandles()
        self.line.movePoint(h0, self.line.mapFromParent(pg.Point(*start)), finish=False)
        self.line.movePoint(h1, self.line.mapFromParent(pg.Point(*end)))

    def _update_profile(self) -> None:
        prof = self.profile()
        if prof is not None:
            self.profile_curve.setData(*prof)

    # -- snapshot --------------------------------------------------------------------------
    def snapshot_metadata(self) -> dict[str, Any]:
        """What a snapshot records: the view's title, levels, colormap, ROI (with its
        statistics), the time, and the panel's :attr:`metadata`."""
        meta: dict[str, Any] = {
            "title": self._title, "time_utc": _dt.datetime.now(_dt.UTC).isoformat(),
            "levels": list(self.levels()), "colormap": self.colormap.currentText(),
            "levels_locked": self.levels_locked}
        roi = self.roi_statistics()
        if roi is not None:
            meta["roi"] = roi
        if self.metadata is not None:
            meta.update(self.metadata())
        return meta

    def default_snapshot_name(self) -> str:
        return f"{self.name}-{_dt.datetime.now():%Y%m%d-%H%M%S}.tif"

    def choose_snapshot(self) -> Job | None:
        """Take the image shown and its metadata now (the click), then ask for a file
        name and :meth:`save_snapshot` what was taken: a live view keeps streaming while
        the dialog is open, and the snapshot is the frame that was on screen at the
        click. The folder is remembered; the default, ``out/snapshots``, is created (a
        folder that cannot be made is said under the image, and the dialog opens in the
        working directory)."""
        from .fields import read, store

        if self.image is None:
            self.stats.setText("no image to save yet")
            return None
        taken = (np.array(self.image, copy=True), self.snapshot_metadata())
        folder = Path(str(read("snapshots/folder", SNAPSHOT_FOLDER)))
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            self.stats.setText(f"snapshot folder {folder} cannot be made ({exc.strerror}); "
                               f"choose a folder in the dialog")
            folder = Path.cwd()
        path = QFileDialog.getSaveFileName(self, "save snapshot (TIFF with metadata)",
                                           str(folder / self.default_snapshot_name()),
                                           "TIFF (*.tif *.tiff)")[0]
        if not path:
            return None
        store("snapshots/folder", str(Path(path).parent))
        return self.save_snapshot(path, taken=taken)

    def note(self, text: str, timeout_ms: int | None = None) -> None:
        """Show ``text`` under the image and in the window's status bar for
        ``timeout_ms`` (default :data:`NOTE_MS`), then clear it (unless something else
        was shown meanwhile)."""
        timeout_ms = NOTE_MS if timeout_ms is None else int(timeout_ms)
        self.stats.setText(text)
        bar = getattr(self.window(), "statusBar", None)
        if callable(bar):
            bar().showMessage(text, timeout_ms)
        QTimer.singleShot(timeout_ms, self, lambda: self.stats.text() == text
                          and self.stats.setText(""))

    def save_snapshot(self, path: str | Path,
                      taken: tuple[np.ndarray, dict[str, Any]] | None = None) -> Job | None:
        """Write the image shown and :meth:`snapshot_metadata` (or ``taken``: an image
        and its metadata taken earlier) to ``path`` on a worker
        (:func:`instrument.writer.files.write_snapshot`);
        the result or the refusal shows under the image."""
        if taken is None:
            if self.image is None:
                self.stats.setText("no image to save yet")
                return None
            taken = (np.array(self.image, copy=True), self.snapshot_metadata())
        from instrument.writer.files import write_snapshot

        image, meta = taken
        job = Job(lambda job: write_snapshot(path, image, meta), name="snapshot",
                  owner=self)
        job.succeeded.connect(lambda p: (self.note(f"snapshot saved: {p}"),
                                         gui_log.info("snapshot of %s saved: %s",
                                                      self._title, p),
                                         self.snapshot_saved.emit(str(p))))
        job.failed.connect(lambda text: self.stats.setText(f"snapshot not saved: {text}"))
        self.jobs = [j for j in self.jobs if j.running] + [job]
        return job.start()

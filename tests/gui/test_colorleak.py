"""pyqtgraph's colours without NumPy's leak of references to None (gui.colorleak)."""

from __future__ import annotations

import gc
import sys

import numpy as np
import pytest

pg = pytest.importorskip("pyqtgraph")

from gui import colorleak  # noqa: E402


def _none_drift(call, n: int = 500) -> float:
    call()
    gc.collect()
    before = sys.getrefcount(None)
    for _ in range(n):
        call()
    gc.collect()
    return (sys.getrefcount(None) - before) / n


@pytest.fixture
def fixed(qapp):
    assert colorleak.install(force=True)
    return pg.functions.mkColor


COLOURS = [(200, 200, 200), (0, 0, 0, 100), [10, 20, 30], (1.7, 2.2, 250.9),
           (np.float64(3.0), np.int32(4), 5), (float("nan"), 3, float("inf"), 7),
           "#00d0ff", "r", 0.5, 7, (3, 9)]


@pytest.mark.parametrize("colour", COLOURS, ids=repr)
def test_colours_are_the_ones_pyqtgraph_makes(fixed, colour):
    original = getattr(fixed, colorleak._PATCH_ATTR)
    assert fixed(colour).getRgb() == original(colour).getRgb()


def test_component_colours_are_the_ones_pyqtgraph_makes(fixed):
    original = getattr(fixed, colorleak._PATCH_ATTR)
    assert fixed(1, 2, 3).getRgb() == original(1, 2, 3).getRgb()
    assert fixed(1, 2, 3, 4).getRgb() == original(1, 2, 3, 4).getRgb()
    with pytest.raises(TypeError):
        fixed((1, 2, 3, 4, 5))


def test_install_is_idempotent_and_reaches_every_caller(fixed):
    import pyqtgraph.colormap as colormap

    assert colorleak.install() and colorleak.installed()
    assert pg.mkColor is fixed and colormap.mkColor is fixed
    assert not hasattr(getattr(fixed, colorleak._PATCH_ATTR), colorleak._PATCH_ATTR)


def test_numpy_leak_is_measured():
    """The probe counts what np.dtype(tuple) keeps: about one per call, or none."""
    leaked = colorleak.numpy_leaks(300)
    assert leaked >= 290 or abs(leaked) < 10, leaked


def test_pens_curves_and_histogram_keep_no_reference_to_none(fixed):
    """A tuple pen, a curve's setData and the histogram's repaint (every frame in the
    live view) kept one reference to None each on the NumPy versions with the leak."""
    original = getattr(fixed, colorleak._PATCH_ATTR)
    if colorleak.numpy_leaks() >= 100:  # the test measures something: unfixed leaks
        assert _none_drift(lambda: original((200, 200, 200))) > 0.9
    assert abs(_none_drift(lambda: pg.mkPen((200, 200, 200)))) < 0.02
    assert abs(_none_drift(lambda: pg.mkBrush((0, 0, 0, 100)))) < 0.02
    curve = pg.PlotDataItem()
    x, y = np.arange(100.0), np.linspace(0, 1, 100)
    assert abs(_none_drift(lambda: curve.setData(x, y))) < 0.02
    widget = pg.GraphicsLayoutWidget()
    image = pg.ImageItem()
    widget.addViewBox().addItem(image)
    histogram = pg.HistogramLUTItem()
    histogram.setImageItem(image)
    widget.addItem(histogram)
    widget.resize(300, 200)
    frame = np.random.default_rng(0).random((64, 64)).astype(np.float32)
    assert abs(_none_drift(lambda: (image.setImage(frame), widget.grab()), 100)) < 0.05

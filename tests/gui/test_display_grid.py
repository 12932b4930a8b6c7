"""A frame larger than its view is drawn at the screen's resolution (offscreen), while
the pixel readout, the ROI statistics, the line profile, the levels, the saturation
mark and the snapshot keep the full-resolution frame."""

from __future__ import annotations

import numpy as np
import pytest

from gui.display_grid import block_any, display_step

ROWS, COLS = 1200, 1600  # a sensor several times the view's size on screen


@pytest.fixture
def big(qapp):
    from gui.imageview import FrameView

    v = FrameView("large sensor", name="large")
    v.resize(500, 400)
    v.show()
    qapp.processEvents()
    rng = np.random.default_rng(3)
    image = rng.integers(0, 4000, (ROWS, COLS), dtype=np.uint16)
    image[601, 803] = 4095  # between two drawn pixels at any stride > 1
    v.setImage(image)
    yield v, image
    v.deleteLater()


def _on_screen_px(v) -> tuple[float, float]:
    ratio = v.glw.devicePixelRatioF()
    return v.plot.vb.width() * ratio, v.plot.vb.height() * ratio


def test_the_array_drawn_is_no_larger_than_the_view(big):
    v, image = big
    drawn = v.item.image
    w, h = _on_screen_px(v)
    assert v.display_step > 1
    assert drawn.shape[1] <= 2 * w and drawn.shape[0] <= 2 * h  # < 2 drawn px a screen px
    assert np.array_equal(drawn, image[::v.display_step, ::v.display_step])
    assert v.image is image  # the full frame is kept
    # drawn over the full-resolution grid: the image spans the sensor's pixels
    rect = v.item.mapRectToParent(v.item.boundingRect())
    assert rect.width() == pytest.approx(COLS, abs=v.display_step)
    assert rect.height() == pytest.approx(ROWS, abs=v.display_step)


def test_readout_roi_and_profile_read_the_full_resolution_frame(big):
    v, image = big
    from PySide6.QtCore import QPointF

    assert v.pixel_text(803.5, 601.2) == "x 803, y 601: 4095"
    v._mouse_moved(v.plot.vb.mapViewToScene(QPointF(803.5, 601.2)))  # the cursor there
    assert v.readout.text() == "x 803, y 601: 4095"
    v.show_roi(True)
    v.roi.setPos((801, 599))
    v.roi.setSize((5, 4))
    s = v.roi_statistics()
    block = image[599:603, 801:806]
    assert s["pixels"] == block.size == 20 and s["max"] == 4095
    assert s["mean"] == pytest.approx(block.mean())
    v.show_profile(True)
    v.set_line((790.0, 601.0), (820.0, 601.0))  # along row 601, through the bright pixel
    dist, values = v.profile()
    assert values.size == 30 and values == pytest.approx(image[601, 790:820], abs=1e-3)


def test_zooming_in_draws_every_pixel_again(big, qapp):
    v, image = big
    v.plot.vb.setRange(xRange=(790, 830), yRange=(590, 620), padding=0)
    qapp.processEvents()
    assert v.display_step == 1 and v.item.image.shape == image.shape
    v.setImage(image + 1)  # the next frame too, at the zoom
    assert v.display_step == 1 and np.array_equal(v.item.image, image + 1)
    v.plot.vb.autoRange()
    qapp.processEvents()
    assert v.display_step > 1


def test_the_saturation_mark_shows_a_pixel_between_drawn_ones(big):
    v, image = big
    mask = image >= 4095
    v.mark(mask)
    overlay = v.mask_item.image
    k = v.display_step
    assert overlay.shape[:2] == v.item.image.shape[:2]
    assert overlay[601 // k, 803 // k].tolist() == [255, 0, 0, 255]
    assert int((overlay[..., 3] > 0).sum()) == int(block_any(mask, k).sum())
    v.mark(np.zeros_like(mask))
    assert v.mask_item.image is None


def test_the_snapshot_is_the_full_resolution_frame(big, wait, tmp_path):
    import tifffile

    v, image = big
    job = v.save_snapshot(tmp_path / "snap.tif")
    wait(lambda: job.done, 30, "the snapshot")
    assert np.array_equal(tifffile.imread(tmp_path / "snap.tif"), image)


def test_display_step_and_block_any():
    assert display_step((1600, 1200), (500, 400)) == 3
    assert display_step((1600, 1200), (2000, 1500)) == 1  # the view is larger
    assert display_step((40, 30), (500, 400)) == 1  # zoomed in
    assert display_step((1600, 1200), (0, 0)) == 1  # not laid out yet
    mask = np.zeros((7, 5), bool)
    mask[4, 4] = True
    on_grid = block_any(mask, 3)
    assert on_grid.shape == (3, 2) and on_grid[1, 1] and on_grid.sum() == 1
    assert block_any(mask, 1) is mask


def test_the_benchmark_phase_of_large_frames_reports_its_figures(qapp):
    """``python -m soak.benchmark --large-frame``: the phase shows frames and reports
    the lateness and the GUI thread's CPU time per frame (values not judged)."""
    from soak.benchmark import large_frame_lateness

    out = large_frame_lateness((600, 800), seconds=1.0)
    assert out["shape"] == [600, 800] and out["frames_shown"] > 0 and out["firings"] > 0
    assert out["cpu_ms_per_frame"] > 0 and out["max_ms"] >= out["p99_ms"] >= 0


def test_a_phase_without_a_sample_says_so_instead_of_crashing():
    """A phase in which the timer fired fewer than twice (the GUI thread held off a core
    for the whole phase) reports "no sample" (np.percentile of an empty sample raised)."""
    import numpy as np

    from soak.benchmark import _line, _summary

    out = _summary(np.array([]), 0.5, 1.0)
    assert out["firings"] == 0 and out["p99_ms"] is None and "no sample" in out["sample"]
    assert "no sample" in _line("idle", out)


def test_a_phase_waits_for_its_firings_when_the_gui_thread_is_held(qapp):
    """The GUI thread held past the whole phase: the phase goes on until the timer has
    fired (it waits on the firings, not on the clock alone)."""
    import threading

    from PySide6.QtCore import QTimer

    from soak.benchmark import measure_lateness

    released = threading.Event()
    # hold the event loop for longer than the phase: no firing within its 0.1 s
    QTimer.singleShot(0, lambda: released.wait(0.5))
    lateness = measure_lateness(qapp, 0.1, until=lambda firings: firings >= 3)
    assert lateness.size >= 2

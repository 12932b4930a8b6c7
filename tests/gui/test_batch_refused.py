"""A batch whose frames are all refused (a dim video: no signal in any frame) ends
with one operator-level message saying why, and Results shows neither an "unexpected
error" nor the previous product's image; a new product is shown whole (issue 67)."""

from __future__ import annotations

import logging
import os

import numpy as np
import pytest

from recon.io import DATA_ORIENTATION

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

NO_SIGNAL = ("the data carry no signal: the frame's energy is {:.2f}x what its noise alone "
             "would give (Poisson-Gaussian model fitted to the frame); check the exposure, "
             "the light source and the lens cap, or the dark frame")


def _run(path, n=3):
    """A run with a product holding every frame (``recon_old``) and one holding none
    (``recon_auto``: every frame refused)."""
    from instrument.runs.runstore import RunStore

    store = RunStore.create(path, plan_name="video", plan_params={},
                            points=[{"t": float(k)} for k in range(n)],
                            frame_tags=[["frame"]] * n, frame_shape=(12, 16),
                            frame_dtype=np.uint16, coord_names=["exposure_s"])
    for i in range(n):
        store.write_frame(i, np.full((12, 16), 100 + i, np.uint16), {"exposure_s": 0.01})
    for name in ("recon_old", "recon_auto"):
        store.create_frame_product(name, n, (12, 16), np.float32,
                                   orientation=DATA_ORIENTATION)
    for i in range(n):
        store.write_product_frame("recon_old", i, np.ones((12, 16), np.float32))
    store.update_attrs(status="complete")
    return store


@pytest.fixture
def record(record_panel):
    return record_panel


def test_every_frame_refused_is_one_operator_message_and_no_product_shown(record,
                                                                           caplog):
    failed = [f"frame {i} (point 0): " + NO_SIGNAL.format(0.5 + 0.01 * i) for i in range(3)]
    shown = []
    record.result_ready.connect(lambda run, product: shown.append(product))
    with caplog.at_level(logging.WARNING, logger="gui.operator"):
        record.on_batch_done("v.zarr", {
            "product": "recon_auto", "reconstructed": 0, "skipped": 0, "cancelled": False,
            "seconds": 6.0, "fps": 0.0, "workers": 1, "failed": failed, "damaged": []})
    text = record.batch_error.text()
    assert text.startswith("3 of 3 frames refused, none reconstructed: frames 0-2: the "
                           "data carry no signal"), text
    assert "bug" not in text and "Traceback" not in text
    assert "no frame reconstructed" in record.batch_status.text()
    assert not shown  # Results is not handed an empty product
    logged = [r.getMessage() for r in caplog.records]
    assert all(any(line in m for m in logged) for line in failed)  # each frame's reason


def test_some_frames_refused_are_said_and_the_product_shown(record):
    shown = []
    record.result_ready.connect(lambda run, product: shown.append(product))
    record.on_batch_done("v.zarr", {
        "product": "recon_auto", "reconstructed": 9, "skipped": 0, "cancelled": False,
        "seconds": 6.0, "fps": 1.5, "workers": 1, "damaged": [],
        "failed": ["frame 4 (point 1): the raw is constant (every pixel 100)"]})
    assert record.batch_error.text().startswith("1 of 10 frames refused: frame 4: the raw "
                                                "is constant")
    assert "1 refused" in record.batch_status.text() and shown == ["recon_auto"]


def test_results_says_an_empty_product_plainly_and_drops_the_old_image(qapp, wait,
                                                                       tmp_path):
    from gui.panels.results import ResultsPanel

    _run(tmp_path / "v.zarr")
    panel = ResultsPanel()
    try:
        job = panel.open(str(tmp_path / "v.zarr"))
        wait(lambda: job.done, 30, "the run")
        job = panel.show_product("recon_old")
        wait(lambda: job.done, 30, "the product")
        assert panel.volume is not None and panel.view.image is not None
        job = panel.show_product("recon_auto")
        wait(lambda: job.done, 30, "the empty product")
        text = panel.error.text()
        assert "holds no reconstructed frame" in text, text
        assert "unexpected" not in text and "bug" not in text
        assert panel.volume is None and panel.view.image is None
    finally:
        panel.close()
        panel.deleteLater()


def test_a_new_product_is_shown_whole_not_at_the_last_zoom(qapp, wait, tmp_path):
    from gui.panels.results import ResultsPanel

    _run(tmp_path / "v.zarr")
    panel = ResultsPanel()
    panel.resize(600, 500)
    panel.show()
    try:
        job = panel.open(str(tmp_path / "v.zarr"))
        wait(lambda: job.done, 30, "the run")
        job = panel.show_product("recon_old")
        wait(lambda: job.done, 30, "the product")
        vb = panel.view.plot.vb
        whole = vb.viewRange()
        vb.setRange(xRange=(2, 4), yRange=(2, 4), padding=0)  # the operator zooms in
        assert vb.viewRange()[0][1] < whole[0][1] - 5
        job = panel.open(str(tmp_path / "v.zarr"), product="recon_old")
        wait(lambda: job.done and panel.job.done and panel.volume is not None, 30,
             "the product again")
        (x0, x1), (y0, y1) = vb.viewRange()
        assert x0 <= 0 and x1 >= 16 and y0 <= 0 and y1 >= 12, vb.viewRange()
    finally:
        panel.close()
        panel.deleteLater()

"""Everything an operator needs is reachable without scrolling at 1600 x 1000 (the
run controls of every task panel, also after a run has shown its frames and its
message), and the window fits a 1366 x 768 laptop screen (its panels scroll there)."""

from __future__ import annotations

import pytest
from PySide6.QtWidgets import QScrollArea


def _in_view(widget) -> bool:
    """``widget`` wholly inside the viewport of every scroll area it sits in."""
    parent = widget.parentWidget()
    while parent is not None:
        if isinstance(parent, QScrollArea):
            port = parent.viewport()
            top = widget.mapTo(port, widget.rect().topLeft())
            bottom = widget.mapTo(port, widget.rect().bottomRight())
            if top.y() < 0 or top.x() < 0 or bottom.y() > port.height() or \
                    bottom.x() > port.width():
                return False
        parent = parent.parentWidget()
    return widget.isVisible()


def _controls(w) -> dict:
    cal, al, rec = w.calibration, w.alignment, w.record
    return {"Calibration": [cal.start_button, cal.pause_button, cal.abort_button,
                            cal.progress, cal.status],
            "Alignment": [al.start_button, al.pause_button, al.abort_button, al.progress],
            "Record": [rec.record_button, rec.record_progress, rec.batch_button,
                       rec.batch_progress]}


def _check_all_in_view(qapp, w) -> None:
    for dock, widgets in _controls(w).items():
        w.docks[dock].raise_()
        qapp.processEvents()
        hidden = [type(x).__name__ for x in widgets if not _in_view(x)]
        assert not hidden, f"{dock}: {hidden} need a scroll at {w.size().toTuple()}"


@pytest.fixture
def layout(window, qapp):
    """The window in its default layout at 1600 x 1000, put back afterwards."""
    size = window.size()
    window.resize(1600, 1000)
    window._default_layout()
    qapp.processEvents()
    yield window
    window.resize(size)
    qapp.processEvents()


def test_run_controls_stay_in_view_after_a_run_at_1600x1000(layout, qapp, wait, tmp_path):
    w = layout
    _check_all_in_view(qapp, w)
    cal = w.calibration
    cal.routine.setCurrentText("dark")
    cal.fields["dark"]["--frames"].setText("2")
    cal.out.setText(str(tmp_path / "a-long-folder-name-as-operators-use" / "dark.zarr"))
    w.docks["Calibration"].raise_()
    job = cal.start()
    wait(lambda: job.done, 120, "the dark run")
    qapp.processEvents()
    assert cal.result is not None and cal.result.status == "complete"
    _check_all_in_view(qapp, w)  # the frame shown and the message pushed them out


def test_the_window_fits_a_laptop_screen(layout):
    hint = layout.minimumSizeHint()
    assert hint.width() <= 1366 and hint.height() <= 768 - 40, hint.toTuple()

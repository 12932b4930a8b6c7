"""An aborted run is numbered alike in the window and the terminal ("point 2 of 4"; the
terminal said "point 1/4"), and the window's words name no function (issue 67)."""

from __future__ import annotations

import logging

from gui.messages import operator_text
from instrument.acquisition.runner import RunControl, Runner
from instrument.devices.virtual_bench import VirtualBench
from tests.instrument.test_runner import ZStepPlan


def test_the_abort_is_numbered_alike_and_read_in_operator_words(tmp_path, caplog):
    control = RunControl()

    def on_event(e):
        if e.kind == "point_done":
            control.abort("stop after the first point")

    with caplog.at_level(logging.WARNING, logger="instrument.acquisition.runner"), \
            VirtualBench(seed=3) as vb:
        result = Runner(vb, on_event=on_event, control=control).run(ZStepPlan(),
                                                                     tmp_path / "r.zarr")
    window = f"at point {result.points_done + 1} of {result.points_total}"  # the panel's
    terminal = [r.getMessage() for r in caplog.records if "aborted" in r.getMessage()]
    assert window == "at point 2 of 4" and window in terminal[0], terminal
    shown = operator_text(terminal[0])  # the log pane's line
    assert "Runner(" not in shown and "press Resume run" in shown, shown


def test_driver_calls_read_as_operator_words():
    for text in ("snap() while streaming: call stop_stream() first",
                 "already streaming: call stop_stream() before a new stream"):
        shown = operator_text(text)
        assert "()" not in shown and "Stop stream on the Live panel" in shown, shown

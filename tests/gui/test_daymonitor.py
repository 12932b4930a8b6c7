"""The operator's day's monitor: lateness per phase, and the watchdog that tells what
the GUI thread ran when it was late (our code, or the event loop waiting for a core)."""

from __future__ import annotations

import time


def _held_up_in_a_slot(seconds: float) -> None:
    time.sleep(seconds)  # stands for work done on the GUI thread


def test_watchdog_names_what_held_the_gui_thread(qapp, wait):
    from PySide6.QtCore import QTimer

    from gui.daymonitor import DayMonitor
    from gui.soak import summarise

    monitor = DayMonitor(sample_s=0.2)
    monitor.start()
    monitor.set_phase("busy")
    QTimer.singleShot(100, lambda: _held_up_in_a_slot(0.4))
    t0 = time.monotonic()
    wait(lambda: time.monotonic() - t0 > 1.0, 5, "a second")
    monitor.set_phase("idle")
    t0 = time.monotonic()
    wait(lambda: time.monotonic() - t0 > 0.5, 5, "half a second")
    monitor.stop()
    report = monitor.report()
    assert report["phases"]["busy"]["max_ms"] > 300
    assert report["stalls"], report["slow_events"]
    stall = report["stalls"][0]
    assert stall["phase"] == "busy"
    assert any("_held_up_in_a_slot" in f for f in stall["gui_stack"]), stall
    figures = summarise({**report, "crashed": False, "records": []})
    assert figures["stalls"][0][0].startswith("busy: ")
    assert "_held_up_in_a_slot" in figures["stalls"][0][0]
    assert not figures["goals_met"]["max_ms"]

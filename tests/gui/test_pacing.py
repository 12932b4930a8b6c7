"""The live view shows fewer images a second while the window falls behind, and counts
the frames it did not show (a clock of the test's own: no verdict depends on the
machine's load)."""

from __future__ import annotations

import time
import types

import numpy as np
import pytest

from gui.pacing import SLOWEST_S, DisplayPacer


def _ticks(pacer: DisplayPacer, times) -> list[bool]:
    return [pacer.tick(t) for t in times]


def test_on_time_every_tick_shows():
    pacer = DisplayPacer(0.05)
    assert all(_ticks(pacer, np.arange(40) * 0.05))
    assert pacer.period_s == 0.05 and pacer.ticks_skipped == 0


def test_a_late_tick_halves_the_rate_and_time_on_time_restores_it():
    pacer = DisplayPacer(0.05, recover_s=2.0)
    assert pacer.tick(0.0)
    assert pacer.tick(0.12)  # a whole tick late: shown, the rate halves
    assert pacer.period_s == pytest.approx(0.1)
    shown = _ticks(pacer, 0.12 + 0.05 * np.arange(1, 9))
    assert shown == [False, True] * 4 and pacer.ticks_skipped == 4
    t = 0.12 + 0.05 * 8
    for _ in range(5):  # late again and again: down to the slowest rate
        t += 0.3
        pacer.tick(t)
    assert pacer.period_s == SLOWEST_S and pacer.rate_hz == pytest.approx(5.0)
    times = t + 0.05 * np.arange(1, 121)  # 6 s on time: back to every tick
    _ticks(pacer, times)
    assert pacer.period_s == pytest.approx(0.05)
    assert all(_ticks(pacer, times[-1] + 0.05 * np.arange(1, 6)))


def test_a_pause_starts_afresh():
    pacer = DisplayPacer(0.05)
    pacer.tick(0.0)
    pacer.tick(0.12)
    assert pacer.period_s > 0.05
    assert pacer.tick(5.0) and pacer.period_s == 0.05  # the panel was hidden 5 s


def test_the_live_view_counts_the_frames_it_did_not_show(window, monkeypatch):
    from drivers.camera import Frame
    from gui.panels import live as live_module

    live = window.live
    assert live.isVisible()
    clock = [100.0]
    monkeypatch.setattr(live_module, "time", types.SimpleNamespace(monotonic=lambda: clock[0]))
    live.timer.stop()  # the test ticks
    try:
        live.pacer = DisplayPacer(live_module.TICK_MS / 1000.0)
        before = live.frames_not_shown

        def tick(t: float, index: int) -> None:
            image = np.full((32, 40), index, np.uint16)
            window.session.show_frame(Frame(image, index, 0.0, 0.0, 0.01, 0.0, 0))
            clock[0] = t
            live._tick()  # the timer's slot

        tick(100.0, 9001)
        assert live._shown_raw == 9001
        tick(100.12, 9002)  # late: shown, and the rate halves
        tick(100.17, 9003)  # on time but within the longer period: not shown
        assert live._shown_raw == 9002 and live.raw_view.image[0, 0] == 9002
        tick(100.22, 9004)
        assert live._shown_raw == 9004 and live.raw_view.image[0, 0] == 9004
        assert live.frames_not_shown - before == 1
        text = live._shown_text()
        assert "at most 10 a second while the window catches up" in text
        assert f"not shown {live.frames_not_shown}" in text
    finally:
        live.pacer = DisplayPacer(live_module.TICK_MS / 1000.0)
        live.timer.start(live_module.TICK_MS)


def test_the_counters_are_rewritten_four_times_a_second(window, monkeypatch):
    """Each rewrite of the counters lays the panel out again: on the timer they follow
    at most every COUNTERS_S while the images follow every tick (refresh() called
    directly rewrites them at once)."""
    from drivers.camera import Frame
    from gui.panels import live as live_module

    live = window.live
    assert live.isVisible()
    t0 = time.monotonic() + 1000.0  # after every real tick so far
    clock = [t0]
    monkeypatch.setattr(live_module, "time", types.SimpleNamespace(monotonic=lambda: clock[0]))
    live.timer.stop()
    try:
        live.pacer = DisplayPacer(live_module.TICK_MS / 1000.0)

        def tick(t: float, index: int) -> None:
            image = np.full((32, 40), index, np.uint16)
            window.session.show_frame(Frame(image, index, 0.0, 0.0, 0.01, 0.0, 0))
            clock[0] = t
            live._tick()

        tick(t0, 9101)
        assert "frame 9101" in live.raw_stats.text()
        tick(t0 + 0.05, 9102)  # the image follows, the counters wait
        assert live.raw_view.image[0, 0] == 9102 and "frame 9101" in live.raw_stats.text()
        tick(t0 + 0.10, 9103)
        assert "frame 9101" in live.raw_stats.text()
        tick(t0 + 0.05 + live_module.COUNTERS_S, 9104)
        assert "frame 9104" in live.raw_stats.text()
        window.session.show_frame(Frame(np.zeros((32, 40), np.uint16), 9105, 0.0, 0.0,
                                        0.01, 0.0, 0))
        live.refresh()
        assert "frame 9105" in live.raw_stats.text()
    finally:
        live.pacer = DisplayPacer(live_module.TICK_MS / 1000.0)
        live.timer.start(live_module.TICK_MS)

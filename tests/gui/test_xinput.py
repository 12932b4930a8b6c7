"""soak.xinput and soak.driver: the xdotool commands an operator's clicks become, and the
waits of the operator's day."""

from __future__ import annotations

import shutil

import pytest
from PySide6.QtCore import QPoint

from soak.xinput import XInput


def test_a_click_where_the_pointer_is_does_not_wait_for_it_to_move(monkeypatch):
    """``mousemove --sync`` to where the pointer already is waits for a move that never
    comes in Debian's xdotool (upstream issue 463): a second click on one spot took
    15 s or more and, under load, failed the emulated operator day at the 20 s limit.
    Only a move that moves the pointer waits."""
    if shutil.which("xdotool") is None:
        pytest.fail("xdotool is missing: bash scripts/system-deps.sh installs it")
    x = XInput()
    sent: list[tuple[str, ...]] = []
    monkeypatch.setattr(x, "_send", lambda *args: sent.append(args))
    here, there = QPoint(402, 323), QPoint(10, 20)
    x.click_at(here)
    x.click_at(here)
    x.move_to(here)
    x.move_to(there)
    x.click_at(here)
    assert sent == [("mousemove", "--sync", "402", "323", "click", "1"),
                    ("mousemove", "402", "323", "click", "1"),
                    ("mousemove", "402", "323"),
                    ("mousemove", "--sync", "10", "20"),
                    ("mousemove", "--sync", "402", "323", "click", "1")]


def test_a_step_waits_as_a_hang_guard_not_a_deadline():
    """The operator day's waits are an idle machine's needs stretched tenfold (at most
    10 min): at load 16-22 a snapshot outlasted its 30 s and failed the emulated day.
    A wait ends when its condition holds, so only a hang costs the longer wait."""
    import time

    from soak.driver import HANG_S, WindowDriver

    start = time.monotonic()
    wait = WindowDriver.until(lambda: False, 30, "the snapshot file")
    assert wait.timeout_s == 300 and wait.deadline >= start + 300
    assert WindowDriver.until(lambda: False, 120, "x").timeout_s == HANG_S
    assert WindowDriver.until(lambda: False, 0.5, "x").timeout_s == 5

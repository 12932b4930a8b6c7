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


class _RepeatingKeyboard:
    """Stands for the X server and the keyboard: ``type`` puts the text into the focused
    line edit, repeating one key in the first ``repeats`` calls (as the X server's
    autorepeat does when a key's release comes late under load); ``Return`` records
    what the field held."""

    def __init__(self, edit, repeats: int) -> None:
        self.edit, self.repeats, self.entered = edit, repeats, []

    def idle(self) -> bool:
        return True

    def click_at(self, point) -> None:
        pass

    def key(self, *keys: str) -> None:
        for k in keys:
            if k == "BackSpace":
                self.edit.clear()
            elif k == "Return":
                self.entered.append(self.edit.text())

    def type(self, text: str) -> None:  # noqa: A003
        if self.repeats > 0:
            self.repeats -= 1
            k = text.index("1")
            text = text[:k] + "1" + text[k:]  # pytest-416 -> pytest-4116
        self.edit.setText(self.edit.text() + text)


def _fill(qapp, monkeypatch, repeats: int, enter: bool):
    """Run ``WindowDriver.fill`` on a line edit with a keyboard that repeats a key in
    its first ``repeats`` typings; returns (the keyboard, the driver, the last wait
    that did not hold or None)."""
    from PySide6.QtWidgets import QLineEdit

    from soak import driver as drv

    edit = QLineEdit("/old/path")
    edit.setObjectName("live.psf")
    driver = drv.WindowDriver(edit)
    keyboard = _RepeatingKeyboard(edit, repeats)
    driver.x = keyboard

    def click(widget, times=1):
        return iter(())

    monkeypatch.setattr(driver, "click", click)
    monkeypatch.setattr(drv.WindowDriver, "_focused", staticmethod(lambda w: True))
    steps = driver.fill(edit, "/tmp/pytest-416/sweep-0.zarr", enter=enter)
    for item in steps:  # the keyboard is synchronous: every wait holds at once, or never
        if isinstance(item, drv._Wait) and not item.condition():
            return keyboard, driver, item
    return keyboard, driver, None


@pytest.mark.parametrize("enter", [True, False])
def test_a_repeated_key_is_typed_again_before_enter(qapp, monkeypatch, enter):
    """The emulated operator day, beside busy processes, typed ``pytest-4116`` for
    ``pytest-416`` (a key's release came late and the X server repeated it) and pressed
    Enter: the Live panel was sent to a PSF that is not there. ``fill`` now looks at
    the field before Enter and types it again."""
    keyboard, driver, stuck = _fill(qapp, monkeypatch, repeats=1, enter=enter)
    assert stuck is None
    assert keyboard.edit.text() == "/tmp/pytest-416/sweep-0.zarr"
    assert keyboard.entered == (["/tmp/pytest-416/sweep-0.zarr"] if enter else [])
    assert driver.retyped == ["live.psf: '/tmp/pytest-4116/sweep-0.zarr' for "
                              "'/tmp/pytest-416/sweep-0.zarr'"]


def test_a_field_that_never_takes_the_text_fails_the_step_and_is_not_entered(qapp,
                                                                              monkeypatch):
    """Typed wrong three times: the step waits for the right text (and fails at its
    limit, naming the field and what it holds); Enter is never pressed."""
    from soak.driver import RETYPES

    keyboard, driver, stuck = _fill(qapp, monkeypatch, repeats=RETYPES + 1, enter=True)
    assert stuck is not None and "live.psf to hold" in stuck.what
    assert keyboard.entered == [] and len(driver.retyped) == RETYPES


def _panel(qapp):
    """A shown, active window like a dock's panel: a scroll area holding a line edit,
    and an editable combo box."""
    from PySide6.QtWidgets import QComboBox, QLineEdit, QScrollArea, QVBoxLayout, QWidget

    scroll = QScrollArea()
    inner = QWidget()
    layout = QVBoxLayout(inner)
    edit, combo = QLineEdit(), QComboBox()
    edit.setObjectName("record.out")
    combo.setEditable(True)
    layout.addWidget(edit)
    layout.addWidget(combo)
    scroll.setWidget(inner)
    scroll.setWidgetResizable(True)
    scroll.show()
    scroll.activateWindow()
    qapp.processEvents()
    return scroll, edit, combo


def _focus(qapp, widget) -> None:
    from PySide6.QtWidgets import QApplication

    widget.setFocus()
    qapp.processEvents()
    assert QApplication.focusWidget() is widget, QApplication.focusWidget()


def test_a_scroll_area_around_the_field_does_not_count_as_its_focus(qapp):
    """Run K's operator typed a path while the Record panel's scroll area held the
    focus: the old check took any ancestor of the field for the field, so the keys went
    nowhere and the step waited 100 s for ``record.out``. An editable combo box, the
    focus proxy of its line edit, still counts for the line edit."""
    from soak.driver import WindowDriver

    scroll, edit, combo = _panel(qapp)
    try:
        _focus(qapp, scroll)
        assert not WindowDriver._focused(edit)
        _focus(qapp, edit)
        assert WindowDriver._focused(edit)
        _focus(qapp, combo)
        assert WindowDriver._focused(combo.lineEdit()) and WindowDriver._focused(combo)
        assert not WindowDriver._focused(edit)
    finally:
        scroll.close()


class _FocusKeyboard:
    """Types into the widget that has the focus, as the X server does; on its first
    typing the panel takes the focus away first (as a panel that relays itself out
    while the operator types)."""

    def __init__(self, qapp, edit, thief) -> None:
        self.qapp, self.edit, self.thief, self.stolen = qapp, edit, thief, False

    def idle(self) -> bool:
        return True

    def click_at(self, point) -> None:
        pass

    def _target(self):
        from PySide6.QtWidgets import QApplication, QLineEdit

        focus = QApplication.focusWidget()
        return focus if isinstance(focus, QLineEdit) else None

    def key(self, *keys: str) -> None:
        if not self.stolen:
            self.stolen = True
            self.thief.setFocus()
            self.qapp.processEvents()
        if "BackSpace" in keys and self._target() is not None:
            self._target().clear()

    def type(self, text: str) -> None:  # noqa: A003
        if self._target() is not None:
            self._target().insert(text)


def test_a_field_that_loses_the_focus_is_clicked_and_typed_again(qapp, monkeypatch):
    """The focus went to the panel between the click and the typing: the step no
    longer waits for text that went nowhere; it clicks the field again, types again
    and counts it in ``retyped``."""
    from soak import driver as drv

    scroll, edit, _ = _panel(qapp)
    try:
        driver = drv.WindowDriver(scroll)
        driver.x = _FocusKeyboard(qapp, edit, scroll)
        clicks = []

        def click(widget, times=1):
            clicks.append(widget)
            widget.setFocus()
            qapp.processEvents()
            return iter(())

        monkeypatch.setattr(driver, "click", click)
        for item in driver.fill(edit, "/tmp/video-0.zarr"):
            if isinstance(item, drv._Wait):
                assert item.condition(), item.what
        assert edit.text() == "/tmp/video-0.zarr"
        assert clicks == [edit, edit]
        assert driver.retyped == ["record.out: '' for '/tmp/video-0.zarr'"]
    finally:
        scroll.close()

"""Driving the real window from its own event loop: a generator of steps stepped by
Qt timers, never blocking the loop, and the widget helpers an operator's hands need
(find a widget by name, scroll it into view, click it, type into it, pick from a
combo box) through the X server (:mod:`soak.xinput`, xdotool).

:class:`WindowDriver` is the base of :class:`soak.operator_day.Operator`
(the operator's day) and of the live soak's day.
"""

from __future__ import annotations

import logging
import time
import traceback
from collections.abc import Callable, Iterator
from typing import Any

from PySide6.QtCore import QPoint, QTimer
from PySide6.QtWidgets import QApplication, QToolButton

from .xinput import XInput, centre

__all__ = ["StepFailed", "WindowDriver"]

log = logging.getLogger(__name__)

#: A step's wait is what an idle machine needs, with a margin; it guards against a hang
#: and is stretched by this factor, to at most :data:`HANG_S` (as the GUI tests' waits):
#: beside busy processes at load 16-22 a snapshot took more than its 30 s and failed the
#: emulated day. A wait ends as soon as its condition holds, so only a hang waits long.
HANG_FACTOR = 10.0
#: The longest a step waits for anything, s.
HANG_S = 600.0
#: How many times :meth:`WindowDriver.fill` types a field again that came out wrong.
RETYPES = 2



def shown_at(widget, before: QPoint | None) -> tuple[QPoint, bool]:
    """``(point, shown)``: ``widget``'s centre on the screen now, and whether the window
    shows the widget there, nothing covering it, at the same spot as ``before`` (the
    last look's point): a panel that re-lays itself out when its dock is raised (the
    Record panel's columns) moves its fields after the first look, and a dialog is
    visible to Qt before the window manager has placed it."""
    point = centre(widget)
    under = QApplication.widgetAt(point)
    return point, (under is not None and (under is widget or widget.isAncestorOf(under))
                   and point == before)

class StepFailed(RuntimeError):
    """A step of the day did not show what it should have (the message says what)."""


class _Wait:
    """A wait for ``condition``: ``timeout_s`` is an idle machine's need; the wait gives
    up after it stretched by :data:`HANG_FACTOR` (at most :data:`HANG_S`)."""

    def __init__(self, condition: Callable[[], bool], timeout_s: float, what: str) -> None:
        self.condition, self.what = condition, what
        self.timeout_s = max(timeout_s, min(timeout_s * HANG_FACTOR, HANG_S))
        self.deadline = time.monotonic() + self.timeout_s


class WindowDriver:
    """A generator of steps (``self._gen``) on the window's event loop: it yields a
    number (wait that many seconds), an :meth:`until` (wait for a condition, polled
    every 50 ms, :class:`StepFailed` thrown into it at the timeout) or anything else
    (step again at once). A step that raises ends the run: ``failure`` names it and
    :meth:`_finish` is called (the subclass ends its run there).

    Parameters
    ----------
    window : gui.app.MainWindow
    """

    def __init__(self, window) -> None:
        self.w = window
        self.app = QApplication.instance()
        self.x = XInput()
        self.failure: str | None = None
        self.target = None
        self._gen: Iterator | None = None
        #: Fields typed again (:meth:`fill`): ``"name: held for typed"``.
        self.retyped: list[str] = []

    def _finish(self, quit: bool = False) -> None:
        """End the run (a failed step calls it; the subclass writes its report)."""
        raise NotImplementedError

    def _step(self, value: Any = None) -> None:
        self._advance(lambda: self._gen.send(value) if value is not None else next(self._gen))

    def _throw(self, exc: Exception) -> None:
        self._advance(lambda: self._gen.throw(exc))

    def _advance(self, resume: Callable[[], Any]) -> None:
        """Run the day to its next yield (``resume``) and schedule what it asks for."""
        try:
            item = resume()
        except StopIteration:
            return
        except Exception as exc:  # noqa: BLE001 (a failed step ends the day, reported)
            self.failure = f"{type(exc).__name__}: {exc}"
            log.error("operator day failed: %s\n%s", exc, traceback.format_exc())
            self._finish()
            return
        if isinstance(item, int | float):
            QTimer.singleShot(int(item * 1000), self._step)
        elif isinstance(item, _Wait):
            self._poll(item)
        else:
            QTimer.singleShot(0, self._step)

    def _poll(self, wait: _Wait) -> None:
        try:
            ok = bool(wait.condition())
        except Exception as exc:  # noqa: BLE001 (the condition itself failed)
            self._throw(StepFailed(f"while waiting for {wait.what}: {exc}"))
            return
        if ok:
            QTimer.singleShot(0, self._step)
        elif time.monotonic() > wait.deadline:
            self._throw(StepFailed(f"timed out after {wait.timeout_s:g} s waiting for "
                                   f"{wait.what}"))
        else:
            QTimer.singleShot(50, lambda: self._poll(wait))

    @staticmethod
    def until(condition: Callable[[], bool], timeout_s: float, what: str) -> _Wait:
        return _Wait(condition, timeout_s, what)

    def typed(self) -> _Wait:
        """Wait until xdotool has carried out what was sent."""
        return _Wait(self.x.idle, 60, "the X input to be carried out")

    def find(self, cls, name: str):
        widget = self.w.findChild(cls, name)
        if widget is None:
            raise StepFailed(f"no {cls.__name__} named {name!r} in the window")
        return widget

    def button(self, name: str):
        from PySide6.QtWidgets import QPushButton

        return self.find(QPushButton, name)

    def tool(self, view, action) -> QToolButton:
        return view.toolbar.widgetForAction(action)

    def dock(self, title: str) -> None:
        self.w.docks[title].raise_()

    def aim(self, widget) -> Iterator:
        """Scroll ``widget`` into view and wait until the window shows it where it will
        be clicked (nothing covering it, the layout settled); the point is in
        :attr:`target`. A tool hidden in a narrow tool bar's overflow is shown first
        (its ">>" button clicked)."""
        from PySide6.QtWidgets import QToolBar

        bar = widget.parentWidget()
        if isinstance(bar, QToolBar) and not widget.isVisible():
            ext = bar.findChild(QToolButton, "qt_toolbar_ext_button")
            if ext is not None and ext.isVisible():
                self.x.click(ext)
                yield self.typed()
                yield self.until(widget.isVisible, 5, "the tool bar's overflow to open")
        before = None
        for _ in range(40):
            point, shown = shown_at(widget, before)
            if shown:
                self.target = point
                return
            before = point
            yield 0.1
        raise StepFailed(f"{widget.objectName() or widget} is not on the screen where the "
                         f"window says (covered or off screen): {QApplication.widgetAt(point)}")

    def click(self, widget, times: int = 1) -> Iterator:
        """Click ``widget``'s centre (``times`` quick clicks) once it shows there."""
        yield from self.aim(widget)
        for _ in range(times):
            self.x.click_at(self.target)
        yield self.typed()

    @staticmethod
    def _focused(widget) -> bool:
        """Whether keys typed now reach ``widget``: it, or a widget inside it (a spin
        box's editor), has the focus, or the widget that forwards its keys to it (an
        editable combo box is its line edit's focus proxy). A panel's scroll area that
        merely holds the field does not count: run K's operator typed a path into the
        Record panel's scroll area, and the field stayed empty."""
        focus = QApplication.focusWidget()
        return focus is not None and (focus is widget or widget.isAncestorOf(focus)
                                      or widget.focusProxy() is focus)

    def fill(self, widget, text: str, enter: bool = False) -> Iterator:
        """Click ``field``, check it took the focus, type ``text`` over what it held and,
        as an operator looks before pressing Enter, check that the field holds it (a line
        edit): a field that holds as many characters as were typed but others is typed
        again, up to :data:`RETYPES` times (each counted in :attr:`retyped`). Under load
        the X server repeats a key whose release comes late (its autorepeat), so a typed
        path gained a character (``pytest-4116`` for ``pytest-416``) and Enter sent
        the operator to a file that is not there. A field that lost the focus before
        it held the text is clicked again and typed again (counted the same way)."""
        yield from self.click(widget)
        yield self.until(lambda: self._focused(widget), 5,
                         f"the field {widget.objectName() or widget} to take the focus")
        name = widget.objectName() or type(widget).__name__
        readable = hasattr(widget, "text")  # a line edit: what it holds can be checked
        held = widget.text() if readable else None  # before typing: not yet a typo
        for attempt in range(RETYPES + 1):
            if attempt and not self._focused(widget):  # the focus went elsewhere: click back
                yield from self.click(widget)
                yield self.until(lambda: self._focused(widget), 5,
                                 f"the field {name} to take the focus again")
            self.x.key("ctrl+a", "BackSpace")
            if text:
                self.x.type(text)
            yield self.typed()
            if not readable:
                break
            last = attempt == RETYPES  # then only the text itself ends the wait
            yield self.until(lambda last=last: widget.text() == text or (not last and (
                (widget.text() != held and len(widget.text()) >= len(text))
                or not self._focused(widget))), 10,
                f"{name} to hold {text!r} (it holds {widget.text()!r}, the focus is on "
                f"{QApplication.focusWidget()})")
            if widget.text() == text:
                break
            wrong = widget.text()
            self.retyped.append(f"{name}: {wrong!r} for {text!r}")
            log.warning("typed again into %s: it held %r for %r", name, wrong, text)
        if enter:
            self.x.key("Return")
            yield self.typed()

    def choose(self, combo, text: str) -> Iterator:
        """Pick ``text`` in a combo box: click it open, click the entry in its list."""
        if combo.currentText() == text:
            return
        index = combo.findText(text)
        if index < 0:
            raise StepFailed(f"{combo.objectName()} offers no {text!r}")
        yield from self.click(combo)
        yield self.until(lambda: QApplication.activePopupWidget() is not None, 10,
                         f"{combo.objectName()}'s list to open")
        view = combo.view()
        rect = view.visualRect(view.model().index(index, combo.modelColumn()))
        self.x.click_at(view.viewport().mapToGlobal(rect.center()))
        yield self.typed()
        yield self.until(lambda: combo.currentText() == text, 10, f"{text!r} chosen")

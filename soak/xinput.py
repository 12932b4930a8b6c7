"""Real X input for driving the GUI in a real window: xdotool clicks, keys and typing.

:class:`XInput` sends mouse and keyboard events through the X server (``xdotool``),
so they reach the window the way an operator's do: through the window manager, the
xcb platform plugin and Qt's event dispatch. The commands run one after another on a
helper thread, so the GUI thread that asks for them never waits: :meth:`XInput.idle`
says when every command sent so far has been carried out. :func:`centre` is a
widget's centre on the screen (scrolled into view first if it sits in a scroll area).
"""

from __future__ import annotations

import queue
import shutil
import subprocess
import threading

from PySide6.QtCore import QPoint
from PySide6.QtWidgets import QScrollArea, QWidget

__all__ = ["XInput", "centre"]


def centre(widget: QWidget) -> QPoint:
    """The global (screen) position of ``widget``'s centre, after scrolling it into
    view in the scroll areas it sits in."""
    parent = widget.parentWidget()
    while parent is not None:
        if isinstance(parent, QScrollArea):
            parent.ensureWidgetVisible(widget, 20, 20)
        parent = parent.parentWidget()
    return widget.mapToGlobal(widget.rect().center())


class XInput:
    """xdotool commands on a helper thread (see the module docstring).

    Parameters
    ----------
    delay_ms : int
        Delay between typed characters, ms.

    Raises
    ------
    FileNotFoundError
        xdotool is not installed (``apt-get install xdotool``; scripts/system-deps.sh).
    """

    def __init__(self, delay_ms: int = 8) -> None:
        self.xdotool = shutil.which("xdotool")
        if self.xdotool is None:
            raise FileNotFoundError(2, "xdotool is not installed (apt-get install xdotool, "
                                    "see scripts/system-deps.sh)", "xdotool")
        self.delay_ms = int(delay_ms)
        self._queue: queue.Queue = queue.Queue()
        self._pending = 0
        self._lock = threading.Lock()
        self.errors: list[str] = []
        self.sent = 0
        self._at: tuple[int, int] | None = None  # where the last move sent puts the pointer
        self._thread = threading.Thread(target=self._run, name="xinput", daemon=True)
        self._thread.start()

    def idle(self) -> bool:
        """True once every command sent has been carried out."""
        with self._lock:
            return self._pending == 0

    def _send(self, *args: str) -> None:
        with self._lock:
            self._pending += 1
        self._queue.put([self.xdotool, *args])

    def _run(self) -> None:
        while True:
            cmd = self._queue.get()
            try:
                run = subprocess.run(cmd, capture_output=True, text=True, timeout=20)
                if run.returncode != 0:
                    self.errors.append(f"{' '.join(cmd[1:])}: {run.stderr.strip()}")
            except (OSError, subprocess.SubprocessError) as exc:
                self.errors.append(f"{' '.join(cmd[1:])}: {exc}")
            finally:
                with self._lock:
                    self._pending -= 1
                    self.sent += 1

    # -- the operator's hands ----------------------------------------------------------
    def click(self, widget: QWidget, button: int = 1) -> None:
        """Move the pointer to ``widget``'s centre and click."""
        self.click_at(centre(widget), button)

    def click_at(self, point: QPoint, button: int = 1) -> None:
        """Move the pointer to the screen position ``point`` and click ``button``."""
        self._send(*self._move(point), "click", str(button))

    def move_to(self, point: QPoint) -> None:
        """Move the pointer to the screen position ``point``."""
        self._send(*self._move(point))

    def _move(self, point: QPoint) -> list[str]:
        """xdotool's move to ``point``: ``--sync`` (wait until the pointer has moved)
        unless the pointer is there already. xdotool before 2024 (Debian's 3.20160805)
        waits then for a move away that never comes (its issue 463): 15.3 s here (Xvfb
        and openbox, idle), per
        click on the spot of the previous one, which under load ran into the 20 s
        limit of a command and failed the operator's day."""
        at = (point.x(), point.y())
        sync = [] if at == self._at else ["--sync"]
        self._at = at  # the commands run in the order they are sent
        return ["mousemove", *sync, str(at[0]), str(at[1])]

    def key(self, *keys: str) -> None:
        """Press ``keys`` one after the other (xdotool names: ``F5``, ``ctrl+q``,
        ``Return``, ``Right``)."""
        self._send("key", "--delay", "30", *keys)

    def type(self, text: str) -> None:  # noqa: A003 (what the operator does)
        self._send("type", "--delay", str(self.delay_ms), text)

    def fill(self, field: QWidget, text: str, enter: bool = False) -> None:
        """Click ``field``, select what it holds and type ``text`` over it (then Enter)."""
        self.click(field)
        self.key("ctrl+a", "BackSpace")
        if text:
            self.type(text)
        if enter:
            self.key("Return")

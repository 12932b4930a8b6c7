"""A look at a stall that the day's watchdog cannot take: the GIL held by a blocked thread.

The watchdog (:class:`soak.daymonitor.DayMonitor`) is a Python thread: it needs the GIL
to read the GUI thread's stack. A thread that blocks in a call that keeps the GIL (a
C extension's or the binding's call that does not release it, a page fault) stops the
watchdog too, so such a stall was recorded "not seen live", with no stack (run F3: a
4.0 s stall, 3.75 s of it blocked, not on a core and not waiting for one). Python's
:mod:`faulthandler` has a C thread that needs no GIL: armed with
:func:`faulthandler.dump_traceback_later` and re-armed by the watchdog while it runs, it
writes every thread's Python stack when the watchdog has not run for
:data:`HIDDEN_AFTER_S`. :class:`HiddenStallLook` arms it, reads what it wrote and
parses it into the watchdog's own stack format.
"""

from __future__ import annotations

import faulthandler
import os
import re
import tempfile
import time

__all__ = ["HIDDEN_AFTER_S", "REARM_EVERY_S", "HiddenStallLook", "parse_dump"]

#: The watchdog silent this long (s): faulthandler's thread writes every thread's stack.
HIDDEN_AFTER_S = 1.0
#: How often the watchdog re-arms it (s); each arming starts a C thread.
REARM_EVERY_S = 0.25
#: A look not claimed by a stall within this long (s) is dropped: the watchdog itself
#: was kept from a core (the GUI thread ran on).
KEEP_S = 10.0

_THREAD = re.compile(r"^(?:Current thread|Thread) (0x[0-9a-fA-F]+)")
_FRAME = re.compile(r'^\s+File "(.*)", line (\d+) in (.+?)\s*$')


def parse_dump(text: str) -> dict[int, list[tuple[str, int, str]]]:
    """Every thread's stack from :mod:`faulthandler`'s text.

    Parameters
    ----------
    text : str
        What :func:`faulthandler.dump_traceback_later` wrote (one or more dumps).

    Returns
    -------
    dict
        ``{thread ident: [(file, line, function), ...]}``, innermost last (faulthandler
        writes the most recent call first), the idents those of
        :func:`threading.get_ident`; of several dumps, the last one's.
    """
    stacks: dict[int, list[tuple[str, int, str]]] = {}
    current: list | None = None
    for line in text.splitlines():
        if line.startswith("Timeout ("):
            stacks, current = {}, None  # a later dump replaces an earlier one
            continue
        head = _THREAD.match(line)
        if head:
            current = stacks.setdefault(int(head.group(1), 16), [])
            continue
        frame = _FRAME.match(line)
        if frame and current is not None:
            current.insert(0, (frame.group(1), int(frame.group(2)), frame.group(3)))
    return stacks


class HiddenStallLook:
    """faulthandler's look at every thread when the watchdog cannot run.

    Used by the watchdog's thread only: :meth:`tick` each turn (re-arms, reads any new
    dump), :meth:`claim` when a stall it did not see live has ended, :meth:`close` at
    its end. The dump goes to an unlinked temporary file (:attr:`path` names it while
    open).
    """

    def __init__(self) -> None:
        self._file = tempfile.TemporaryFile(mode="w+b")
        self._read = 0
        self._text = ""  # the latest dump, as read so far (it may be read mid-write)
        self._armed_at = float("-inf")
        self._look: tuple[tuple[float, float], dict] | None = None  # (written, read), stacks

    @property
    def path(self) -> str:
        """The dump file's path (through ``/proc``: the file has no name), str."""
        return f"/proc/{os.getpid()}/fd/{self._file.fileno()}"

    def tick(self) -> None:
        """Re-arm faulthandler (every :data:`REARM_EVERY_S`) and read what it wrote."""
        now = time.monotonic()
        size = os.fstat(self._file.fileno()).st_size
        if size > self._read:
            text = os.pread(self._file.fileno(), size - self._read, self._read)
            self._read = size
            self._text += text.decode("utf-8", "replace")
            start = self._text.rfind("Timeout (")
            if start > 0 or self._look is None:  # a new dump: written after the arming
                # that ran out, read now
                self._text, span = self._text[max(start, 0):], (
                    self._armed_at + HIDDEN_AFTER_S, now)
            else:  # the rest of the dump read before
                span = self._look[0]
            self._look = (span, parse_dump(self._text))
        elif self._look is not None and now - self._look[0][1] > KEEP_S:
            self._look = None
        if now - self._armed_at >= REARM_EVERY_S:
            faulthandler.dump_traceback_later(HIDDEN_AFTER_S, repeat=False, file=self._file)
            self._armed_at = now

    def claim(self, began: float, ended: float) -> dict | None:
        """The look taken during a stall from monotonic ``began`` to ``ended``, once;
        None when there is none. The look was written between its arming's end (the
        arming plus :data:`HIDDEN_AFTER_S`) and its reading: a stall that ended before
        that or began after it is another one (the watchdog, let run after a block,
        handles an earlier stall's end and the block's in one turn: run H4 gave the
        block's look to the stall before it)."""
        if self._look is None:
            return None
        (written_after, read_at) = self._look[0]
        if ended < written_after or began > read_at:
            return None
        stacks, self._look, self._text = self._look[1], None, ""
        return stacks

    def close(self) -> None:
        """Disarm faulthandler and close the dump file."""
        faulthandler.cancel_dump_traceback_later()
        self._file.close()

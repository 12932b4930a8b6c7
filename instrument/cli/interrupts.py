"""SIGTERM and SIGHUP handled like Ctrl-C for the length of one command.

Schedulers (SLURM, systemd, ``kill``) stop a process with SIGTERM, and closing its
terminal sends SIGHUP; by default either ends Python at once, leaving a run
"running" or "recording", its writer lock in place and the bench not made safe.
:func:`terminate_like_ctrl_c` turns the first of them into :class:`Terminated`, a
:class:`KeyboardInterrupt`, raised in the main thread where the command runs, so
every path that handles Ctrl-C handles them the same way: a calibration run is
aborted (safe state, status aborted, lock released), a recording stopped and cut to
its frames (status stopped), a batch reconstruction keeps its finished frames and
releases its lock. A second one while that cleanup runs is logged and ignored (the
cleanup is what the signal asked for; SIGKILL remains for a process that hangs).
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
from collections.abc import Iterator

__all__ = ["HANDLED", "Terminated", "exit_status", "terminate_like_ctrl_c"]

log = logging.getLogger("diffuserlab")

#: The signals turned into :class:`Terminated` (SIGHUP where the platform has it).
HANDLED = tuple(s for s in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None))
                if s is not None)


class Terminated(KeyboardInterrupt):
    """The process was asked to stop by a signal (SIGTERM, SIGHUP).

    Attributes
    ----------
    signum : int
        The signal received.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(f"stopped by {signal.Signals(signum).name}")
        self.signum = int(signum)


def exit_status(exc: KeyboardInterrupt) -> int:
    """128 + the signal number: 130 for Ctrl-C (SIGINT), 143 for SIGTERM, 129 for SIGHUP."""
    return 128 + (exc.signum if isinstance(exc, Terminated) else int(signal.SIGINT))


@contextlib.contextmanager
def terminate_like_ctrl_c() -> Iterator[list[int]]:
    """Within the block, the first SIGTERM or SIGHUP raises :class:`Terminated` in the
    main thread; the previous handlers are restored after it.

    Yields
    ------
    list of int
        The signals received so far (empty when none).
    """
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return

    def handler(signum, frame):
        received.append(signum)
        if len(received) == 1:
            raise Terminated(signum)
        log.warning("%s received while stopping: finishing the clean-up first",
                    signal.Signals(signum).name)

    previous = {s: signal.signal(s, handler) for s in HANDLED}
    try:
        yield received
    finally:
        for s, h in previous.items():
            signal.signal(s, h)

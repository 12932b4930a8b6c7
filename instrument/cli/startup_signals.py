"""The first thing the ``diffuserlab`` process runs: its signals handled from the start.

Importing the command modules takes seconds (numpy, scipy, zarr, dask); a Ctrl-C or
a SIGTERM in that window must end as one line with exit 128 + the signal, like
anywhere else, and an import that catches the interrupt itself (a library's
``except BaseException``) must not let the command run on. So, before anything else
is imported, :func:`install` makes SIGINT raise KeyboardInterrupt and SIGTERM and
SIGHUP raise :class:`Terminated` (a KeyboardInterrupt) and records each
(:func:`received`). Only the standard library's ``signal``, ``sys`` and ``os`` are
imported here, so the window before it is as short as can be. Only the command
process is changed (:func:`is_command_process`): the tests and the GUI, which import
the command line, keep their own handlers.

A KeyboardInterrupt is only caught where something waits for it: the package's
guarded imports (``instrument.cli``'s first lines) and :func:`instrument.cli.main`'s
boundary. Between them (the package's module body after its imports, the console
script calling ``main``, ``main``'s own first lines) one raised would escape with a
traceback, so the package's start (``install(starting=True)``) raises only the first
signal, and :func:`hold` (the last of the guarded imports) makes the handler record
the signals without raising until :func:`release` (``main``'s first step inside its
boundary), which raises the first one held there: one line, 128 + the signal,
nothing done. A handler that runs inside a finalizer (a weakref callback: importlib
frees its module locks in one) raises where Python can only print the interrupt as
"Exception ignored" and run on; the command process's ``sys.unraisablehook``
(:func:`install`) keeps those of this handler quiet, since they are recorded and
``main`` stops the command for them.
"""

from __future__ import annotations

import os
import signal
import sys

__all__ = ["HANDLED", "SignalSeen", "Terminated", "count", "forget_unhandled_interrupt", "hold",
           "install", "is_command_process", "received", "record", "release"]

#: The signals besides SIGINT that stop a command like Ctrl-C (SIGHUP where it exists).
HANDLED = tuple(s for s in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None))
                if s is not None)

#: The signals :func:`install`'s handler saw, in order.
_RECEIVED: list[int] = []

#: Non-empty while the handler only records (:func:`hold` to :func:`release`).
_HOLD: list[bool] = []

#: The signals recorded while held, for :func:`release` to raise.
_HELD: list[int] = []

#: Non-empty while the package imports (``install(starting=True)``): after the first
#: signal's interrupt, the next ones are held (one line, whatever the except runs into).
_STARTING: list[bool] = []


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


def is_command_process() -> bool:
    """Whether this process is the ``diffuserlab`` command (its console script, or
    ``python -m instrument.cli``), not a program that imports the command line."""
    argv = list(getattr(sys, "orig_argv", []))
    if "-m" in argv[:-1] and argv[argv.index("-m") + 1] == "instrument.cli":
        return True
    script = next((a for a in argv[1:] if not a.startswith("-")), "")
    return os.path.basename(script) in ("diffuserlab", "diffuserlab.exe",
                                        "diffuserlab-script.py")


def record(signum: int) -> None:
    """Note a signal handled elsewhere (:func:`instrument.cli.interrupts.terminate_like_ctrl_c`)."""
    _RECEIVED.append(int(signum))


def _interrupt(signum: int) -> KeyboardInterrupt:
    exc = KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)
    exc.from_startup_handler = True  # for _unraisable: recorded already
    return exc


def _unraisable(unraisable) -> None:
    """``sys.unraisablehook`` while the command starts: the handler's interrupt raised
    where Python cannot raise it (a weakref callback, ``__del__``: importlib's module
    locks are freed by one) is recorded already, and :func:`instrument.cli.main` stops
    the command for it ("while starting; nothing was done"), so it is not printed;
    anything else goes to the hook that was there."""
    if getattr(unraisable.exc_value, "from_startup_handler", False):
        return
    _PREVIOUS_HOOK[0](unraisable)


#: The unraisable hook :func:`install` replaced.
_PREVIOUS_HOOK = [sys.unraisablehook]


def _handler(signum, frame):
    record(signum)
    if _HOLD:  # nothing would catch an interrupt here: release() raises it
        _HELD.append(int(signum))
        return
    if _STARTING:  # the package's guard handles this one; a second is held
        _HOLD.append(True)
    raise _interrupt(signum)


def install(starting: bool = False) -> None:
    """In the command process, SIGINT, SIGTERM and SIGHUP raise KeyboardInterrupt /
    :class:`Terminated` and are recorded from now on; elsewhere nothing changes.

    Parameters
    ----------
    starting : bool
        The package's start (its guarded imports): the first signal raises, the next
        ones are held (:func:`hold`) until :func:`release`.
    """
    _HOLD.clear()
    _HELD.clear()
    _STARTING[:] = [True] if starting else []
    if not is_command_process():
        return
    if sys.unraisablehook is not _unraisable:
        _PREVIOUS_HOOK[0] = sys.unraisablehook
        sys.unraisablehook = _unraisable
    for s in (signal.SIGINT, *HANDLED):
        try:
            signal.signal(s, _handler)
        except ValueError:  # not the main thread: its signals are not ours
            return


def hold() -> None:
    """From now on the handler records a signal without raising it (:func:`release`
    raises it): the package's last guarded step, where no interrupt could be caught
    until :func:`instrument.cli.main` enters its boundary."""
    _HOLD.append(True)


def release() -> None:
    """The handler raises again; a signal held since :func:`hold` is raised now (the
    first one), where the caller's boundary catches it (``main``'s first step)."""
    _STARTING.clear()
    _HOLD.clear()
    if _HELD:
        signum = _HELD[0]
        _HELD.clear()
        raise _interrupt(signum)


def forget_unhandled_interrupt() -> None:
    """Clear CPython's "unhandled KeyboardInterrupt" flag before the command exits.

    CPython (3.11, 3.12) sets that flag when code run from a *string* (``exec`` or
    ``eval`` of source text: ``dataclasses``, ``collections.namedtuple`` and others
    build functions so while modules import) ends with a KeyboardInterrupt, even when
    a caller then catches it; under ``python -m`` the interpreter then ends the
    process by SIGINT (exit -2) in place of the status the command chose. So a Ctrl-C
    that landed in such an ``exec`` while the command started printed its one line and
    still exited -2 (the fault-injection test, 1 run in 25 beside busy loops). The flag
    is reset at the start of every string ``exec``: one that ends normally clears it.
    The console script (``diffuserlab``) runs as a file, whose exit does not read it.
    """
    exec("None", {})  # noqa: S102 - a constant string, run only for CPython's reset


def received(since: int = 0) -> int | None:
    """The first signal the handler saw (after the first ``since`` ones), or None."""
    return _RECEIVED[since] if len(_RECEIVED) > since else None


def count() -> int:
    """How many signals the handler has seen (a mark for :func:`received`)."""
    return len(_RECEIVED)


class SignalSeen:
    """A stop flag for a command's long loop that does not depend on its interrupt
    reaching the loop: true once a signal was recorded (:func:`record`) after it was made.

    A handler raises its KeyboardInterrupt wherever the main thread happens to be; a
    library that catches it there (``except BaseException`` around a wait, a finalizer)
    lets the loop run on, so a Ctrl-C as a recording starts was once lost: every frame
    recorded, exit 0. A loop that also polls this flag (as
    :func:`instrument.acquisition.recorder.record_from_ring` polls its ``stop``) ends at its next
    step whatever happened to the interrupt. It reads a list (no lock), so the handler
    never waits on it.

    Examples
    --------
    >>> seen = SignalSeen()
    >>> seen.is_set()
    False
    """

    def __init__(self) -> None:
        self._mark = len(_RECEIVED)

    def is_set(self) -> bool:
        """Whether a signal came since this flag was made."""
        return len(_RECEIVED) > self._mark

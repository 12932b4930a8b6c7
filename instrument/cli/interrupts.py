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

The ``diffuserlab`` process itself (the console script or ``python -m
instrument.cli``, :func:`is_command_process`) is covered from its first line of our
code to its exit: :mod:`instrument.cli.startup_signals` (run before the command
modules are imported, seconds of numpy, scipy, zarr, dask) turns SIGINT, SIGTERM and
SIGHUP into KeyboardInterrupt / :class:`Terminated` and records each, so an import
that swallows the interrupt (a library's ``except BaseException``) is still seen and
the command never starts, and a library that turns the interrupt into an error of
its own (dask: "Nanny failed to start") is still reported as interrupted
(:func:`instrument.cli.main`); and :func:`quiet_shutdown` keeps the
errors of libraries' exit hooks (dask closing a cluster whose start was
interrupted, zarr's event loop) off the console: the command has printed its one
line and chosen its status by then (``-v`` logs them).
"""

from __future__ import annotations

import contextlib
import logging
import signal
import sys
import threading
import time
from collections.abc import Iterator

from .startup_signals import HANDLED, Terminated, is_command_process, record

__all__ = ["HANDLED", "Terminated", "after_the_command", "exit_status", "is_command_process",
           "quiet_shutdown", "redeliver", "signal_text", "terminate_like_ctrl_c"]

log = logging.getLogger("diffuserlab")


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
        if signum in _REDELIVER:  # the first one, lost in a finalizer: raised again
            _REDELIVER.remove(signum)
            raise Terminated(signum)
        received.append(signum)
        record(signum)
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


#: Signals whose interrupt a finalizer swallowed, raised again in the main thread.
_REDELIVER: list[int] = []


def redeliver(exc: BaseException | None) -> bool:
    """Raise an interrupt that Python could not raise again in the main thread.

    A signal whose handler runs while a finalizer (``__del__``, a weakref callback)
    is on the stack raises its KeyboardInterrupt there, and Python hands it to
    ``sys.unraisablehook`` and runs on (the likely way a Ctrl-C as a recording started
    was once lost under load: all its frames recorded, exit 0; not reproduced on
    demand, the finalizer case is, in the tests). The
    command process (:func:`quiet_shutdown` installs this in its hook) sends the same
    signal to its main thread again (``_thread.interrupt_main``), where it stops the
    command like any Ctrl-C; before :func:`after_the_command` only.

    Parameters
    ----------
    exc : BaseException or None
        The exception the hook was given.

    Returns
    -------
    bool
        True when ``exc`` was an interrupt and was sent again.
    """
    import _thread

    if not isinstance(exc, KeyboardInterrupt) or _AFTER:
        return False
    signum = exc.signum if isinstance(exc, Terminated) else int(signal.SIGINT)
    if signum != signal.SIGINT:
        _REDELIVER.append(signum)
    # from another thread, a moment later: the main thread is still in the hook, where
    # a handler's interrupt would be lost again
    def later() -> None:
        time.sleep(0.05)
        _thread.interrupt_main(signum)

    try:
        threading.Thread(target=later, daemon=True, name="redeliver-interrupt").start()
    except KeyboardInterrupt:  # another signal, here: it is the same request
        pass
    return True


#: Set once the command has chosen its status (:func:`after_the_command`).
_AFTER: list[bool] = []


def signal_text(signum: int | None) -> str:
    """``Ctrl-C`` for SIGINT (or None), ``stopped by SIGTERM`` for the others."""
    if signum is None or signum == signal.SIGINT:
        return "Ctrl-C"
    return f"stopped by {signal.Signals(signum).name}"


def quiet_shutdown(debug: bool) -> None:
    """In the command process, errors that Python reports while it shuts down (an
    exit hook's, a finalizer's: ``sys.unraisablehook``) go to the debug log instead
    of the console, and the resource tracker's leak warning of workers stopped
    mid-start is not shown, unless ``debug``."""
    if not is_command_process():
        return
    if debug:
        default = sys.unraisablehook
        sys.unraisablehook = lambda u: redeliver(u.exc_value) or default(u)
        return

    def hook(unraisable) -> None:
        if redeliver(unraisable.exc_value):
            return
        log.debug("while exiting: %s: %s (%s)", type(unraisable.exc_value).__name__,
                  unraisable.exc_value, unraisable.err_msg)

    sys.unraisablehook = hook
    # multiprocessing's resource tracker (a process of its own, started by dask with
    # this process's -W options) warns of the semaphores of workers stopped mid-start,
    # which it then removes
    sys.warnoptions.append("ignore:resource_tracker:UserWarning")


def after_the_command() -> None:
    """In the command process, once the command has chosen its status: SIGINT, SIGTERM
    and SIGHUP are noted and otherwise ignored while Python shuts down (the libraries'
    exit hooks run for a moment), so the status and the one line stand; a library
    that re-raises an interrupt then (``_thread.interrupt_main``) is ignored too."""
    if not is_command_process() or threading.current_thread() is not threading.main_thread():
        return
    _AFTER.append(True)
    for s in (signal.SIGINT, *HANDLED):
        signal.signal(s, lambda signum, frame: record(signum))

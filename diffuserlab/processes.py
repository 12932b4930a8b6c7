"""What every child process shares: how it ended, in people's words (one wording for
the window's messages, ``gui.messages``, and the processes' own logs), and how its
error crosses to the parent (:func:`portable_error`: the batch, live and bench
processes, ``instrument.processing.batch_process``, :mod:`instrument.acquisition.live_process`,
:mod:`instrument.bench.bench_host`)."""

from __future__ import annotations

import os
import pickle
import signal
import threading
import time
import traceback

from .errors import DiffuserLabError, InputError

__all__ = ["EXIT_STATUS_S", "ChildProcessFailure", "has_ended", "how_it_ended",
           "portable_error", "yield_to_parent"]


class ChildProcessFailure(DiffuserLabError, RuntimeError):
    """An error raised in a child process that could not reach its parent as itself
    (its type does not survive pickling and is none of the project's): its message,
    with the child's traceback as a note."""


def portable_error(exc: BaseException, where: str,
                   fallback: type[BaseException] = ChildProcessFailure) -> BaseException:
    """``exc`` made fit to send to the parent process (a pipe or queue pickles it).

    Parameters
    ----------
    exc : BaseException
        The exception the child caught.
    where : str
        Which process it was raised in (``"the bench process"``), for the note.
    fallback : type
        The type that carries the message of an exception that does not survive
        pickling and is none of the project's (:class:`ChildProcessFailure`, or the
        process's own, ``instrument.processing.batch_process.BatchProcessError``).

    Returns
    -------
    BaseException
        ``exc`` itself (a copy through pickle) if it survives pickling, else the
        nearest of :class:`~diffuserlab.errors.InputError`,
        :class:`~diffuserlab.errors.DiffuserLabError` and ``fallback`` with its
        message (its type's name if it has none); either way with the child's
        traceback as a note headed "in ``where``:" (the parent's log shows it for a
        bug).
    """
    try:
        portable = pickle.loads(pickle.dumps(exc))
    except Exception:  # an exception type whose arguments do not round-trip
        kind = (InputError if isinstance(exc, InputError) else
                DiffuserLabError if isinstance(exc, DiffuserLabError) else fallback)
        portable = kind(str(exc) or type(exc).__name__)
    portable.add_note(f"in {where}:\n" + "".join(
        traceback.format_exception(type(exc), exc, exc.__traceback__)))
    return portable


def how_it_ended(exit_status: int | None) -> str:
    """How a process ended, in an operator's words.

    Parameters
    ----------
    exit_status : int or None
        Its exit code, or minus the signal that ended it (as
        ``multiprocessing.Process.exitcode``); None: not known.

    Returns
    -------
    str
        ``"it was killed (signal 9, SIGKILL)"``, ``"it exited with status 1"``, ...
    """
    if exit_status is None:
        return "it stopped answering"
    if exit_status < 0:
        try:
            name = f", {signal.Signals(-exit_status).name}"
        except ValueError:
            name = ""
        return f"it was killed (signal {-exit_status}{name})"
    if exit_status > 128:
        try:
            return f"it ended on {signal.Signals(exit_status - 128).name}"
        except ValueError:
            pass
    return f"it exited with status {exit_status}"


#: One reaper at a time for every child (see :func:`has_ended`).
_REAPING = threading.Lock()

#: How long :func:`has_ended` waits for the exit status of a child that has ended (it
#: is a zombie within moments of closing its sentinel).
EXIT_STATUS_S = 5.0


def has_ended(process, wait_s: float = 0.0) -> bool:
    """Whether a started ``multiprocessing`` child has ended, waiting up to ``wait_s``
    for it; right from any number of threads at once. An ended child is reaped (no
    zombie left) and its ``exitcode`` is set.

    ``Process.is_alive`` and ``join`` learn of the end by reaping the child
    (``waitpid``). When two threads do so at once, the one that loses the race gets
    ECHILD, which CPython's ``Popen.poll`` answers with None: for that thread the dead
    child reads as alive (measured here: two threads, a child killed with SIGKILL, one
    of them saw it alive in 51 of 200 kills). A window's threads do exactly that when a
    child is killed: the event listener and the job's waiter both ask. So the end is
    read from the child's sentinel (a pipe end it holds until it exits, closed for
    every reader), and the reaping is done under one lock.

    Parameters
    ----------
    process : multiprocessing.Process
        A child of this process (one not started has not ended).
    wait_s : float
        Seconds to wait for its end (0: only look).

    Returns
    -------
    bool
        True once it has ended (its ``exitcode`` set, unless something outside this
        function reaped it and has not yet stored the status; then None for up to
        :data:`EXIT_STATUS_S`).
    """
    from multiprocessing.connection import wait

    if process.pid is None:  # not started: nothing has ended
        return False
    if not wait([process.sentinel], max(0.0, float(wait_s))):
        return False
    with _REAPING:
        process.join(EXIT_STATUS_S)  # it has closed its sentinel: a zombie within moments
        # a reaper outside the lock (multiprocessing's own, as another child starts)
        # may have won: it stores the status a moment after its waitpid
        deadline = time.monotonic() + EXIT_STATUS_S
        while process.exitcode is None and time.monotonic() < deadline:
            time.sleep(0.005)
    return True


def yield_to_parent(nice: int) -> dict:
    """Put the calling (child) process below its parent in the scheduler, so on a busy
    machine a window's GUI thread gets a core before the child's work.

    Two steps. The process leaves its parent's session (``setsid``): with the kernel's
    automatic process groups (``/proc/sys/kernel/sched_autogroup_enabled``, on by
    default) each session is one scheduling group, and a busy child in the window's
    group used up that group's share, so the GUI thread, waking for a timer or an input,
    queued behind every other busy group (``python -m soak.napari_widget_benchmark``: a
    viewer blocked 231-459 ms at load 8-13 while its widget's solver ran; see
    docs/open-data.md). In a group of its own the child gets a
    program's share, as before, and the window's group, mostly asleep, is served first
    when it wakes. Then ``nice`` is added to the process's own nice value (which orders
    it below the window where both share a group: no autogroup, or one control group
    for the user's programs). The group's own nice is left at 0: raising it starves the
    child beside other busy programs (the napari benchmark's four solves, about 2 min
    otherwise, had not ended after 6 min with the group at nice 10, beside three busy
    loops and two test suites).
    A step that the platform refuses (``setsid`` of a session leader; no nice) is skipped.

    Parameters
    ----------
    nice : int
        How far below the parent, 0-19 (``nice(1)``'s scale).

    Returns
    -------
    dict
        ``{"session": bool, "nice": int}``: whether the process now leads a session of
        its own, and its nice value.
    """
    try:
        os.setsid()
    except OSError:  # already a session leader, or not permitted
        pass
    try:  # from the value inherited from the parent
        os.nice(int(nice))
    except OSError:  # a platform without nice
        pass
    return {"session": os.getsid(0) == os.getpid(), "nice": os.nice(0)}

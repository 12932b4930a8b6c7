"""A batch reconstruction in a process of its own, for a long-lived caller (the GUI).

:func:`instrument.processing.batch.reconstruct_run` starts a ``dask.distributed`` scheduler and
client in the calling process. The command line (``recon-run``) is a process per batch,
so that costs nothing; a GUI session that reconstructs many batches would keep, from
each, threads, references and memory of dask's scheduler, and share its interpreter
lock with them while the live view streams. Measured on this project's bench (four
batches of four frames, one worker each): the process held about 230 more references
to ``None`` after each batch and 87 MB more after the first.

:func:`reconstruct_run_in_process` runs the same call in a child process (``spawn``,
so it shares no lock state or thread with the caller) and gives back what it would
have: the result dict, the progress reports as they come, and the exception it
raised. The child runs :data:`BATCH_NICE` lower in the OS scheduler than its caller's
process (its main thread), so on a machine short of cores the caller's window comes
first. Lower than the process, not than the calling thread: a child inherits the nice
value of the thread that starts it, and the GUI starts the batch from a job thread that
already runs at nice 10; ten more put the batch at 19, where beside two busy loops a
4 s batch of two frames had not finished after 600 s. Cancelling sets an
event the child's batch checks between frames (every finished frame is kept, as in
the same process); a child that does not end within ``stop_timeout_s`` of its result
or of a cancel is terminated.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import queue as queue_module
import threading
import time
from collections.abc import Callable
from typing import Any

from diffuserlab.processes import ChildProcessFailure, has_ended, how_it_ended, portable_error

__all__ = ["BATCH_NICE", "BatchProcessError", "batch_nice", "reconstruct_run_in_process"]

log = logging.getLogger(__name__)

#: How much lower than its caller the batch process (and the dask workers it starts)
#: runs in the OS scheduler: on a busy machine the caller's live view comes first.
BATCH_NICE = 10


class BatchProcessError(ChildProcessFailure):
    """The batch process ended without a result (killed, or it crashed): the frames it
    finished are stored in the run; starting the batch again does the rest."""


def _portable(exc: BaseException, where: str = "the batch process") -> BaseException:
    """:func:`diffuserlab.processes.portable_error` with the batch's fallback,
    :class:`BatchProcessError`."""
    return portable_error(exc, where, BatchProcessError)


def batch_nice() -> int:
    """The nice value the batch process runs at.

    Returns
    -------
    int
        :data:`BATCH_NICE` above the calling process's nice value (its main thread's,
        whatever the calling thread's), at most 19.
    """
    return min(19, os.getpriority(os.PRIO_PROCESS, os.getpid()) + BATCH_NICE)


def _child(kwargs: dict, messages, cancel, nice: int) -> None:
    """The child's work at nice value ``nice`` (inherited by the dask workers it
    starts): ``reconstruct_run(**kwargs)``, reporting on ``messages``."""
    from .batch import reconstruct_run

    try:  # from the starting thread's value; lowering it needs privileges
        os.nice(nice - os.nice(0))
    except OSError:  # a platform without nice, or an unprivileged raise
        pass
    try:
        result = reconstruct_run(**kwargs, cancel=cancel,
                                 on_progress=lambda p: messages.put(("progress", p)))
    except BaseException as exc:  # every failure goes back to the caller
        messages.put(("error", _portable(exc)))
    else:
        messages.put(("done", {**result, "process": {"pid": os.getpid(),
                                                     "nice": os.nice(0)}}))


def reconstruct_run_in_process(run, psf, options=None, *,
                               on_progress: Callable[[dict], None] | None = None,
                               cancel: threading.Event | None = None,
                               poll_s: float = 0.2, stop_timeout_s: float = 30.0,
                               **keywords: Any) -> dict[str, Any]:
    """:func:`instrument.processing.batch.reconstruct_run` in a child process.

    Parameters
    ----------
    run, psf, options, **keywords
        As :func:`instrument.processing.batch.reconstruct_run` (pickled to the child: a PSF
        ``(rows, cols)`` float array or a :class:`instrument.processing.batch_grid.GridBatchModel`,
        the :class:`recon.options.ReconOptions`).
    on_progress : callable, optional
        Called in this process, on the calling thread, with each progress dict of the
        batch (``done``, ``total``, ``skipped``, ``elapsed_s``, ``fps``).
    cancel : threading.Event, optional
        Set to stop the batch after the frame in hand (checked every ``poll_s``).
    poll_s : float
        How often the child's messages and ``cancel`` are looked at, s.
    stop_timeout_s : float
        How long the child may take to end after its result or a cancel before it is
        terminated, s.

    Returns
    -------
    dict
        The batch's result (as :func:`~instrument.processing.batch.reconstruct_run`), and
        ``process``: the child's ``pid`` and ``nice`` value (:func:`batch_nice`:
        :data:`BATCH_NICE` above the calling process's, at most 19).

    Raises
    ------
    Exception
        What the batch raised in the child (the same type where it can be pickled,
        else :class:`diffuserlab.errors.InputError` / ``DiffuserLabError`` with its
        message), with the child's traceback as a note.
    BatchProcessError
        The child ended without a result (killed, or out of memory).
    """
    context = multiprocessing.get_context("spawn")
    messages = context.Queue()
    stop = context.Event()
    kwargs = dict(run=run, psf=psf, options=options, **keywords)
    child = context.Process(target=_child, args=(kwargs, messages, stop, batch_nice()),
                            name="diffuserlab-batch")
    child.start()
    outcome = None
    try:
        while outcome is None:
            if cancel is not None and cancel.is_set():
                stop.set()
            try:
                kind, value = messages.get(timeout=poll_s)
            except queue_module.Empty:
                if has_ended(child):
                    outcome = _last_word(messages, child)
                continue
            if kind == "progress":
                if on_progress is not None:
                    on_progress(value)
            else:
                outcome = (kind, value)
    finally:
        if outcome is None:  # the caller was interrupted: the child stops too
            stop.set()
        _stop(child, stop_timeout_s)
        messages.close()
    kind, value = outcome
    if kind == "error":
        raise value
    return value


def _last_word(messages, child) -> tuple[str, Any]:
    """The result a child that has ended left on its queue, or the error of one that
    ended without one."""
    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline:  # the queue's feeder may still be flushing
        try:
            kind, value = messages.get(timeout=0.1)
        except queue_module.Empty:
            continue
        if kind != "progress":
            return kind, value
    return "error", BatchProcessError(
        f"the batch process ended before finishing: {how_it_ended(child.exitcode)} "
        "(killed, or out of memory); the frames it finished are stored in the run: start "
        "the batch again to reconstruct the rest")


def _stop(child, timeout_s: float) -> None:
    """Wait ``timeout_s`` for ``child`` to end, then terminate it (and say so)."""
    if not has_ended(child, timeout_s):
        log.warning("the batch process did not end within %g s; terminating it", timeout_s)
        child.terminate()
        has_ended(child, 5.0)

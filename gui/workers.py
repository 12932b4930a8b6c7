"""Background jobs for the GUI: library calls on worker threads, results by Qt signals.

The GUI thread never blocks: every device or compute call a panel makes runs in a
:class:`Job` (a Python thread), which reports progress, its result or a readable
error through Qt signals. Signals emitted on the worker thread reach slots of
objects living on the GUI thread as queued calls, so the slots run on the GUI
thread. A job can be cancelled: the function it runs gets the job and checks
:attr:`Job.cancelled` (or waits on :attr:`Job.cancel_event`) between its steps.

:func:`readable_error` turns an exception into the message the operator sees: the
library's own message (device, plan, run store and input errors name the problem
and the fix), never a traceback.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import queue
import threading
import time
import warnings
from collections.abc import Callable
from typing import Any

import shiboken6
from PySide6.QtCore import QObject, QTimer, Signal

import diffuserlab.errors
from diffuserlab.errors import DiffuserLabError

__all__ = ["BACKGROUND_NICE", "DEVICE_NICE", "HEAP_SETTLING_JOBS", "CameraBusy", "InputError",
           "Job", "readable_error", "settle_heap", "wait_until"]

log = logging.getLogger(__name__)

#: Nice increment of the GUI's worker threads (jobs, the live reconstruction): on a
#: machine whose cores the solvers fill, the event loop's thread still gets the CPU
#: when a timer or an input is due (Linux;
# :func:`instrument.acquisition.live.lower_thread_priority`).
#: ``python -m soak.benchmark`` with ADMM x5 live and a PSF sweep: p99 lateness 51 ms
#: at +5, 29-35 ms at +10.
BACKGROUND_NICE = 10
#: Nice increment of the jobs that wait on hardware with a timeout (opening and closing
#: the bench, device commands and polls, moves, the stream, recordings, calibration
#: runs and the mask alignment): none. A reply timeout counts wall time, and a thread
#: at +10 waits for a core behind every program at normal priority: the emulated
#: day beside three busy loops (load 10 on 2 cores) failed to open the bench, a Zaber
#: reply's first byte read and the rest past the driver's 1 s.
DEVICE_NICE = 0


class CameraBusy(DiffuserLabError, RuntimeError):
    """Another job holds the camera (or no bench is connected); the message says which."""


class InputError(diffuserlab.errors.InputError):
    """A value the operator typed into the GUI that it cannot use (the message names the
    field and what to type)."""


#: errno values of an OSError that are the operator's or the system's problem (a path
#: that does not exist, no permission, a full disk), not a bug: as the command line.
_ORDINARY_ERRNOS = frozenset({errno.ENOSPC, errno.EROFS, errno.EDQUOT, errno.EACCES,
                              errno.EPERM, errno.ENOENT, errno.EISDIR, errno.ENOTDIR,
                              errno.EEXIST, errno.ENAMETOOLONG})


def _input_errors() -> tuple[type[BaseException], ...]:
    """The project's own exception types, whose message is written for the operator
    (problem and fix): :class:`diffuserlab.errors.DiffuserLabError` and its subclasses
    (the GUI's :class:`InputError`, :class:`CameraBusy` and the binding check's error
    among them). Anything else (a KeyError, a TypeError, numpy's ValueError) is a
    bug, shown as one and logged with its traceback."""
    return (DiffuserLabError,)


def readable_error(exc: BaseException, labels: dict[str, str] | None = None) -> str:
    """The operator's message for ``exc``: one or more lines, never a traceback.

    Parameters
    ----------
    exc : BaseException
    labels : dict, optional
        ``{command-line flag: field label}`` of the panel that shows the message
        (:func:`gui.messages.operator_text`).

    Returns
    -------
    str
        A bench file's problems one per line; the message of one of the project's own
        errors (device, plan, run store, input, ...: it names the fix) or of an
        ordinary OS error (no such file, permission denied, disk full: with the path)
        in the GUI's terms; a connection to the bench process refused or cut: that it
        stopped and what to press; for anything else, the error's type and text marked as a
        bug (the traceback goes to the log).
    """
    from instrument.config import BenchConfigError

    from .messages import operator_text

    if isinstance(exc, BenchConfigError):
        return "\n".join(exc.lines())
    if isinstance(exc, OSError) and exc.errno in _ORDINARY_ERRNOS:
        reason = exc.strerror or str(exc) or type(exc).__name__
        paths = [str(p) for p in (exc.filename, exc.filename2) if p is not None]
        return f"{reason}: {' -> '.join(paths)}" if paths else reason
    if isinstance(exc, _input_errors()):
        return operator_text(str(exc) or type(exc).__name__, labels)
    if isinstance(exc, ConnectionError | EOFError):  # the bench process is gone
        return ("the bench process does not answer (it stopped); press Restart bench on "
                "the Devices panel")
    log.error("unexpected error in a GUI job", exc_info=exc)
    return (f"unexpected error ({type(exc).__name__}: {exc}); this is a bug - the log has "
            "the traceback to report")


#: How soon a job whose thread has not ended yet is looked at again for release, ms.
RELEASE_RETRY_MS = 20

#: Jobs started and not yet released on the GUI thread (:meth:`Job._release`).
_LIVE_JOBS: set[Job] = set()

#: Jobs after which the heap is settled (:func:`settle_heap`): they import libraries
#: and build long-lived objects (the bench, numba's and dask's machinery, plans).
HEAP_SETTLING_JOBS = frozenset({"open-bench", "build-live", "calibration", "alignment",
                                "record-video", "batch-recon"})


def settle_heap() -> None:
    """Collect the garbage, then freeze what survives (:func:`gc.freeze`), so the
    collector's full passes stop walking the libraries' and the bench's long-lived
    objects: a full collection of the GUI's heap held every thread for up to 0.3 s
    (measured in the operator's day), a pause the event loop shows as a freeze.

    The collection is a full one, and must be: a frozen object is never collected, and
    cyclic garbage that had reached the oldest generation, which a young collection
    does not look at, was frozen with the survivors and kept for good (57000 objects
    at the end of a 24-minute day). A full collection walks only the objects
    not frozen yet, those made since the last settle: a few milliseconds once the
    window is up (at most 62 ms, the first, in an 8.8-minute day). Called on the GUI
    thread at start and after the long jobs of :data:`HEAP_SETTLING_JOBS`.
    """
    import gc

    from .memory import trim_soon

    gc.collect()
    gc.freeze()
    trim_soon()


class Job(QObject):
    """Run ``fn(job, *args, **kwargs)`` on a worker thread.

    Signals
    -------
    progress(object)
        Whatever ``fn`` passes to :meth:`report` (emitted on the worker thread,
        delivered on the GUI thread).
    succeeded(object)
        ``fn``'s return value.
    failed(str)
        :func:`readable_error` of the exception ``fn`` raised.
    finished()
        After ``succeeded`` or ``failed``, always.

    Parameters
    ----------
    fn : callable
        ``fn(job, *args, **kwargs)``; checks :attr:`cancelled` between steps.
    name : str
        Thread name (shows in logs).
    owner : QObject, optional
        The widget whose slots the job's signals serve: once its C++ object is
        deleted (a closed window, a replaced panel), ``progress``, ``succeeded`` and
        ``failed`` and ``finished`` are no longer emitted (their slots would touch
        deleted widgets and raise ``RuntimeError``) and the job is cancelled; it is
        still marked :attr:`done` and let go as usual.
    nice : int
        Nice levels below the GUI's process the worker thread runs at:
        :data:`BACKGROUND_NICE` (compute, the default) or :data:`DEVICE_NICE` (a job
        that waits on hardware with a timeout).
    """

    progress = Signal(object)
    succeeded = Signal(object)
    failed = Signal(str)
    finished = Signal()
    # emitted on the worker thread, relayed to the public ones on the GUI thread (where
    # the owner is checked first)
    _progress = Signal(object)
    _succeeded = Signal(object)
    _failed = Signal(str)
    _finished = Signal()

    def __init__(self, fn: Callable[..., Any], *args: Any, name: str = "gui-job",
                 owner: QObject | None = None, nice: int = BACKGROUND_NICE,
                 **kwargs: Any) -> None:
        super().__init__()
        self.nice = nice
        self._fn, self._args, self._kwargs = fn, args, kwargs
        self.name = name
        self._owner = owner
        self._progress.connect(self._relay_progress)
        self._succeeded.connect(self._relay_succeeded)
        self._failed.connect(self._relay_failed)
        self._finished.connect(self._relay_finished)
        self.cancel_event = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = False
        self._launched = threading.Event()
        self._ended = threading.Event()
        self.result: Any = None
        self.error: str | None = None
        #: True once ``finished`` was delivered on the GUI thread (its slots have run).
        self.done = False
        self.finished.connect(self._mark_done)

    def _owner_gone(self) -> bool:
        """True once the owner's C++ object is deleted (then the job is cancelled)."""
        if self._owner is None or shiboken6.isValid(self._owner):
            return False
        self.cancel_event.set()
        return True

    def _relay_progress(self, value: Any) -> None:
        if not self._owner_gone():
            self.progress.emit(value)

    def _relay_succeeded(self, value: Any) -> None:
        if not self._owner_gone():
            self.succeeded.emit(value)

    def _relay_failed(self, text: str) -> None:
        if not self._owner_gone():
            self.failed.emit(text)

    def _relay_finished(self) -> None:
        if self._owner_gone():
            self._mark_done()  # the job's own bookkeeping, without the owner's slots
        else:
            self.finished.emit()

    def _mark_done(self) -> None:
        self.done = True
        QTimer.singleShot(0, self._release)  # after the other slots of ``finished``

    def _release(self) -> None:
        """On the GUI thread, once every slot has run and the worker thread has ended
        (else again a little later, never waiting): cut the connections (their
        closures often hold the job: a cycle through Qt that Python's collector cannot
        see) and let the job go. Its last reference
        is then dropped on the GUI thread, never on the worker (a QObject deleted on
        another thread while events for it wait in the GUI thread's queue crashed the
        window)."""
        thread = self._thread
        if not self._launched.is_set() or (thread is not None and thread.is_alive()):
            # the worker (or the launcher) still holds the job: come back, never block
            # the event loop joining a thread that waits for a core (seen in the soak)
            QTimer.singleShot(RELEASE_RETRY_MS, self._release)
            return
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            for signal in (self.progress, self.succeeded, self.failed, self.finished,
                           self._progress, self._succeeded, self._failed, self._finished):
                with contextlib.suppress(RuntimeError, TypeError):
                    signal.disconnect()
        _LIVE_JOBS.discard(self)
        if self.name in HEAP_SETTLING_JOBS:
            settle_heap()

    @property
    def cancelled(self) -> bool:
        """True once :meth:`cancel` was called."""
        return self.cancel_event.is_set()

    @property
    def running(self) -> bool:
        """True from :meth:`start` until the job's function has returned."""
        return self._started and not self._ended.is_set()

    def start(self) -> Job:
        """Start the worker thread; returns the job (kept alive until its ``finished``
        has been handled on the GUI thread) at once: the thread is started by the
        launcher (:func:`_launch`), so the GUI thread never waits for a new thread to
        get the interpreter (``Thread.start`` waits for the thread's first step, which
        held the event loop up to 5 s on a loaded machine in the operator's day)."""
        _LIVE_JOBS.add(self)
        self._started = True
        _launch(self)
        return self

    def cancel(self) -> None:
        """Ask the job to stop at its next check (returns at once)."""
        self.cancel_event.set()

    def report(self, value: Any) -> None:
        """Emit ``progress(value)`` (call from ``fn``; delivered on the GUI thread)."""
        self._progress.emit(value)

    def wait(self, timeout_s: float) -> bool:
        """Join the worker thread (tests and shutdown only; True if it ended)."""
        if not self._started:
            return True
        if not self._ended.wait(timeout_s):
            return False
        thread = self._thread
        if thread is not None:
            thread.join(timeout_s)
            return not thread.is_alive()
        return True

    def _run(self) -> None:
        from instrument.acquisition.live import lower_thread_priority

        lower_thread_priority(self.nice)
        try:
            self.result = self._fn(self, *self._args, **self._kwargs)
        except BaseException as exc:  # noqa: BLE001 (every error becomes a message)
            self.error = readable_error(exc)
            self._failed.emit(self.error)
        else:
            self._succeeded.emit(self.result)
        finally:
            self._finished.emit()
            self._ended.set()


_launch_queue: queue.SimpleQueue[Job] = queue.SimpleQueue()
_launcher: threading.Thread | None = None
_launcher_lock = threading.Lock()


def _launch(job: Job) -> None:
    """Have the launcher thread start ``job``'s worker thread (started itself once)."""
    global _launcher
    _launch_queue.put(job)
    with _launcher_lock:
        if _launcher is None:
            _launcher = threading.Thread(target=_launch_jobs, name="job-launcher",
                                         daemon=True)
            _launcher.start()


def _launch_jobs() -> None:
    """The launcher thread: start each queued job's thread, then let go of the job
    before saying so (``_launched``): a job's last reference must go on the GUI thread
    (:meth:`Job._release` waits for ``_launched``)."""
    while True:
        job = _launch_queue.get()
        launched = job._launched
        thread = threading.Thread(target=job._run, name=job.name, daemon=True)
        job._thread = thread
        try:
            thread.start()
        except RuntimeError as exc:  # "can't start new thread": the job fails, reported
            job.error = readable_error(exc)
            job._failed.emit(job.error)
            job._finished.emit()
            job._ended.set()
        del job, thread
        launched.set()


def wait_until(app, condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    """Process Qt events until ``condition()`` holds (scripts and tests, never a panel).

    Raises
    ------
    TimeoutError
        After ``timeout_s`` seconds, naming ``what``.
    """
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout_s:g} s waiting for {what}")
        app.processEvents()
        time.sleep(0.005)

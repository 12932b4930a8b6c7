"""A job of the bench process that any client holds by its id: its events, stop, result.

The bench process (:class:`~instrument.bench.bench_host.BenchHost`) keeps a
:class:`JobRegistry`: for every job it runs, whichever client started it, a log of the
job's events (``progress`` with the value the job reported, its arrays left out
(:func:`without_arrays`), then ``done`` with its result or ``failed`` with its error,
as :class:`~instrument.bench.bench_service.BenchEvent` s, ``device`` None) that every client
reads with a long poll, as it reads the bench's events (the client that started it
too: one route, the same sequence numbers for every client); and the job's start and end
as a ``job`` event in the bench's own :class:`~instrument.bench.bench_service.EventLog`
(``data``: :meth:`JobInfo.as_event`), so a window sees the job a notebook started.

A client holds a job as a :class:`JobHandle`
(:meth:`instrument.bench.bench_process.BenchClient.start_job` or
:meth:`~instrument.bench.bench_process.BenchClient.job` by id): it waits on the job's events,
stops, pauses or aborts it, and takes its result or error. Any client may stop any
job.

A job belongs to the bench process, not to a client: a client that disconnects (a
notebook closed, its kernel restarted) leaves the jobs it started running to their
end; a recording records its frames or seconds and closes its run ``complete``, and its
result waits in the registry (the last :data:`ENDED_JOBS_KEPT` ended jobs) for any
client that asks by id. The bench closing (the window closing, the bench process
ending) ends every job as :meth:`~instrument.bench.bench_host.BenchHost.close` does (a
recording stopped, its run closed ``stopped``, its lock released).
"""

from __future__ import annotations

import copy
import dataclasses
import inspect
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from .bench_service import BenchEvent, BenchGoneError, BenchServiceError, EventLog

__all__ = ["ENDED_JOBS_KEPT", "JOB_EVENTS_KEPT", "OWNER_JOBS", "JobHandle", "JobInfo",
           "JobRegistry", "check_params", "without_arrays"]

#: Events kept per job (a reader that fell further behind gets the newest; the job's
#: end is always the last kept).
JOB_EVENTS_KEPT = 64

#: Ended jobs whose events and result the bench process keeps for a client to collect.
ENDED_JOBS_KEPT = 32

#: Jobs only the client that started the bench process (the window) runs: opening and
#: closing the bench under it is the window's to do.
OWNER_JOBS = frozenset({"open_bench", "close_bench"})

#: Longest single wait, s, of a long poll in the bench process.
_POLL_CAP_S = 5.0


@dataclasses.dataclass(frozen=True)
class JobInfo:
    """A job of the bench process, as plain data.

    Attributes
    ----------
    id : int
        Its id (unique while the bench process runs).
    name : str
        The job's name (``record``, ``run_plan``, ...).
    params : dict
        The keyword parameters it was started with.
    state : str
        ``running``, ``done`` or ``failed``.
    owner : str
        The client that started it (its name: ``BenchClient(name=...)``, by default
        ``pid N``), as refusals and confirmations name it.
    holds : tuple of str
        The ids of the devices it holds while it runs (its declaration,
        :func:`instrument.bench.bench_jobs.holding`); no other job may use them.
    progress : object
        The last progress it reported, its arrays left out (None before the first).
    """

    id: int
    name: str
    params: dict
    state: str
    owner: str = ""
    holds: tuple = ()
    progress: Any = None

    def as_event(self) -> dict:
        """``{"id", "name", "state", "owner", "holds", "run"}``: the ``data`` of the
        bench's ``job`` event (``run``: the run it writes,
        :func:`instrument.bench.bench_recovery.run_path_of`, or None)."""
        from .bench_recovery import run_path_of

        return {"id": self.id, "name": self.name, "state": self.state,
                "owner": self.owner, "holds": list(self.holds),
                "run": run_path_of(self.params)}

    def describe(self) -> str:
        """``job 3 (record) of the window``: how a refusal or a confirmation names it."""
        return f"job {self.id} ({self.name}) of {self.owner or 'an unnamed client'}"


def without_arrays(value: Any) -> Any:
    """``value`` with its NumPy arrays left out: a dict without those items, a
    dataclass (a copy) with those fields None, anything else as it is.

    A calibration run's progress carries each frame it took (its ``last_frame``) for
    the window's display; kept in every job's log, a run's frames would pile up in the
    bench process (tens of megabytes each on a large sensor), so only the newest
    progress that had arrays keeps them, for a reader that asks for them
    (:meth:`JobRegistry.events_after` with ``arrays``: the window's
    :meth:`~instrument.bench.bench_process.BenchClient.run_job`). A notebook takes frames
    with ``snap()`` or from the run.
    """
    if isinstance(value, dict):
        return {k: v for k, v in value.items() if not isinstance(v, np.ndarray)}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        arrays = [f.name for f in dataclasses.fields(value)
                  if isinstance(getattr(value, f.name, None), np.ndarray)]
        if arrays:
            value = copy.copy(value)  # keeps attributes set besides the fields
            for name in arrays:
                object.__setattr__(value, name, None)
    return value


def check_params(name: str, fn: Callable, params: dict) -> None:
    """Refuse parameters job ``fn`` (``function(ctx, **params)``) does not take, before
    it starts: each keyword its signature does not name (unless it takes ``**kwargs``),
    then the job's own ``fn.check(params)`` (a nested dict of options, e.g.
    :func:`instrument.bench.bench_jobs.record`'s ``options``).

    Raises
    ------
    instrument.bench.bench_service.BenchServiceError
        One line naming the first unknown key and the accepted ones.
    """
    sig = inspect.signature(fn)
    kinds = {p.kind for p in sig.parameters.values()}
    if inspect.Parameter.VAR_KEYWORD not in kinds:
        accepted = [p.name for p in list(sig.parameters.values())[1:]
                    if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
        for key in params:
            if key not in accepted:
                raise BenchServiceError(f"{name}: unknown parameter {key!r}; it accepts "
                                        f"{', '.join(accepted) or 'none'}")
    check = getattr(fn, "check", None)
    if check is not None:
        check(params)


class _Job:
    def __init__(self, info: JobInfo) -> None:
        self.info = info
        self.log = EventLog(JOB_EVENTS_KEPT)
        #: The sequence number and value of the newest progress event that had arrays
        #: (a calibration's ``last_frame``), for a reader that asks for them; one per
        #: job, dropped when it ends.
        self.arrays: tuple[int, Any] | None = None


class JobRegistry:
    """The bench process's jobs: their events, state and outcome (host side).

    Parameters
    ----------
    bench_events : EventLog
        The bench's log, where each job's start and end is logged as a ``job`` event.
    """

    def __init__(self, bench_events: EventLog) -> None:
        self.bench_events = bench_events
        self._jobs: OrderedDict[int, _Job] = OrderedDict()
        self._lock = threading.Lock()

    def started(self, job_id: int, name: str, params: dict, owner: str = "",
                holds: tuple = ()) -> None:
        """Log job ``job_id`` as running, started by client ``owner``, holding the
        devices ``holds``."""
        job = _Job(JobInfo(job_id, name, dict(params), "running", owner, tuple(holds)))
        with self._lock:
            self._jobs[job_id] = job
        self.bench_events.put("job", None, job.info.as_event())

    def report(self, job_id: int, value: Any) -> None:
        """Log the job's progress ``value``, less its arrays (:func:`without_arrays`);
        the newest value with its arrays is kept beside it for a reader that asks for
        them (:meth:`events_after` with ``arrays``)."""
        job = self._jobs.get(job_id)
        if job is not None:
            plain = without_arrays(value)
            with self._lock:
                job.info = dataclasses.replace(job.info, progress=plain)
                event = job.log.put("progress", None, plain)
                if plain is not value and not (isinstance(value, dict)
                                               and len(plain) == len(value)):
                    job.arrays = (event.seq, value)  # kept past events without arrays

    def ended(self, job_id: int, state: str, value: Any) -> None:
        """Log the job's end: ``state`` ``done`` (``value`` its result) or ``failed``
        (``value`` its error); forget the oldest ended jobs past
        :data:`ENDED_JOBS_KEPT`."""
        with self._lock:
            job = self._jobs[job_id]
            job.info = dataclasses.replace(job.info, state=state)
            job.arrays = None
            ended = [i for i, j in self._jobs.items() if j.info.state != "running"]
            for old in ended[:max(0, len(ended) - ENDED_JOBS_KEPT)]:
                del self._jobs[old]
        job.log.put(state, None, value)
        self.bench_events.put("job", None, job.info.as_event())

    def _job(self, job_id: int) -> _Job:
        job = self._jobs.get(int(job_id))
        if job is None:
            raise BenchServiceError(f"the bench process has no job {job_id} (running or "
                                    f"among the last {ENDED_JOBS_KEPT} ended); list them "
                                    "with jobs()")
        return job

    def info(self, job_id: int) -> JobInfo:
        """The job's :class:`JobInfo`.

        Raises
        ------
        instrument.bench.bench_service.BenchServiceError
            No such job (never started, or ended long ago).
        """
        return self._job(job_id).info

    def infos(self) -> list[JobInfo]:
        """Every job kept (running and recently ended), oldest first."""
        with self._lock:
            return [j.info for j in self._jobs.values()]

    def events_after(self, job_id: int, seq: int, timeout_s: float = 1.0,
                     arrays: bool = False) -> tuple[int, list[BenchEvent]]:
        """The job's events after ``seq`` (0: from the first kept), waiting up to
        ``timeout_s`` (at most 5 s) for one; see :meth:`EventLog.after
        <instrument.bench.bench_service.EventLog.after>`. Every client reads a job's events
        here, by the same sequence numbers.

        ``arrays``: of the events returned, the newest that had arrays carries them (a
        calibration's ``last_frame``, for the window's display; not after the job's
        end); the others, and every event without ``arrays``, carry
        :func:`without_arrays`' value.
        """
        job = self._job(job_id)
        last, events = job.log.after(int(seq), min(float(timeout_s), _POLL_CAP_S))
        with self._lock:
            kept = job.arrays if arrays else None
        if kept is not None:
            events = [dataclasses.replace(e, data=kept[1]) if e.seq == kept[0] else e
                      for e in events]
        return last, events


class JobHandle:
    """A job of the bench process, held by a client (see the module docstring).

    Parameters
    ----------
    host : object
        The client's way to the bench process (its ``job_events_after``,
        ``job_info`` and ``job_control``).
    info : JobInfo
        The job as it was when the handle was made.
    arrays : bool
        Read the newest progress event with its arrays (:meth:`JobRegistry.events_after`;
        :meth:`~instrument.bench.bench_process.BenchClient.run_job`'s ``report``); False
        (default) leaves them out.
    """

    def __init__(self, host, info: JobInfo, arrays: bool = False) -> None:
        self._host = host
        self._arrays = bool(arrays)
        self.id, self.name, self.params = info.id, info.name, info.params
        self._seq = 0
        self._end: BenchEvent | None = None

    def __repr__(self) -> str:
        return f"JobHandle(id={self.id}, name={self.name!r})"

    @property
    def state(self) -> str:
        """``running``, ``done`` or ``failed``, as the bench process has it now."""
        if self._end is not None:
            return self._end.kind
        return self._call("job_info", self.id).state

    @property
    def ended(self) -> bool:
        """Whether this handle has read the job's end."""
        return self._end is not None

    def _call(self, method: str, *args):
        try:
            return getattr(self._host, method)(*args)
        except (OSError, EOFError, BenchGoneError) as exc:
            why = getattr(exc, "cause", type(exc).__name__)
            raise BenchGoneError(f"the bench process is gone ({why}); "
                                 f"job {self.id} ({self.name}) ended with it") from None

    # -- events ------------------------------------------------------------------------
    def next_events(self, timeout_s: float = 1.0) -> list[BenchEvent]:
        """The job's events this handle has not read yet, waiting up to ``timeout_s``
        for one (a long poll: it returns as soon as one is logged); empty: none came,
        or the job's end was read already.

        Returns
        -------
        list of BenchEvent
            ``progress`` (``data``: what the job reported), then ``done`` (``data``: its
            result) or ``failed`` (``data``: its error).
        """
        if self._end is not None:
            return []
        deadline = time.monotonic() + max(0.0, float(timeout_s))
        while True:
            left = deadline - time.monotonic()
            _, events = self._call("job_events_after", self.id, self._seq,
                                   min(max(left, 0.0), _POLL_CAP_S), self._arrays)
            if events or left <= 0:
                break
        if events:
            self._seq = events[-1].seq
            if events[-1].kind in ("done", "failed"):
                self._end = events[-1]
        return events

    def events(self, timeout_s: float = 60.0) -> Iterator[BenchEvent]:
        """Each event of the job as it comes, up to its end (included).

        Raises
        ------
        TimeoutError
            No event came within ``timeout_s`` (the job is still running).
        """
        while self._end is None:
            got = self.next_events(timeout_s)
            if not got:
                raise TimeoutError(f"job {self.id} ({self.name}) logged nothing in "
                                   f"{timeout_s:g} s; it is still running")
            yield from got

    def wait_for(self, test: Callable[[BenchEvent], bool],
                 timeout_s: float = 60.0) -> BenchEvent:
        """The first unread event of the job for which ``test(event)`` is true.

        Raises
        ------
        TimeoutError
            No event came within ``timeout_s`` of the one before.
        LookupError
            The job ended without such an event.
        """
        for event in self.events(timeout_s):
            if test(event):
                return event
        raise LookupError(f"job {self.id} ({self.name}) ended ({self._end.kind}) without "
                          "the event waited for")

    def result(self, timeout_s: float | None = None) -> Any:
        """Wait for the job's end; its result.

        Parameters
        ----------
        timeout_s : float, optional
            Longest wait, s (None: as long as the job runs).

        Raises
        ------
        BaseException
            The job's error (its type kept when it could be pickled).
        TimeoutError
            The job is still running after ``timeout_s``.
        """
        deadline = None if timeout_s is None else time.monotonic() + float(timeout_s)
        while self._end is None:
            left = _POLL_CAP_S if deadline is None else deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"job {self.id} ({self.name}) still runs after "
                                   f"{timeout_s:g} s")
            self.next_events(min(left, _POLL_CAP_S))
        if self._end.kind == "failed":
            raise self._end.data
        return self._end.data

    # -- control -----------------------------------------------------------------------
    def stop(self) -> None:
        """Stop the job as the window's stop button does (a recording keeps what it
        recorded, its run ``stopped``)."""
        self._call("job_control", self.id, "stop")

    def cancel(self) -> None:
        """Cancel the job (an opening bench stops homing)."""
        self._call("job_control", self.id, "cancel")

    def pause(self) -> None:
        """Pause a calibration run after its current point."""
        self._call("job_control", self.id, "pause")

    def resume(self) -> None:
        """Resume a paused calibration run."""
        self._call("job_control", self.id, "resume")

    def abort(self, reason: str = "aborted from a client") -> None:
        """Abort a calibration run to the safe state."""
        self._call("job_control", self.id, "abort", reason)

"""The client of a :class:`~instrument.bench.bench_host.BenchHost`: in a child process or here.

:class:`BenchClient` starts the host in a process of its own (``spawn``, served by
``multiprocessing.managers.BaseManager``, which gives every calling thread its own
connection and serves each on a thread of the host, so a long stage move does not hold
up a status read) or, with ``in_process``, in the caller's process; the rest is the
same either way:

* calls go over a small pool of connections (``_PooledHost``), not one per calling
  thread.
* the bench's typed commands (:class:`~instrument.bench.bench_service.BenchService`:
  :meth:`BenchClient.devices`, :meth:`BenchClient.apply_settings`,
  :meth:`BenchClient.move`, ...), by device id with plain data; no device object comes
  here. The client is a proxy of the service (:data:`PROXIED`): each public command of
  :class:`~instrument.bench.bench_service.BenchService` is a method here, with its
  signature, that calls it in the bench process.
* ``on_event(event)`` for each :class:`~instrument.bench.bench_service.BenchEvent` (settings,
  positions, statuses, the bench opened or closed), long-polled from the host.
* :meth:`BenchClient.run_job` - a job run by the host by its name
  (:data:`instrument.bench.bench_jobs.JOBS` and the ``jobs`` given to the client,
  :class:`~instrument.bench.bench_host.JobContext`), its progress handed to
  ``report``; a :class:`~instrument.acquisition.runner.RunControl`, a stop and a cancel event of the
  caller are forwarded while it runs; returns its result or raises its error. It follows
  the job by a :class:`~instrument.bench.bench_job_handle.JobHandle`, the route by which
  every client reads a job's events (the same sequence numbers for all); the client
  that started the bench process (the window) asks for the newest progress event's
  arrays (a calibration's ``last_frame``, for its display).
* :meth:`BenchClient.start_job` - the same job started without waiting: a
  :class:`~instrument.bench.bench_job_handle.JobHandle` to wait on its events and result and
  to stop it, from any client; :meth:`BenchClient.job` holds a job another client
  started, by its id.
* frames: ``on_frame(frame, counters)`` on a reader thread for every frame the host
  publishes (newest only: a reader that falls behind skips, the counters say so).
* ``on_message(text)`` and ``on_prompt(action, message, reply)`` for the host's other
  events.

The host process owns what its jobs write: when its parent is gone (an operator's
window that crashed or was killed) or it is sent SIGTERM or SIGHUP, it ends its jobs as
:meth:`~instrument.bench.bench_host.BenchHost.close` does (a recording stopped as on Ctrl-C:
its run ``stopped``, its lock released), closes the bench (no stage moving, no camera
held) and exits.
"""

from __future__ import annotations

import inspect
import logging
import multiprocessing
import os
import select
import signal
import threading
from collections.abc import Callable, Mapping
from multiprocessing.managers import BaseManager
from typing import Any

from diffuserlab.processes import has_ended, how_it_ended

from ..acquisition.shared_slot import SharedImageSlot
from .bench_host import FRAME_META, BenchHost, BenchHostError, EventChannel, FrameWaker
from .bench_job_handle import JobHandle, JobInfo
from .bench_service import BenchEvent, BenchGoneError, BenchService

__all__ = ["ENDING_SIGNALS", "PROXIED", "BenchClient"]

log = logging.getLogger(__name__)

_SERVER: dict[str, Any] = {}

#: Longest wait, s, for a bench process whose connection broke to end (a hang guard).
_ENDING_S = 10.0


#: The signals that end the host process as its parent's death does (SIGINT is
#: ignored there: a Ctrl-C in the window's terminal is the window's to handle).
ENDING_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n))


def _serve_init(events, wake, parent_pid: int, jobs: Mapping[str, Callable]) -> None:
    """In the host process: keep the channels and the jobs; when the parent dies or an
    :data:`ENDING_SIGNALS` signal comes, end the jobs, close the bench and exit."""
    _SERVER.update(events=EventChannel(events), wake=FrameWaker(wake), jobs=dict(jobs))
    ended: list[int] = []
    wakeup = threading.Event()

    def on_signal(signum, frame) -> None:  # the main thread (the manager's): note it only
        ended.append(signum)
        wakeup.set()

    for signum in ENDING_SIGNALS:
        signal.signal(signum, on_signal)

    def watch() -> None:
        while os.getppid() == parent_pid and not wakeup.wait(0.5):
            pass
        why = (f"{signal.Signals(ended[0]).name} received" if ended
               else "the window's process is gone")
        log.warning("bench process: %s; ending the jobs and closing the bench", why)
        host = _SERVER.get("host")
        try:
            if host is not None:
                host.set_closing(True)  # nobody to give the bench back to
                host.close()
        finally:
            if host is not None:
                host.remove_connection_file()
            os._exit(128 + ended[0] if ended else 0)

    threading.Thread(target=watch, name="bench-parent-watch", daemon=True).start()


def _the_host() -> BenchHost:
    if "host" not in _SERVER:
        _SERVER["host"] = BenchHost(_SERVER["events"], _SERVER["wake"])
        _SERVER["host"].register_jobs(_SERVER["jobs"])
    return _SERVER["host"]


class _Manager(BaseManager):
    pass


def gone(address: Any, exc: BaseException) -> BenchGoneError:
    """The clear error for a bench process that cannot be reached at ``address``
    (``exc``: the connection's own error, e.g. ``ConnectionRefusedError``)."""
    error = BenchGoneError(f"the bench process at {address} is gone or not running "
                           f"({type(exc).__name__}); start it again (the window's Restart "
                           "bench, or `diffuserlab bench serve`) and connect anew")
    error.cause = type(exc).__name__
    return error


class _PooledHost:
    """The host's methods called over a pool of connections, in the manager's own
    protocol (``(id, method, args, kwargs)`` -> ``(kind, result)``).

    The manager's proxy keeps one connection per calling thread in a
    ``multiprocessing.util.ForkAwareLocal``, whose ``__init__`` runs again in every new
    thread and each time adds an entry that is never removed to the after-fork registry:
    a window that starts a thread per job (one a second for the device poll) grew by
    ~19000 references an hour. A connection here is taken from the pool for one call
    and put back; one that failed mid-call is closed.
    """

    def __init__(self, proxy) -> None:
        from multiprocessing import managers

        self._managers = managers
        self._proxy = proxy  # holds the host's reference count in the server
        self._token, self._authkey, self._client = proxy._token, proxy._authkey, proxy._Client
        self._free: list = []
        self._lock = threading.Lock()

    def _take(self):
        with self._lock:
            if self._free:
                return self._free.pop()
        conn = self._client(self._token.address, authkey=self._authkey)
        self._managers.dispatch(conn, None, "accept_connection", ("bench-client",))
        return conn

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)

        def call(*args, **kwargs):
            try:
                conn = self._take()
            except (OSError, EOFError) as exc:
                raise gone(self._token.address, exc) from None
            try:
                conn.send((self._token.id, name, args, kwargs))
                kind, result = conn.recv()
            except (OSError, EOFError) as exc:
                conn.close()
                raise gone(self._token.address, exc) from None
            except BaseException:
                conn.close()
                raise
            with self._lock:
                self._free.append(conn)
            if kind == "#RETURN":
                return result
            raise self._managers.convert_to_error(kind, result)

        call.__name__ = name
        return call

    def close_connections(self) -> None:
        """Close the pool's connections (not the host: its ``close`` is a call)."""
        with self._lock:
            free, self._free = self._free, []
        for conn in free:
            conn.close()


_Manager.register("BenchHost", _the_host)


class BenchClient:
    """A bench host and its channels (see the module docstring).

    Parameters
    ----------
    in_process : bool
        Run the host in this process (no child), e.g. for tests that replace code the
        host runs.
    jobs : dict, optional
        ``{name: function(ctx, **kwargs)}``: jobs of the packages above the instrument
        the host may run besides :data:`instrument.bench.bench_jobs.JOBS` (the functions are
        sent by reference: the bench process imports their modules).
    on_frame : callable, optional
        ``on_frame(frame, counters)``: every frame read (a
        :class:`drivers.camera.Frame`, its ``counters`` dict of :data:`FRAME_META`,
        ``published``: the frame's number in the slot, ``missed``: frames published
        since the last one read and not read).
    on_message, on_prompt, on_stream_ended : callable, optional
        ``on_message(text)``; ``on_prompt(action, message, reply)`` where
        ``reply(ok)`` answers the host; ``on_stream_ended()`` when the camera's stream
        stopped on an error (after ``on_message`` says which).
    on_event : callable, optional
        ``on_event(event)``: each :class:`~instrument.bench.bench_service.BenchEvent` the
        bench logs (settings, positions, status, the bench opened or closed), on a
        thread of this client.
    address, authkey : optional
        Connect to the bench process another client started (its :attr:`address` and
        :attr:`authkey`) instead of starting one: the devices' commands, the events,
        the stream's start and stop and the jobs (:meth:`start_job`, :meth:`run_job`)
        but opening and closing the bench; the frames stay with the client that
        started it, and closing this client leaves the bench open and its jobs
        running. :meth:`connect` reads both from the bench process's connection file.
    name : str, optional
        How the bench process names this client as the owner of its jobs and stream
        (``"the window"``); ``pid N`` is added (default: ``pid N`` alone).

    Once the bench process is gone (killed, ended), every call raises
    :class:`~instrument.bench.bench_service.BenchGoneError`, saying so.

    Raises
    ------
    EOFError
        The host process ended while starting.
    instrument.bench.bench_service.BenchGoneError
        No bench process at ``address``.
    multiprocessing.AuthenticationError
        ``authkey`` is not that bench process's.
    """

    def __init__(self, *, in_process: bool = False, jobs: Mapping[str, Callable] | None = None,
                 on_frame: Callable[[Any, dict], None] | None = None,
                 on_message: Callable[[str], None] | None = None,
                 on_prompt: Callable[[str, str, Callable[[bool], None]], None] | None = None,
                 on_stream_ended: Callable[[], None] | None = None,
                 on_event: Callable[[BenchEvent], None] | None = None,
                 address: Any = None, authkey: bytes | None = None,
                 name: str | None = None) -> None:
        self.in_process = bool(in_process)
        #: How the bench process names this client (the owner of its jobs and stream).
        self.name = f"{name} (pid {os.getpid()})" if name else f"pid {os.getpid()}"
        self.attached = address is not None
        self.on_frame, self.on_message, self.on_prompt = on_frame, on_message, on_prompt
        self.on_stream_ended, self.on_event = on_stream_ended, on_event
        #: Where a second client connects (None in process) and the key it needs.
        self.address, self.authkey = address, authkey
        #: The connection file the bench process this client started wrote
        #: (:mod:`instrument.bench.bench_connection`; None in process or when attached).
        self.connection_file: str | None = None
        ctx = multiprocessing.get_context("spawn")
        self._manager = None
        self._events = self._wake = None
        if self.attached:
            self._manager = _Manager(address=address, authkey=authkey)
            try:
                self._manager.connect()
            except (OSError, EOFError) as exc:
                raise gone(address, exc) from None
            self.host = _PooledHost(self._manager.BenchHost())
        else:
            # pipes, not queues or semaphores: nothing for the resource tracker to find
            # "leaked" when the window ends with os._exit
            self._events, events = ctx.Pipe(duplex=False)
            self._wake, wake = ctx.Pipe(duplex=False)
        if self.in_process:
            self.host = BenchHost(EventChannel(events), FrameWaker(wake))
            self.host.register_jobs(jobs or {})
        elif not self.attached:
            self.authkey = os.urandom(32)
            self._manager = _Manager(ctx=ctx, authkey=self.authkey)
            self._manager.start(_serve_init, (events, wake, os.getpid(), dict(jobs or {})))
            self.address = self._manager.address
            events.close()
            wake.close()
            self.host = _PooledHost(self._manager.BenchHost())
            self.connection_file = self.host.write_connection_file(self.address, self.authkey)
        self._lock = threading.Lock()
        self._slot: SharedImageSlot | None = None
        self._next_slot: tuple[str, int] | None = None
        self._seen = 0
        self._closed = threading.Event()
        self._threads = []
        if not self.attached:
            self._threads += [threading.Thread(target=self._dispatch, name="bench-events",
                                               daemon=True),
                              threading.Thread(target=self._read_frames, name="bench-frames",
                                               daemon=True)]
        #: {job id: run path} of the runs this client's bench process writes now (from
        #: the ``job`` events): closed here if that process is killed
        #: (:meth:`close_orphaned_runs`).
        self.writing: dict[int, str] = {}
        if on_event is not None or not (self.attached or self.in_process):
            first = self.host.events_after(None)[0] if self.attached else 0
            self._threads.append(threading.Thread(target=self._listen, args=(first,),
                                                  name="bench-device-events", daemon=True))
        for t in self._threads:
            t.start()

    @classmethod
    def connect(cls, path: str | os.PathLike | None = None, **options) -> BenchClient:
        """Attach to a running bench process by its connection file
        (:mod:`instrument.bench.bench_connection`): ``path``, or the newest of this user's
        that still runs (the window's, or ``diffuserlab bench serve``'s).

        Parameters
        ----------
        path : str or path, optional
        **options
            The other :class:`BenchClient` options (``on_event``, ``name``).

        Raises
        ------
        instrument.bench.bench_service.BenchGoneError
            No bench process runs (or the file's has ended), or the file is not a
            connection file.
        """
        from .bench_connection import find_connection_file, read_connection_file

        info = read_connection_file(find_connection_file() if path is None else path)
        return cls(address=info["address"], authkey=info["authkey"], **options)

    # -- the typed commands: BenchService's, proxied (see _proxy below) --------------
    def start_stream(self, ring_frames: int = 64) -> None:
        """:meth:`~instrument.bench.bench_host.BenchHost.start_stream` (frames: to the client
        that started the bench process); the stream holds the camera for this client,
        and yields it to a job that needs it."""
        self.host.start_stream(ring_frames, client=self.name)

    def stop_stream(self, timeout_s: float = 2.0) -> None:
        """:meth:`~instrument.bench.bench_host.BenchHost.stop_stream` (by this client: a
        stream another client started ends for it, told so)."""
        self.host.stop_stream(timeout_s, client=self.name)

    def set_closing(self, closing: bool) -> None:
        """Tell the bench the window closes (jobs then leave the bench as it is)."""
        self.host.set_closing(closing)

    def _listen(self, seq: int) -> None:
        """Hand each logged event to ``on_event`` (a long poll: the host answers as
        soon as one is logged)."""
        while not self._closed.is_set():
            try:
                seq, events = self.host.events_after(seq, 0.5)
            except Exception:  # noqa: BLE001 (the bench process ended or is ending)
                if self._closed.is_set() or not self.alive():
                    return
                self._closed.wait(0.5)
                continue
            for event in events:
                if event.kind == "job" and event.data.get("run"):
                    if event.data["state"] == "running":
                        self.writing[event.data["id"]] = event.data["run"]
                    else:
                        self.writing.pop(event.data["id"], None)
                if self.on_event is None:
                    continue
                try:
                    self.on_event(event)
                except Exception:  # noqa: BLE001 (a subscriber's fault: logged, not fatal)
                    log.exception("bench event %s: the subscriber failed", event.kind)

    # -- the bench process ---------------------------------------------------------
    def alive(self) -> bool:
        """Whether the host can still answer (its process runs)."""
        if self.in_process:
            return True
        if self.attached:
            try:
                self.host.events_after(None)
            except (OSError, EOFError, BenchGoneError):
                return False
            return True
        process = getattr(self._manager, "_process", None)
        return process is not None and not has_ended(process)

    def close_orphaned_runs(self) -> list[str]:
        """Close the runs the bench process this client started was writing when it
        ended unasked (killed): each still locked by that process is marked
        ``interrupted``, ``closed_by`` this client with why, its lock removed and its
        frames kept (:func:`instrument.bench.bench_recovery.close_orphaned_run`). Nothing
        while it runs, nor for a client in process or attached.

        Returns
        -------
        list of str
            The runs closed.
        """
        process = None if self.in_process or self.attached else getattr(
            self._manager, "_process", None)
        if process is None or not has_ended(process):
            return []
        from .bench_recovery import close_orphaned_run

        why = (f"the bench process (pid {process.pid}) that wrote it ended: "
               f"{how_it_ended(process.exitcode)}")
        closed = []
        for path in sorted(set(self.writing.values())):
            try:
                if close_orphaned_run(path, writer_pid=process.pid, closed_by=self.name,
                                      why=why):
                    closed.append(path)
                    log.warning("closed %s: %s", path, why)
            except Exception:  # noqa: BLE001 (one run's damage: logged, the others closed)
                log.exception("could not close %s after the bench process ended", path)
        return closed

    def exit_status(self) -> int | None:
        """How the bench process this client started ended: its exit code, or minus
        the number of the signal that ended it (``-9``: SIGKILL); the process is reaped
        (no zombie is left). None while it runs, and for a host in this process or a
        client connected by ``address``."""
        process = None if self.in_process or self.attached else getattr(
            self._manager, "_process", None)
        if process is None or not has_ended(process):
            return None
        return process.exitcode

    # -- jobs ------------------------------------------------------------------------
    def run_job(self, name: str, kwargs: dict | None = None, *,
                report: Callable[[Any], None] | None = None, control=None,
                stop: threading.Event | None = None, cancel: threading.Event | None = None,
                poll_s: float = 0.05) -> Any:
        """Run job ``name`` in the host and wait for it (see the module docstring).

        Raises
        ------
        BaseException
            What the job raised (its type kept when it can be pickled).
        instrument.bench.bench_host.BenchHostError
            The host process ended while the job ran.
        """
        job = self.start_job(name, kwargs, arrays=not self.attached)
        try:
            return self._run_held(job, report, control, stop, cancel, poll_s)
        except BenchGoneError:
            if self.attached or self.in_process:
                raise
            # its connection breaks while the killed process is ending: wait for its end
            # (reaped), so that close() finds it gone
            has_ended(self._manager._process, _ENDING_S)
            if self.alive():
                raise
            closed = self.close_orphaned_runs()
            kept = (f"; its run {', '.join(closed)} is closed (interrupted), "
                    "the frames it stored kept" if closed else "")
            raise BenchHostError(f"the bench process ended while the job ran"
                                 f"{kept}; start the bench again") from None

    def _run_held(self, job: JobHandle, report, control, stop, cancel, poll_s: float) -> Any:
        """Follow ``job`` by its handle (the route every client reads a job's events
        by), handing its progress to ``report`` and forwarding the caller's control,
        stop and cancel."""
        sent = {"paused": False, "abort": None, "stop": False, "cancel": False}
        while True:
            self._forward(job.id, sent, control, stop, cancel)
            for event in job.next_events(poll_s):
                if event.kind == "progress":
                    if report is not None:
                        report(event.data)
                else:
                    return job.result()

    def start_job(self, name: str, params: dict | None = None, *,
                  arrays: bool = False) -> JobHandle:
        """Start job ``name`` with ``params`` in the bench process and return at once
        (from any client: the window, a notebook).

        Parameters
        ----------
        name : str
            The job's name (:data:`instrument.bench.bench_jobs.JOBS` and those registered).
        params : dict, optional
            Its keyword parameters.
        arrays : bool
            The handle reads the newest progress event with its arrays
            (:meth:`~instrument.bench.bench_job_handle.JobRegistry.events_after`); False
            (default) leaves them out, as a notebook wants.

        Returns
        -------
        JobHandle
            Its id, its events (progress, then its result or error) to wait on, and
            ``stop()``; see :mod:`instrument.bench.bench_job_handle` for what happens to it
            when this client disconnects (it runs on).

        Raises
        ------
        instrument.bench.bench_host.BenchHostError
            No job of that name, or a second client asks for ``open_bench`` or
            ``close_bench`` (the window's), a parameter the job does not take (one
            line naming it and the accepted ones), no bench open for a job that needs
            its devices ("open the bench first"), or a device the job needs is held by
            another job (the line names that job and its owner; the holder's device is
            not touched).
        instrument.bench.bench_service.BenchGoneError
            The bench process is gone.
        """
        job_id = self.host.start_job(name, dict(params or {}), owner=not self.attached,
                                     client=self.name)
        return JobHandle(self.host, self.host.job_info(job_id), arrays)

    def job(self, job_id: int) -> JobHandle:
        """A handle on job ``job_id``, whichever client started it (from its first
        event kept).

        Raises
        ------
        instrument.bench.bench_service.BenchServiceError
            No such job, running or among the last ended.
        """
        return JobHandle(self.host, self.host.job_info(int(job_id)))

    def jobs(self) -> list[JobInfo]:
        """The bench process's jobs, running and recently ended, oldest first, whichever
        client started them (their ``owner``, ``state``, last ``progress`` and the
        devices they hold)."""
        return self.host.job_infos()

    def holders(self) -> dict[str, dict]:
        """:meth:`~instrument.bench.bench_host.BenchHost.holders`: who holds which device."""
        return self.host.holders()

    def _forward(self, job_id: int, sent: dict, control, stop, cancel) -> None:
        """Send the host the changes of the caller's control, stop and cancel."""
        if control is not None:
            if control.abort_reason is not None and sent["abort"] is None:
                sent["abort"] = control.abort_reason
                self.host.job_control(job_id, "abort", control.abort_reason)
            if control.paused != sent["paused"]:
                sent["paused"] = control.paused
                self.host.job_control(job_id, "pause" if control.paused else "resume")
        for name, event in (("stop", stop), ("cancel", cancel)):
            if event is not None and event.is_set() and not sent[name]:
                sent[name] = True
                self.host.job_control(job_id, name)

    # -- channels --------------------------------------------------------------------
    def _dispatch(self) -> None:
        while not self._closed.is_set():
            try:
                if not self._events.poll(0.2):
                    continue
                msg = self._events.recv()
            except (EOFError, OSError):
                return
            kind = msg[0]
            if kind == "slot":
                with self._lock:
                    self._next_slot = (msg[1], msg[2])
            elif kind == "stream_ended":
                if self.on_message is not None:
                    self.on_message(msg[1])
                if self.on_stream_ended is not None:
                    self.on_stream_ended()
            elif kind == "prompt" and self.on_prompt is not None:
                prompt_id = msg[1]
                self.on_prompt(msg[2], msg[3],
                               lambda ok, i=prompt_id: self.host.answer(i, bool(ok)))
            elif kind == "message" and self.on_message is not None:
                self.on_message(msg[1])

    def _read_frames(self) -> None:
        from drivers.camera import Frame

        while not self._closed.is_set():
            # a frame published before its slot's event arrived is read at the next
            # look (at most 0.1 s later)
            try:
                if select.select([self._wake], [], [], 0.1)[0]:
                    os.read(self._wake.fileno(), 65536)
            except (OSError, ValueError):
                return
            with self._lock:
                attach, self._next_slot = self._next_slot, None
            if attach is not None:  # the host made a larger slot: only this thread reads
                try:
                    new = SharedImageSlot(attach[1], name=attach[0])
                except FileNotFoundError:  # already gone: a newer slot's event follows,
                    new = None             # or the bench closed (the thread then ends)
                    log.debug("frame slot %s was gone before it was attached", attach[0])
                old, self._slot, self._seen = self._slot, new, 0
                if old is not None:
                    old.close()
            got = self._slot.read(after=self._seen) if self._slot is not None else None
            if got is None:
                continue
            meta = dict(zip(FRAME_META, (float(v) for v in got.meta), strict=False))
            meta["published"] = got.sequence
            meta["missed"] = got.sequence - self._seen - 1
            self._seen = got.sequence
            frame = Frame(got.image, int(meta["index"]), meta["device_timestamp_s"],
                          meta["host_timestamp_s"], meta["exposure_s"], meta["gain"],
                          int(meta["saturated_pixels"]))
            if self.on_frame is not None:
                self.on_frame(frame, meta)

    def close(self, timeout_s: float = 10.0) -> None:
        """Close the bench (if open) and end the host process and the threads (a client
        connected by ``address``: only its own connections and threads)."""
        if self.attached:
            self._closed.set()
            for t in self._threads:
                t.join(timeout_s)
            self.host.close_connections()
            return
        try:
            if self.in_process or self.alive():
                self.host.close()  # BenchHost.close, in the bench process
            else:
                self.close_orphaned_runs()
        finally:
            self._closed.set()
            for t in self._threads:
                t.join(timeout_s)
            if self._manager is not None:
                self.host.close_connections()
                self._manager.shutdown()
                if self.connection_file is not None:  # the process ended without removing it
                    try:
                        os.unlink(self.connection_file)
                    except OSError:
                        pass
            if self._slot is not None:
                self._slot.close()
                self._slot = None
            if self.in_process:
                self.host.events.conn.close()
                self.host.wake.conn.close()
            self._events.close()
            self._wake.close()


def _proxy(name: str) -> Callable:
    """``BenchClient.name``: :class:`~instrument.bench.bench_service.BenchService`'s command
    ``name`` called in the bench process, with its signature."""
    target = getattr(BenchService, name)

    def call(self, *args, **kwargs):
        return getattr(self.host, name)(*args, **kwargs)

    call.__name__, call.__qualname__ = name, f"BenchClient.{name}"
    call.__module__ = __name__
    call.__signature__ = inspect.signature(target)
    call.__doc__ = (f":meth:`~instrument.bench.bench_service.BenchService.{name}`, called in the "
                    "bench process (plain data in and out).")
    return call


#: BenchService's commands, each a method of :class:`BenchClient` that calls it in the
#: bench process (as pymmcore-plus's RemoteMMCore proxies CMMCorePlus): one written
#: command, no hand-written forwarder; a command added to the service is the client's.
PROXIED = tuple(name for name, _ in inspect.getmembers(BenchService, inspect.isfunction)
                if not name.startswith("_") and name not in vars(BenchClient))
for _name in PROXIED:
    setattr(BenchClient, _name, _proxy(_name))

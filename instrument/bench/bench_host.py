"""The bench's owner in a process of its own: devices, camera stream and jobs.

The operator's window keeps nothing of the bench in its own process: a
:class:`BenchHost` owns the open :class:`~instrument.devices.bench.Bench` (or virtual bench),
streams its camera and runs the jobs that use the devices (a calibration run, the
mask alignment, a recording), in the child process that
:class:`instrument.bench.bench_process.BenchClient` starts. Compute and device waits of
the host then never take the window's interpreter lock or its cores' time slices
(the pattern of Micro-Manager's core and PyMoDAQ's hardware workers, here as a
process). The same class also runs in the caller's process
(``BenchClient(in_process=True)``), with the same frame and event
channels, so the one code path is tested both ways.

What crosses between the processes:

* commands on the devices by their ids, plain data in and out, and the events that
  say what changed: the host is a :class:`~instrument.bench.bench_service.BenchService`. No
  device object leaves the host.
* frames: the stream's frames (and a recording's) go into a
  :class:`~instrument.acquisition.shared_slot.SharedImageSlot` (newest only) and a byte down a pipe
  wakes the reader (:class:`FrameWaker`); each carries its metadata and the ring's
  counters (:data:`FRAME_META`).
* events: ``(kind, ...)`` tuples down a pipe (:class:`EventChannel`): a prompt
  for the operator (``("prompt", id, action, message)``), a new frame slot (``("slot", name,
  capacity)``), the stream's end unasked (``("stream_ended", text)``: the camera's
  error, no frame for :meth:`BenchHost.stream_silence_s`, a frame that could not be
  published; every client's events also get ``stream`` ``{"state": "ended", ...}``),
  and ``stream`` events ``{"state": "yielded", "to": job}`` and ``{"state":
  "resumed"}`` while a job holds the live stream's camera.
* jobs: :meth:`BenchHost.start_job` runs a job by its name (:data:`instrument.bench.bench_jobs.JOBS`
  and those given to :meth:`BenchHost.register_jobs`) as ``function(ctx, **kwargs)`` on
  a thread of the host with a :class:`JobContext` (the bench, progress, pause/abort,
  stop and cancel events); :meth:`BenchHost.job_control` pauses, resumes, aborts, stops
  or cancels it, whichever client asks. A job holds the devices it declares
  (:func:`instrument.bench.bench_jobs.holding`) and the live stream holds the camera: a job
  needing a held device is refused before anything touches it, naming the holder and
  its owner (:meth:`BenchHost.holders`), and the stream yields the camera to a job and
  starts again when it ends. Every job's progress and end is logged in
  :attr:`BenchHost.job_registry`, the one route by which every client follows it, the
  one that started it too (:class:`~instrument.bench.bench_job_handle.JobHandle`).
"""

from __future__ import annotations

import itertools
import logging
import os
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from ..acquisition.runner import RunControl
from ..acquisition.shared_slot import SharedImageSlot
from .bench_job_handle import OWNER_JOBS, JobInfo, JobRegistry, check_params
from .bench_service import BenchService, BenchServiceError, EventLog

__all__ = ["FRAME_META", "JOBS_CLOSE_TIMEOUT_S", "STREAM_SILENCE_FLOOR_S",
           "STREAM_SILENCE_PERIODS", "BenchHost", "BenchHostError", "EventChannel",
           "FrameWaker", "JobContext"]

log = logging.getLogger(__name__)

#: The metadata each published frame carries in its slot, in order.
FRAME_META = ("index", "device_timestamp_s", "host_timestamp_s", "exposure_s", "gain",
              "saturated_pixels", "acquired", "read", "skipped", "dropped", "bit_depth")

#: The shortest silence, s, after which a free-run stream with no frame ends as a
#: stream that died (:meth:`BenchHost.stream_silence_s`): longer than the stalls a
#: loaded machine gives the camera's threads (seconds at a load of 15 on 2 cores).
STREAM_SILENCE_FLOOR_S = 10.0
#: A free-run stream also waits this many frame periods (a long exposure's).
STREAM_SILENCE_PERIODS = 10

#: Longest wait, s, for the jobs to end when the bench closes (a recording writes what
#: it has queued and closes its run first).
JOBS_CLOSE_TIMEOUT_S = 60.0


def _silence_text(silent_s: float, bound_s: float, lost: int) -> str:
    """The operator's line for a stream that sent no frame for ``silent_s`` (of a
    bound of ``bound_s``), ``lost`` frames dropped on the way meanwhile."""
    why = (f"; {lost} frames were lost on the way" if lost > 0 else "")
    return (f"camera stream stopped: no frame from the camera for {silent_s:.3g} s (the "
            f"stream waits {bound_s:.3g} s{why}); check the camera's cable and power, then "
            "start the stream again (Start stream)")


class BenchHostError(BenchServiceError):
    """A call the bench host cannot serve: no bench open, an unknown job."""


class JobContext:
    """What a job running in the host gets: ``bench``, ``report(value)`` (progress to
    the client), ``control`` (:class:`~instrument.acquisition.runner.RunControl`), ``stop`` and
    ``cancel`` (``threading.Event``), ``publish(frame)`` (show a frame the job
    took in the window, as the stream does) and ``host`` (its :class:`BenchHost`)."""

    def __init__(self, host: BenchHost, job_id: int) -> None:
        self.host, self.job_id = host, job_id
        self.control = RunControl()
        self.stop = threading.Event()
        self.cancel = threading.Event()
        self.thread: threading.Thread | None = None

    @property
    def bench(self):
        return self.host.bench

    def report(self, value: Any) -> None:
        self.host.job_registry.report(self.job_id, value)

    def publish(self, frame) -> None:
        self.host.publish(frame)


class EventChannel:
    """The host's end of the event pipe: ``put`` sends one event (any thread)."""

    def __init__(self, conn) -> None:
        self.conn = conn
        self._lock = threading.Lock()

    def put(self, event: tuple) -> None:
        with self._lock:
            try:
                self.conn.send(event)
            except (OSError, ValueError):  # the window is gone: nobody to tell
                log.debug("event %s not sent: the window's end is closed", event[0])


class FrameWaker:
    """The host's end of the frame pipe: ``release`` writes one byte, never
    waiting (a reader that fell behind finds the pipe full and reads the newest frame
    anyway)."""

    def __init__(self, conn) -> None:
        self.conn = conn
        os.set_blocking(conn.fileno(), False)

    def release(self) -> None:
        try:
            os.write(self.conn.fileno(), b"\0")
        except (BlockingIOError, OSError):
            pass


class BenchHost(BenchService):
    """The open bench, its camera stream and its jobs (see the module docstring).

    Parameters
    ----------
    events : EventChannel
        Where events go (``put((kind, ...))``).
    wake : FrameWaker
        Released once per published frame.
    """

    def __init__(self, events, wake) -> None:
        self.events, self.wake = events, wake
        self.bench = None
        #: True while the window closes: jobs leave the bench as it is.
        self.closing = False
        self._slot: SharedImageSlot | None = None
        self._publish_lock = threading.Lock()
        self._stream: tuple[Any, threading.Thread, threading.Event] | None = None
        self._stream_lock = threading.RLock()
        self._jobs: dict[int, JobContext] = {}
        #: {device id: job id} of the devices the running jobs hold.
        self._holds: dict[str, int] = {}
        self._holds_lock = threading.RLock()
        self._stream_owner = ""
        self._stream_frames = 64
        #: The floor of :meth:`stream_silence_s`, s (a test makes it short).
        self.stream_silence_floor_s = STREAM_SILENCE_FLOOR_S
        #: True while :meth:`close` ends the jobs (the live view is not started again).
        self._ending = False
        #: (ring frames, client) of a live stream to start when the camera is free.
        self._resume: tuple[int, str] | None = None
        self._ids = itertools.count(1)
        self._prompts: dict[int, tuple[threading.Event, dict]] = {}
        #: The jobs :meth:`start_job` runs, by name.
        self.jobs: dict[str, Callable] = {}
        from .bench_jobs import JOBS

        self.register_jobs(JOBS)
        self.device_events = EventLog()
        #: Every job's events and outcome, for any client
        #: (:class:`~instrument.bench.bench_job_handle.JobHandle`).
        self.job_registry = JobRegistry(self.device_events)
        self._watcher: tuple[threading.Thread, threading.Event] | None = None
        #: This bench process's connection file (None: none written).
        self.connection_file: str | None = None
        self._connection: tuple[Any, bytes] | None = None

    def write_connection_file(self, address: Any, authkey: bytes) -> str:
        """Write this bench process's connection file
        (:func:`instrument.bench.bench_connection.write_connection_file`), removed when the
        process ends; its path."""
        import atexit

        from .bench_connection import write_connection_file

        self._connection = (address, authkey)
        path = write_connection_file(address, authkey, bench=self._serving())
        if self.connection_file is None:
            atexit.register(self.remove_connection_file)
        self.connection_file = str(path)
        return self.connection_file

    def _serving(self) -> str | None:
        bench = self.bench
        if bench is None:
            return None
        if self.is_virtual():
            return "simulated"
        config = getattr(bench, "config", None)
        return getattr(config, "name", None)

    def remove_connection_file(self) -> None:
        """Remove the connection file (the process ends: nobody to connect to)."""
        path, self.connection_file = self.connection_file, None
        if path is not None:
            try:
                os.unlink(path)
            except OSError:
                pass

    def describe(self) -> dict | None:
        """``{"devices": [ids], "virtual": bool}`` of the open bench (None: none)."""
        if self.bench is None:
            return None
        return {"devices": list(self.bench.devices), "virtual": self.is_virtual()}

    def set_closing(self, closing: bool) -> None:
        self.closing = bool(closing)

    # -- operator prompts ------------------------------------------------------------
    def ask(self, action: str, message: str) -> bool:
        """Ask the operator (a plan's prompt on a real bench) and wait for
        ``answer``."""
        prompt_id = next(self._ids)
        done, answer = threading.Event(), {}
        self._prompts[prompt_id] = (done, answer)
        self.events.put(("prompt", prompt_id, action, message))
        done.wait()
        self._prompts.pop(prompt_id, None)
        return bool(answer.get("ok"))

    def answer(self, prompt_id: int, ok: bool) -> None:
        done, answer = self._prompts.get(int(prompt_id), (None, None))
        if done is not None:
            answer["ok"] = bool(ok)
            done.set()

    # -- frames ----------------------------------------------------------------------
    def publish(self, frame, ring=None) -> None:
        """Put ``frame`` (a :class:`drivers.camera.Frame`) in the frame slot with its
        metadata and ``ring``'s counters, and wake the reader."""
        image = frame.image
        with self._publish_lock:
            if self._slot is None or image.nbytes > self._slot.capacity:
                old, self._slot = self._slot, SharedImageSlot(max(image.nbytes, 1 << 20))
                self.events.put(("slot", self._slot.name, self._slot.capacity))
                if old is not None:
                    old.close()
            counters = ((ring.acquired, ring.read, ring.skipped, ring.dropped)
                        if ring is not None else (0, 0, 0, 0))
            cam = getattr(self.bench, "camera", None)
            bit_depth = getattr(cam, "bit_depth", 16) if cam is not None else 16
            self._slot.write(image, (frame.index, frame.device_timestamp_s,
                                     frame.host_timestamp_s, frame.exposure_s, frame.gain,
                                     frame.saturated_pixels, *counters, bit_depth))
        self.wake.release()

    @property
    def streaming(self) -> bool:
        stream = self._stream
        return stream is not None and stream[1].is_alive()

    def start_stream(self, ring_frames: int = 64, client: str = "") -> None:
        """Start the camera's free-run stream and the thread that publishes its frames.

        The stream holds the camera for ``client`` (the live view): a job that needs the
        camera takes it and gives it back (:meth:`start_job`). While a job holds the
        camera, the stream starts when that job ends (a message says so).

        Raises
        ------
        BenchHostError
            No bench is open.
        drivers.errors.DeviceError
            The camera refused to stream.
        """
        from drivers.camera import FrameRing

        with self._holds_lock, self._stream_lock:
            if self.streaming:
                return
            cam = self._camera()
            holder = self._holds.get(self._camera_id())
            if holder is not None:
                self._resume = (int(ring_frames), client or "an unnamed client")
                taker = self.job_registry.info(holder).describe()
                self._say(f"live view: the camera is held by {taker}; the live view "
                          "starts when it ends")
                self.device_events.put("stream", None, {"state": "yielded", "to": taker,
                                                        "owner": self._resume[1]})
                return
            ring = FrameRing(ring_frames)
            cam.start_stream(ring)
            stop = threading.Event()
            pump = threading.Thread(target=self._pump, args=(ring, stop),
                                    name="bench-stream", daemon=True)
            self._stream = (ring, pump, stop)
            self._stream_frames = int(ring_frames)
            self._stream_owner = client or "an unnamed client"
            pump.start()

    def stop_stream(self, timeout_s: float = 2.0, client: str = "") -> None:
        """Stop the stream (idempotent); waits for the camera's grab thread. A stream
        that yielded the camera to a job is not started again; the job's camera is
        left alone. Stopped by a ``client`` other than the one it runs for, it ends
        for that one as a stream that ended unasked (told who stopped it)."""
        with self._holds_lock:
            owner = (self._stream_owner if self._stream is not None
                     else self._resume[1] if self._resume is not None else None)
            self._resume = None
            self._stop_stream_now(timeout_s)
        if owner is not None and client and client != owner:
            self._tell_stream_ended(f"live stream stopped by {client}")

    def _stop_stream_now(self, timeout_s: float = 2.0) -> None:
        with self._stream_lock:
            if self._stream is None:
                return
            _, pump, stop = self._stream
            stop.set()
            try:
                if self.bench is not None:
                    self.bench.camera.stop_stream()
            finally:
                pump.join(timeout_s)
                self._stream = None

    def stream_silence_s(self) -> float:
        """How long, s, the stream waits for a frame before it ends as a stream that
        died: ``max(stream_silence_floor_s, STREAM_SILENCE_PERIODS x the camera's frame
        period)`` in free-run (the period from its resulting frame rate, which a long
        exposure lowers); infinite in a triggered mode (a camera waiting for its
        trigger is silent by design)."""
        floor = float(self.stream_silence_floor_s)
        cam = getattr(self.bench, "camera", None)
        if cam is None:
            return floor
        try:
            if cam.trigger_mode != "free_run":
                return float("inf")
            period_s = 1.0 / float(cam.resulting_frame_rate_hz)
        except Exception:  # noqa: BLE001 (a camera that cannot say: the floor)
            return floor
        return max(floor, STREAM_SILENCE_PERIODS * period_s)

    def _pump(self, ring, stop: threading.Event) -> None:
        """Publish the stream's frames until ``stop``; a stream that ends otherwise (the
        camera's error, no frame for :meth:`stream_silence_s`, a frame that cannot be
        published) ends as a stream that died (:meth:`_stream_died`)."""
        from drivers.errors import CameraTimeoutError

        last, dropped = time.monotonic(), ring.dropped
        try:
            while not stop.is_set():
                try:
                    frame = ring.get(timeout_s=0.05)
                except CameraTimeoutError:
                    silent_s = time.monotonic() - last
                    if silent_s > self.stream_silence_floor_s:
                        bound_s = self.stream_silence_s()
                        if silent_s > bound_s:
                            self._stream_died(stop, _silence_text(
                                silent_s, bound_s, ring.dropped - dropped))
                            return
                    continue
                last, dropped = time.monotonic(), ring.dropped
                self.publish(frame, ring)
        except Exception as exc:  # noqa: BLE001 (the camera's or the frame channel's)
            self._stream_died(stop, f"camera stream stopped: {exc}")

    def _tell_stream_ended(self, text: str) -> None:
        """Tell every client the live stream ended unasked, saying why in ``text``."""
        log.info("bench process: %s", text)  # the window's log shows it once, as told
        self.events.put(("stream_ended", text))
        self.device_events.put("stream", None, {"state": "ended", "reason": text,
                                                "owner": self._stream_owner})

    def _stream_died(self, stop: threading.Event, text: str) -> None:
        """The stream whose stop event is ``stop`` ended unasked (on its pump thread):
        the camera's stream is stopped, then the client that started the bench process is
        sent ``("stream_ended", text)`` and every client's events get a ``stream``
        event (``{"state": "ended", "reason": text, "owner": ...}``). Nothing if the
        stream was stopped meanwhile."""
        while not self._stream_lock.acquire(timeout=0.05):
            if stop.is_set():  # being stopped: its stopper waits for this thread
                return
        try:
            if self._stream is None or self._stream[2] is not stop or stop.is_set():
                return
            stop.set()
            self._stream = None
            cam = getattr(self.bench, "camera", None)
            if cam is not None:  # first: a client told may snap at once
                try:
                    cam.stop_stream()
                except Exception as exc:  # noqa: BLE001 (it died already; logged)
                    log.warning("bench process: the camera's stream did not stop: %s", exc)
            self._tell_stream_ended(text)
        finally:
            self._stream_lock.release()

    # -- jobs ------------------------------------------------------------------------
    def register_jobs(self, jobs: Mapping[str, Callable]) -> None:
        """Add ``{name: function(ctx, **kwargs)}`` to the jobs :meth:`start_job` runs."""
        self.jobs.update(jobs)

    def start_job(self, name: str, kwargs: dict | None = None, *, owner: bool = True,
                  client: str = "") -> int:
        """Run job ``name`` as ``function(ctx, **kwargs)`` on a thread; returns the job's
        id. Its progress and end go to :attr:`job_registry`, where every client reads
        them by its :class:`~instrument.bench.bench_job_handle.JobHandle` (the one that
        started it too: one route, the same sequence numbers for all).

        The devices the job declares (:func:`instrument.bench.bench_jobs.holding`) are
        checked first and held for it until it ends: a device another job holds
        refuses the job before anything touches it. The live stream yields the camera
        (stopped, a message saying who took it, started again when the job ends).

        Parameters
        ----------
        name : str
        kwargs : dict, optional
            The job's parameters: a key its signature does not name, or one its own
            check refuses, is refused
            (:func:`instrument.bench.bench_job_handle.check_params`).
        owner : bool
            Asked by the client that started the bench process (a second client may
            not run :data:`~instrument.bench.bench_job_handle.OWNER_JOBS`).
        client : str
            The asking client's name (the job's owner, as refusals name it).

        Raises
        ------
        BenchHostError
            No job of that name, a second client asks to open or close the bench, a
            parameter the job does not accept, or a device it needs is held by another
            job (the message names that job and its owner).
        """
        fn = self.jobs.get(name)
        if fn is None:
            raise BenchHostError(f"the bench process has no job {name!r}; its jobs are "
                                 f"{', '.join(sorted(self.jobs))}")
        if not owner and name in OWNER_JOBS:
            raise BenchHostError(f"{name} runs from the client that started the bench "
                                 "process (the window); use the window's Connect and "
                                 "Disconnect")
        kwargs = dict(kwargs or {})
        check_params(name, fn, kwargs)
        if getattr(fn, "holds", ()) and self.bench is None:
            raise BenchHostError(f"{name}: no bench is open; open the bench first (the "
                                 "window's Connect, the open_bench job, or `diffuserlab "
                                 "bench serve`)")
        client = client or "an unnamed client"
        with self._holds_lock:
            holds = self._needs(name, fn)
            for device in holds:
                holder = self._holds.get(device)
                if holder is not None:
                    raise BenchHostError(
                        f"{name}: {device} is held by {self.job_registry.info(holder).describe()}"
                        "; wait for it to end, or stop it (BenchClient.jobs() lists the "
                        "jobs)")
            job_id = next(self._ids)
            ctx = JobContext(self, job_id)
            self._jobs[job_id] = ctx
            self.job_registry.started(job_id, name, kwargs, client, holds)
            for device in holds:
                self._holds[device] = job_id
            camera = self._camera_id()
            yielded = camera in holds and self._stream is not None
            if yielded:
                self._yield_stream(job_id)

        def run() -> None:
            from diffuserlab.processes import portable_error

            try:
                result = fn(ctx, **kwargs)
            except BaseException as exc:  # noqa: BLE001 (every failure goes back)
                self._job_ended(ctx, "failed", portable_error(exc, "the bench process"))
            else:
                self._job_ended(ctx, "done", result)

        ctx.thread = threading.Thread(target=run, name=f"bench-job-{name}", daemon=True)
        ctx.thread.start()
        return job_id

    def _needs(self, name: str, fn: Callable) -> tuple[str, ...]:
        """The ids of the devices job ``fn`` declares it holds, on the open bench."""
        declared = getattr(fn, "holds", ())
        bench = self.bench
        if not declared or bench is None:
            return ()
        if "*" in declared:
            return tuple(bench.devices)
        ids = []
        for role in declared:
            dev = bench.camera if role == "camera" else bench.devices.get(role)
            found = [i for i, d in bench.devices.items() if d is dev]
            ids += [i for i in found if i not in ids]
        return tuple(ids)

    def _camera_id(self) -> str | None:
        bench = self.bench
        if bench is None:
            return None
        return next((i for i, d in bench.devices.items() if d is bench.camera), None)

    def holders(self) -> dict[str, dict]:
        """``{device id: {"job", "name", "owner"}}`` of the devices jobs hold now, and
        the live stream's camera (``"job"`` None, ``"name"`` ``live stream``)."""
        with self._holds_lock:
            out = {d: {"job": i, "name": self.job_registry.info(i).name,
                       "owner": self.job_registry.info(i).owner}
                   for d, i in self._holds.items()}
            camera = self._camera_id()
            if self._stream is not None and camera is not None and camera not in out:
                out[camera] = {"job": None, "name": "live stream", "owner": self._stream_owner}
        return out

    def _say(self, text: str) -> None:
        log.info("bench process: %s", text)
        self.events.put(("message", text))
        self.device_events.put("message", None, text)

    def _yield_stream(self, job_id: int) -> None:
        """The live stream gives the camera to job ``job_id`` (held lock: _holds_lock)."""
        self._resume = (self._stream_frames, self._stream_owner)
        self._stop_stream_now()
        taker = self.job_registry.info(job_id).describe()
        self._say(f"live view: the camera was taken by {taker}; the live view comes back "
                  "when it ends")
        self.device_events.put("stream", None, {"state": "yielded", "to": taker,
                                                "owner": self._stream_owner})

    def _job_ended(self, ctx: JobContext, state: str, value: Any) -> None:
        self._jobs.pop(ctx.job_id, None)
        with self._holds_lock:
            for device in [d for d, i in self._holds.items() if i == ctx.job_id]:
                del self._holds[device]
            back = (self._resume is not None and self._camera_id() not in self._holds
                    and not self.closing and not self._ending and self.bench is not None)
            resume, self._resume = (self._resume, None) if back else (None, self._resume)
        try:
            if resume is not None:
                try:
                    self.start_stream(resume[0], client=resume[1])
                    self._say(f"live view: the camera is back from job {ctx.job_id}")
                    self.device_events.put("stream", None, {"state": "resumed",
                                                            "owner": resume[1]})
                except Exception as exc:  # noqa: BLE001 (said; the job's end still goes out)
                    self._say(f"live view: could not start again after job {ctx.job_id}: "
                              f"{exc}")
                    self._tell_stream_ended(f"camera stream stopped: {exc}")
        finally:
            self.job_registry.ended(ctx.job_id, state, value)

    def job_info(self, job_id: int) -> JobInfo:
        """:meth:`~instrument.bench.bench_job_handle.JobRegistry.info`."""
        return self.job_registry.info(job_id)

    def job_infos(self) -> list[JobInfo]:
        """:meth:`~instrument.bench.bench_job_handle.JobRegistry.infos`."""
        return self.job_registry.infos()

    def job_events_after(self, job_id: int, seq: int, timeout_s: float = 1.0,
                         arrays: bool = False) -> tuple:
        """:meth:`~instrument.bench.bench_job_handle.JobRegistry.events_after`."""
        return self.job_registry.events_after(job_id, seq, timeout_s, arrays)

    def job_control(self, job_id: int, action: str, reason: str = "") -> None:
        """``pause``, ``resume``, ``abort`` (with ``reason``), ``stop`` or ``cancel`` job
        ``job_id`` (a job that ended already: nothing)."""
        ctx = self._jobs.get(int(job_id))
        if ctx is None:
            return
        if action == "pause":
            ctx.control.pause()
        elif action == "resume":
            ctx.control.resume()
        elif action == "abort":
            ctx.control.abort(reason or "aborted by the operator")
        elif action in ("stop", "cancel"):
            getattr(ctx, action).set()
        else:
            raise BenchHostError(f"unknown job action {action!r}; use pause, resume, abort, "
                                 "stop or cancel")

    def open_bench(self, bench) -> None:
        """Make ``bench`` (opened by a job) the host's bench, and start watching its
        devices for changes (:class:`~instrument.bench.bench_service.BenchService`)."""
        self._stop_watch()
        self.bench = bench
        stop = threading.Event()
        watcher = threading.Thread(target=self._watch, args=(stop,), name="bench-watch",
                                   daemon=True)
        self._watcher = (watcher, stop)
        if self._connection is not None:  # say what it serves now
            self.write_connection_file(*self._connection)
        self.device_events.put("bench", None, {"open": True, "devices": list(bench.devices)})
        watcher.start()

    def _stop_watch(self) -> None:
        watcher, self._watcher = self._watcher, None
        if watcher is not None:
            watcher[1].set()
            if watcher[0] is not threading.current_thread():
                watcher[0].join(10.0)

    def close(self, jobs_timeout_s: float = JOBS_CLOSE_TIMEOUT_S) -> None:
        """End every job and close the stream, the bench and the frame slot.

        Each job is aborted, stopped and cancelled (a recording stops as on Ctrl-C:
        status ``stopped``, its lock released; a calibration run aborts to the safe
        state) and a prompt waiting for the operator is refused; the bench closes once
        the jobs have ended (the job calling this excepted), or after
        ``jobs_timeout_s`` (a job stuck in a device call: logged, the bench closed
        under it).
        """
        current = threading.current_thread()
        self._ending = True
        self._resume = None
        jobs = [ctx for ctx in list(self._jobs.values()) if ctx.thread is not current]
        for ctx in jobs:
            ctx.control.abort("the bench is closing")
            ctx.stop.set()
            ctx.cancel.set()
        for prompt_id in list(self._prompts):
            self.answer(prompt_id, False)
        deadline = time.monotonic() + jobs_timeout_s
        for ctx in jobs:
            if ctx.thread is not None:
                ctx.thread.join(max(0.0, deadline - time.monotonic()))
                if ctx.thread.is_alive():
                    log.warning("job %s did not end within %.0f s of the bench closing; "
                                "closing the bench under it", ctx.thread.name, jobs_timeout_s)
        try:
            self._stop_watch()
            self.stop_stream()
        finally:
            bench, self.bench = self.bench, None
            if bench is not None:
                bench.close()
                self.device_events.put("bench", None, {"open": False, "devices": []})
            with self._publish_lock:
                if self._slot is not None:
                    self._slot.close()
                    self._slot = None
            self._ending = False

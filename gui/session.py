"""The GUI's bench session: the open bench, the camera stream and who uses the camera.

One :class:`Session` per window. The bench lives in a process of its own (a
:class:`instrument.bench.bench_host.BenchHost` served to the window by
:class:`instrument.bench.bench_process.BenchClient`): the devices, the camera's stream and
the jobs that use them (calibration runs, the mask alignment, recordings; bodies in
:mod:`instrument.bench.bench_jobs` and :mod:`calibration_routines.bench_jobs`) run there, so
their compute and device waits never take this process's interpreter lock.
``session.service`` is that bench's typed service
(:class:`~instrument.bench.bench_service.BenchService` commands by device id, with plain
data), ``session.devices`` its devices (:class:`~instrument.bench.bench_service.DeviceInfo`),
and the changes the bench process pushes (settings, positions, statuses) come as the
``device_event`` signal. The bench file's bench is opened,
or with ``simulate`` the virtual bench streaming in real time, as ``capture live
--simulate`` does.

The stream's frames come through shared memory to a reader thread here, which keeps
the newest for the displays and hands each frame to the consumers (the live
reconstruction's :meth:`~instrument.acquisition.live_process.LiveReconstructionProcess.offer`),
which never block.

A camera cannot stream and snap at once, so jobs that take frames themselves (a
calibration run, the mask alignment, a video recording that streams on its own)
claim the camera first (:meth:`Session.claim_camera`): the stream stops, and
another claimant is refused with a message naming the job that holds it.

:data:`BENCH_IN_PROCESS` runs the same host in the window's process instead (tests
that replace code the host runs); :data:`BENCH_JOBS` are the jobs the bench process may
run besides the instrument's own.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from PySide6.QtCore import QObject, QTimer, Signal

from calibration_routines.bench_jobs import JOBS as CALIBRATION_JOBS

from .workers import DEVICE_NICE, CameraBusy, Job

__all__ = ["CameraBusy", "RATE_WINDOW_S", "SCENES", "Session"]

log = logging.getLogger(__name__)

#: The camera's frame rate shown is measured over this many seconds.
RATE_WINDOW_S = 2.0

#: Moving scenes the virtual bench can put in front of the camera (``--simulate``).
SCENES = ("beads-flow", "neurons", "none")

#: How often the window looks whether the bench process still runs, ms (a look reaps
#: a process that ended: no zombie is left).
BENCH_WATCH_MS = 500

#: Run the bench host in the window's process (False: in a process of its own).
BENCH_IN_PROCESS = False

#: The jobs the bench process may run besides :data:`instrument.bench.bench_jobs.JOBS`, by
#: name (tests add theirs before the bench opens).
BENCH_JOBS: dict[str, Callable] = dict(CALIBRATION_JOBS)


class Session(QObject):
    """The open bench of one GUI window (see the module docstring).

    Parameters
    ----------
    bench_path : str, optional
        Bench TOML file; None with ``simulate`` is the built-in simulated bench.
    simulate : bool
        Swap every device for its simulated twin on the real-time virtual bench.
    seed : int
        Seed of the virtual bench.
    scene : str
        ``simulate``: the moving scene in front of the camera at start (:data:`SCENES`).

    Signals
    -------
    changed()
        Connected, disconnected, streaming started or stopped, camera claimed or
        released.
    message(str)
        A line for the status bar / log.
    prompt(str, str, object)
        ``(action, message, reply)``: a plan asks the operator to do something on a
        real bench; the GUI answers with ``reply(bool)``.
    device_event(object)
        A :class:`~instrument.bench.bench_service.BenchEvent` the bench process pushed.
    bench_lost(str)
        The bench process ended without being asked (killed, crashed): the operator's
        message, also in :attr:`lost`; ``changed`` follows (not connected).
    """

    changed = Signal()
    message = Signal(str)
    prompt = Signal(str, str, object)
    device_event = Signal(object)
    bench_lost = Signal(str)
    _resume = Signal()
    _stream_ended = Signal()

    def __init__(self, bench_path: str | None = None, *, simulate: bool = False,
                 seed: int = 0, scene: str = "beads-flow") -> None:
        super().__init__()
        self.bench_path = bench_path
        self.simulate = bool(simulate)
        self.seed = int(seed)
        #: The open bench's typed service, a
        #: :class:`~instrument.bench.bench_process.BenchClient` (None: not connected).
        self.service = None
        #: ``{device id: DeviceInfo}`` of the open bench (empty: not connected).
        self.devices: dict = {}
        #: ``{device id: data}`` of the last ``status`` event of each device (what a
        #: panel built after the event shows first).
        self.device_states: dict[str, dict] = {}
        self._virtual = False
        if scene not in SCENES:
            raise ValueError(f"scene {scene!r} is unknown; use one of {', '.join(SCENES)}")
        self.scene_name = scene
        self.camera_user: str | None = None
        self._closing = False
        self._consumers: dict[str, Callable[[Any], None]] = {}
        self._latest = None
        self._counters: dict[str, float] = {}
        self._streaming = False
        #: The live stream was asked back (a job gave the camera back) and has not
        #: started yet: a job that takes the camera meanwhile gives it back the same way.
        self._resume_pending = False
        #: Why the live stream ended unasked (the bench's line), until it starts again
        #: or is stopped; None: it did not.
        self.stream_end_reason: str | None = None
        #: The job of the bench (``job 4 (record) of a notebook``) that took the live
        #: stream's camera, until it gives it back; None: none.
        self.stream_taken_by: str | None = None
        self._lock = threading.Lock()
        self._stream_lock = threading.RLock()  # one start or stop at a time
        self.frames_seen = 0
        self._rate: deque[tuple[float, int]] = deque()
        self.job: Job | None = None
        #: Why the bench process ended without being asked (None: it did not): the
        #: operator's message, until the bench is connected again.
        self.lost: str | None = None
        self._watch = QTimer(self)
        self._watch.setInterval(BENCH_WATCH_MS)
        self._watch.timeout.connect(self._check_bench)
        self._resume.connect(self._resume_stream)
        self.device_event.connect(self._note_event)
        self._stream_ended.connect(self.changed.emit)

    # -- connection -----------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self.service is not None

    @property
    def is_virtual(self) -> bool:
        """The bench is the virtual bench (``simulate``)."""
        return self.service is not None and self._virtual

    @property
    def closing(self) -> bool:
        """True while the window closes (jobs then leave the bench as it is)."""
        return self._closing

    @closing.setter
    def closing(self, value: bool) -> None:
        self._closing = bool(value)
        service = self.service
        if service is not None:
            try:
                service.set_closing(self._closing)
            except Exception as exc:  # noqa: BLE001 (a bench process already gone)
                log.warning("could not tell the bench process the window closes: %s", exc)

    def connect_bench(self, on_error: Callable[[str], None] | None = None,
                      on_open: Callable[[], None] | None = None) -> Job:
        """Open the bench on a worker thread; ``changed`` fires when it is open, then
        ``on_open()``; ``on_error(message)`` is called if it cannot be opened."""
        self.device_states = {}
        job = Job(self._open, name="open-bench", nice=DEVICE_NICE)
        job.succeeded.connect(self._opened)
        job.failed.connect(lambda text: self.message.emit(f"could not connect: {text}"))
        if on_error is not None:
            job.failed.connect(on_error)
        if on_open is not None:
            job.succeeded.connect(lambda _: on_open())
        self.job = job
        return job.start()

    def _open(self, job: Job):
        from instrument.bench.bench_process import BenchClient

        client = BenchClient(in_process=BENCH_IN_PROCESS, jobs=BENCH_JOBS, name="the window",
                             on_frame=self._on_frame,
                             on_message=self.message.emit, on_prompt=self.prompt.emit,
                             on_stream_ended=self._on_stream_ended,
                             on_event=self.device_event.emit)
        try:
            client.run_job("open_bench", {"bench_path": self.bench_path,
                                          "simulate": self.simulate, "seed": self.seed,
                                          "scene": self.scene_name}, cancel=job.cancel_event)
            devices = {d.name: d for d in client.devices()}
            virtual = client.is_virtual()
        except BaseException:
            client.close()
            raise
        return client, devices, virtual

    def _opened(self, opened) -> None:
        self.service, self.devices, self._virtual = opened
        self.lost = None
        self._watch.start()
        where = "built-in simulated bench" if self.bench_path is None else self.bench_path
        self.message.emit(f"connected: {where}{' (simulated)' if self.simulate else ''}, "
                          f"devices {', '.join(self.devices)}")
        self.changed.emit()

    def disconnect_bench(self, then: Callable[[], None] | None = None) -> Job | None:
        """Stop the stream and close every device and the bench process on a worker
        thread (``changed`` fires at once: the panels stop using the bench); ``then()``
        once they are closed."""
        if self.service is None:
            return None
        return self._drop_bench("disconnected", then)

    def _drop_bench(self, said: str, then: Callable[[], None] | None = None) -> Job:
        """Forget the bench (``changed`` at once) and close its client on a worker;
        ``said`` once closed."""
        self._watch.stop()
        client, self.service, self.devices = self.service, None, {}
        self.device_states = {}
        self.camera_user = None
        self._streaming = self._resume_pending = False
        self.changed.emit()

        def close(job: Job) -> None:
            client.close()

        job = Job(close, name="close-bench", nice=DEVICE_NICE)
        job.succeeded.connect(lambda _: self.message.emit(said) if said else None)
        job.failed.connect(lambda text: self.message.emit(f"disconnect: {text}"))
        if then is not None:
            job.finished.connect(then)
        self.job = job
        return job.start()

    def _check_bench(self) -> None:
        """Timer slot: when the bench process ended unasked, say how (:attr:`lost`,
        ``bench_lost`` and a message) and close what is left of its client."""
        service = self.service
        if service is None or service.alive():
            return
        from .messages import how_it_ended

        self.lost = (f"The bench process stopped: {how_it_ended(service.exit_status())}. "
                     "Its devices cannot be reached and the live stream ended. Press "
                     "Restart bench to start it again and reopen the devices.")
        log.warning("%s", self.lost)
        self.message.emit(self.lost)
        self._drop_bench("")
        self.bench_lost.emit(self.lost)

    def _note_event(self, event) -> None:
        if event.kind == "status":
            self.device_states[event.device] = event.data
        elif event.kind == "stream":
            state = event.data.get("state")
            if state == "ended":
                self.stream_end_reason = event.data.get("reason") or "the stream ended"
            self.stream_taken_by = event.data.get("to") if state == "yielded" else None
            self.changed.emit()

    def run_on_bench(self, target: str, kwargs: dict | None = None, **channels) -> Any:
        """Run job ``target`` (by name: :data:`instrument.bench.bench_jobs.JOBS`,
        :data:`calibration_routines.bench_jobs.JOBS`) in the bench process and
        wait for it (:meth:`instrument.bench.bench_process.BenchClient.run_job`; ``report``,
        ``control``, ``stop``, ``cancel``). Call it on a worker.

        Raises
        ------
        CameraBusy
            No bench is connected.
        """
        service = self.service
        if service is None:
            raise CameraBusy("no bench is connected; press Connect first")
        return service.run_job(target, kwargs, **channels)

    # -- the virtual bench's scene ---------------------------------------------------------
    def set_scene(self, name: str, on_error: Callable[[str], None] | None = None) -> Job:
        """Put a moving scene (:data:`SCENES`) in front of the virtual bench's camera
        (rendered ahead in the bench process)."""
        if name not in SCENES:
            raise ValueError(f"scene {name!r} is unknown; use one of {', '.join(SCENES)}")
        self.scene_name = name
        job = Job(lambda job: self.run_on_bench("set_scene", {"name": name}),
                  name="scene")
        job.failed.connect(lambda text: self.message.emit(f"scene: {text}"))
        if on_error is not None:
            job.failed.connect(on_error)
        self.job = job
        return job.start()

    # -- camera ownership -----------------------------------------------------------------
    def claim_camera(self, user: str) -> None:
        """Take the camera for ``user`` (stops the live stream).

        Raises
        ------
        CameraBusy
            Another job holds it.
        """
        if self.service is None:
            raise CameraBusy("no bench is connected; press Connect first")
        if self.camera_user not in (None, user):
            raise CameraBusy(f"the camera is busy with {self.camera_user}; wait for it to "
                             "end or stop it first")
        self.stop_stream()
        self.camera_user = user
        self.changed.emit()

    def release_camera(self, user: str, *, resume_stream: bool = False) -> None:
        """Give the camera back (no-op if ``user`` does not hold it); ``resume_stream``:
        start the live stream again (on the GUI thread, whichever thread calls)."""
        if self.camera_user == user:
            self.camera_user = None
            self.changed.emit()
            if resume_stream:
                self._resume_pending = True
                self._resume.emit()

    @contextmanager
    def camera_claimed(self, user: str) -> Iterator[None]:
        """:meth:`claim_camera` for the block, then :meth:`release_camera`, the live
        stream started again if it ran or was being started again after the job before
        (not when the window is closing). Call it on a worker (stopping the stream waits
        for the camera)."""
        was_streaming = self.streaming or self._resume_pending
        self.claim_camera(user)
        try:
            yield
        finally:
            self.release_camera(user, resume_stream=was_streaming and not self.closing)

    def _resume_stream(self) -> None:
        if self.camera_user is not None:
            return  # a job took the camera first: its end asks for the stream again
        if self.service is None or self.streaming:
            self._resume_pending = False
            return
        self.stream_job(True, on_error=self._resume_failed, yield_to_job=True)

    def _resume_failed(self, text: str) -> None:
        self._resume_pending = False
        self.message.emit(f"the live stream could not start again: {text}")

    def stream_job(self, on: bool, then: Callable[[], Any] | None = None,
                   on_error: Callable[[str], None] | None = None,
                   done: Callable[[Any], None] | None = None,
                   yield_to_job: bool = False) -> Job:
        """Start (``on``) or stop the stream on a worker, then ``then()`` there too
        (stopping waits for the camera's grab thread in the bench process: never on
        the GUI thread); ``done(then's result)`` and ``on_error(text)`` on the GUI
        thread. ``yield_to_job``: a start refused because a job took the camera
        meanwhile is a log line, not an error (the stream coming back after a job: that
        job's end starts it). Returns the started job."""

        def work(job: Job):
            if on:
                try:
                    self.start_stream()
                except CameraBusy as exc:
                    if not yield_to_job or self.camera_user is None:
                        raise
                    log.info("live stream: %s", exc)
            else:
                self.stop_stream()
            return None if then is None else then()

        job = Job(work, name="stream-on" if on else "stream-off",
                  nice=DEVICE_NICE)
        if on_error is not None:
            job.failed.connect(on_error)
        if done is not None:
            job.succeeded.connect(done)
        return job.start()

    # -- the stream ------------------------------------------------------------------------
    @property
    def streaming(self) -> bool:
        return self._streaming

    def start_stream(self, ring_frames: int = 64) -> None:
        """Start the camera's free-run stream in the bench process.

        Raises
        ------
        CameraBusy
            No bench, or a job holds the camera.
        drivers.errors.DeviceError
            The camera refused to stream.
        """
        with self._stream_lock:
            service = self.service
            if service is None:
                raise CameraBusy("no bench is connected; press Connect first")
            if self.camera_user is not None:
                raise CameraBusy(f"the camera is busy with {self.camera_user}; the live "
                                 "view starts again when it ends")
            if self._streaming:
                return
            self.frames_seen = 0
            self.stream_end_reason = self.stream_taken_by = None
            self._counters = {}
            self._rate.clear()
            service.start_stream(ring_frames)
            self._streaming = True
            self._resume_pending = False
            self.changed.emit()

    def stop_stream(self, timeout_s: float = 2.0) -> None:
        """Stop the stream (idempotent); the counters shown stay. Waits for the
        camera's grab thread: call it on a worker (:meth:`stream_job`)."""
        with self._stream_lock:
            service = self.service
            if not self._streaming:
                return
            self.stream_end_reason = self.stream_taken_by = None
            try:
                if service is not None:
                    service.stop_stream(timeout_s)
            finally:
                self._streaming = False
                self.changed.emit()

    def _on_stream_ended(self) -> None:
        self._streaming = False
        self._stream_ended.emit()

    def add_consumer(self, name: str, offer: Callable[[Any], None]) -> None:
        """Hand every frame read to ``offer(frame)`` (must return at once)."""
        with self._lock:
            self._consumers[name] = offer

    def remove_consumer(self, name: str) -> None:
        with self._lock:
            self._consumers.pop(name, None)

    def show_frame(self, frame) -> None:
        """Make ``frame`` the newest for the displays (a snapshot the camera took)."""
        self._latest = frame
        self.frames_seen += 1

    def latest_frame(self):
        """The newest :class:`drivers.camera.Frame` read (None before the first)."""
        return self._latest

    def frame_bit_depth(self) -> int:
        """The camera's bit depth when the newest frame was published (16 before)."""
        return int(self._counters.get("bit_depth", 16) or 16)

    def stream_counters(self) -> dict[str, float]:
        """The camera ring's counters (acquired, read, skipped, dropped) as the bench
        process published them with the newest frame, ``missed``: frames published
        that this window's reader did not take (it takes the newest), and ``fps``: the
        rate of the frames published over the last :data:`RATE_WINDOW_S` seconds (not
        since the stream started: a change of exposure shows within seconds). Never
        waits: the GUI thread reads what the reader thread stored. Empty when no frame
        was published and the stream is stopped; zeros while the first is awaited."""
        c = self._counters
        if not c and not self.streaming:
            return {}
        out: dict[str, float] = {k: int(c.get(k, 0)) for k in
                                 ("acquired", "read", "skipped", "dropped")}
        out["missed"] = int(c.get("missed_total", 0))
        out["fps"] = self.frame_rate() if self.streaming else 0.0
        return out

    def frame_rate(self) -> float:
        """Frames published per second over the last :data:`RATE_WINDOW_S` seconds."""
        now = time.monotonic()
        rate = self._rate
        rate.append((now, self.frames_seen))
        while len(rate) > 2 and now - rate[1][0] >= RATE_WINDOW_S:
            rate.popleft()
        (t0, n0), (t1, n1) = rate[0], rate[-1]
        if t1 - t0 < 0.2:
            return 0.0
        return (n1 - n0) / (t1 - t0)

    def _on_frame(self, frame, meta: dict) -> None:
        """The reader thread's hand-off: the newest frame, its counters, the consumers."""
        missed = max(int(meta.get("missed", 0)), 0)
        meta["missed_total"] = self._counters.get("missed_total", 0) + missed
        self._counters = meta
        self._latest = frame
        self.frames_seen += 1 + missed
        with self._lock:
            consumers = list(self._consumers.values())
        for offer in consumers:
            offer(frame)

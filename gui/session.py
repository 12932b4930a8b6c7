"""The GUI's bench session: the open bench, the camera stream and who uses the camera.

One :class:`Session` per window. It opens the bench of a bench file (or, with
``simulate``, the virtual bench streaming in real time, as ``capture live
--simulate`` does) on a worker thread, and owns the camera's stream: a grab thread
fills a :class:`drivers.camera.FrameRing`, and one fan-out thread reads every frame
in order, keeps the newest for the displays and hands each frame to the consumers
(the live reconstruction's :meth:`~instrument.live.LiveReconstruction.offer`, the
recorder's :meth:`~instrument.recorder.Recorder.offer`), which never block.

A camera cannot stream and snap at once, so jobs that take frames themselves (a
calibration run, the mask alignment, a video recording that streams on its own)
claim the camera first (:meth:`Session.claim_camera`): the stream stops, and
another claimant is refused with a message naming the job that holds it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QObject, Signal

from .workers import DEVICE_NICE, CameraBusy, Job

__all__ = ["CameraBusy", "RATE_WINDOW_S", "SCENES", "Session"]

log = logging.getLogger(__name__)

#: The camera's frame rate shown is measured over this many seconds.
RATE_WINDOW_S = 2.0

#: Moving scenes the virtual bench can put in front of the camera (``--simulate``).
SCENES = ("beads-flow", "neurons", "none")


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
    """

    changed = Signal()
    message = Signal(str)
    prompt = Signal(str, str, object)
    _resume = Signal()

    def __init__(self, bench_path: str | None = None, *, simulate: bool = False,
                 seed: int = 0, scene: str = "beads-flow") -> None:
        super().__init__()
        self.bench_path = bench_path
        self.simulate = bool(simulate)
        self.seed = int(seed)
        self.bench = None
        if scene not in SCENES:
            raise ValueError(f"scene {scene!r} is unknown; use one of {', '.join(SCENES)}")
        self.scene_name = scene
        self.camera_user: str | None = None
        #: True while the window closes (jobs then leave the bench as it is).
        self.closing = False
        self.ring = None
        self._consumers: dict[str, Callable[[Any], None]] = {}
        self._latest = None
        self._fanout: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._stream_lock = threading.RLock()  # one start or stop at a time
        self.frames_seen = 0
        self._stream_t0 = 0.0
        self._rate: deque[tuple[float, int]] = deque()
        self.job: Job | None = None
        self._resume.connect(self._resume_stream)

    # -- connection -----------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self.bench is not None

    @property
    def is_virtual(self) -> bool:
        """The bench is the virtual bench (``simulate``)."""
        return self.bench is not None and hasattr(self.bench, "set_scene")

    def config(self):
        """The bench configuration (:func:`instrument.cli.common.bench_config`)."""
        from instrument.cli.common import bench_config

        return bench_config(self.bench_path, simulate=self.simulate, command="gui")

    def connect_bench(self, on_error: Callable[[str], None] | None = None,
                      on_open: Callable[[], None] | None = None) -> Job:
        """Open the bench on a worker thread; ``changed`` fires when it is open, then
        ``on_open()``; ``on_error(message)`` is called if it cannot be opened."""
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
        from instrument.bench import Bench
        from instrument.virtual_bench import VirtualBench

        config = self.config()
        if not self.simulate:
            return Bench.open(config, on_prompt=self._ask, cancel=job.cancel_event)
        vb = VirtualBench(config, seed=self.seed, realtime=True).open()
        vb.led_array.all_off()
        self._set_scene(vb, self.scene_name)
        return vb

    def _opened(self, bench) -> None:
        self.bench = bench
        where = "built-in simulated bench" if self.bench_path is None else self.bench_path
        self.message.emit(f"connected: {where}{' (simulated)' if self.simulate else ''}, "
                          f"devices {', '.join(bench.devices)}")
        self.changed.emit()

    def disconnect_bench(self, then: Callable[[], None] | None = None) -> Job | None:
        """Stop the stream and close every device on a worker thread (``changed`` fires
        at once: the panels stop using the bench); ``then()`` once they are closed."""
        if self.bench is None:
            return None
        bench, self.bench = self.bench, None
        self.camera_user = None
        self.changed.emit()

        def close(job: Job) -> None:
            self.stop_stream(bench=bench)
            bench.close()

        job = Job(close, name="close-bench", nice=DEVICE_NICE)
        job.succeeded.connect(lambda _: self.message.emit("disconnected"))
        job.failed.connect(lambda text: self.message.emit(f"disconnect: {text}"))
        if then is not None:
            job.finished.connect(then)
        self.job = job
        return job.start()

    def _ask(self, action: str, message: str) -> bool:
        """A plan's operator prompt on a real bench: asked in the GUI, answered there."""
        answer: dict[str, bool] = {}
        done = threading.Event()

        def reply(ok: bool) -> None:
            answer["ok"] = bool(ok)
            done.set()

        self.prompt.emit(action, message, reply)
        done.wait()
        return answer["ok"]

    # -- the virtual bench's scene ---------------------------------------------------------
    @staticmethod
    def _set_scene(vb, name: str) -> None:
        from instrument.bench_scenes import show_video_scene

        if name == "none":
            vb.set_scene(None)
            return
        show_video_scene(vb, name, seed=vb.seed)  # as `capture --simulate --scene`

    def set_scene(self, name: str, on_error: Callable[[str], None] | None = None) -> Job:
        """Put a moving scene (:data:`SCENES`) in front of the virtual bench's camera
        (rendered ahead on a worker thread)."""
        if name not in SCENES:
            raise ValueError(f"scene {name!r} is unknown; use one of {', '.join(SCENES)}")
        self.scene_name = name
        job = Job(lambda job: self._set_scene(self.bench, name), name="scene")
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
        if self.bench is None:
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
                self._resume.emit()

    def _resume_stream(self) -> None:
        if self.bench is None or self.camera_user is not None or self.streaming:
            return
        self.stream_job(True, on_error=lambda text: self.message.emit(
            f"the live stream could not start again: {text}"))

    def stream_job(self, on: bool, then: Callable[[], Any] | None = None,
                   on_error: Callable[[str], None] | None = None,
                   done: Callable[[Any], None] | None = None) -> Job:
        """Start (``on``) or stop the stream on a worker, then ``then()`` there too
        (stopping joins the camera's grab thread, which may be rendering or reading a
        frame: never on the GUI thread); ``done(then's result)`` and ``on_error(text)``
        on the GUI thread. Returns the started job."""

        def work(job: Job):
            if on:
                self.start_stream()
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
        return self._fanout is not None and self._fanout.is_alive()

    def start_stream(self, ring_frames: int = 64) -> None:
        """Start the camera's free-run stream and the fan-out thread.

        Raises
        ------
        CameraBusy
            No bench, or a job holds the camera.
        drivers.errors.DeviceError
            The camera refused to stream.
        """
        from drivers.camera import FrameRing

        with self._stream_lock:
            if self.bench is None:
                raise CameraBusy("no bench is connected; press Connect first")
            if self.camera_user is not None:
                raise CameraBusy(f"the camera is busy with {self.camera_user}; the live "
                                 "view starts again when it ends")
            if self.streaming:
                return
            self._start(self.bench.camera, FrameRing(ring_frames))

    def _start(self, cam, ring) -> None:
        self.ring = ring
        cam.start_stream(self.ring)
        self._stop.clear()
        self.frames_seen = 0
        self._stream_t0 = time.monotonic()
        self._rate.clear()
        self._fanout = threading.Thread(target=self._fan_out, args=(self.ring,),
                                        name="gui-stream", daemon=True)
        self._fanout.start()
        self.changed.emit()

    def stop_stream(self, timeout_s: float = 2.0, *, bench=None) -> None:
        """Stop the stream (idempotent); the ring keeps its counters. Waits for the
        camera's grab thread: call it on a worker (:meth:`stream_job`)."""
        with self._stream_lock:
            if self._fanout is None:
                return
            bench = bench if bench is not None else self.bench
            self._stop.set()
            try:
                if bench is not None:
                    bench.camera.stop_stream()
            finally:
                self._fanout.join(timeout_s)
                self._fanout = None
                self.changed.emit()

    def add_consumer(self, name: str, offer: Callable[[Any], None]) -> None:
        """Hand every streamed frame to ``offer(frame)`` (must return at once)."""
        with self._lock:
            self._consumers[name] = offer

    def remove_consumer(self, name: str) -> None:
        with self._lock:
            self._consumers.pop(name, None)

    def show_frame(self, frame) -> None:
        """Make ``frame`` the newest for the displays (a job streaming the camera itself,
        e.g. a recording, shows its frames so)."""
        self._latest = frame
        self.frames_seen += 1

    def latest_frame(self):
        """The newest streamed :class:`drivers.camera.Frame` (None before the first)."""
        return self._latest

    def stream_counters(self) -> dict[str, float]:
        """The ring's counters (acquired, read, skipped, dropped) and ``fps``: the rate
        of the frames delivered over the last :data:`RATE_WINDOW_S` seconds (not since
        the stream started: a change of exposure shows within seconds).

        Read without the ring's lock (each counter is one int, read whole): the GUI
        thread never waits for the grab thread, which on a loaded machine held it while
        descheduled (the operator's day's watchdog found the event loop there); the
        numbers shown may be one frame apart."""
        ring = self.ring
        if ring is None:
            return {}
        out: dict[str, float] = {"acquired": ring.acquired, "read": ring.read,
                                 "skipped": ring.skipped, "dropped": ring.dropped}
        out["fps"] = self.frame_rate() if self.streaming else 0.0
        return out

    def frame_rate(self) -> float:
        """Frames delivered per second over the last :data:`RATE_WINDOW_S` seconds."""
        now = time.monotonic()
        rate = self._rate
        rate.append((now, self.frames_seen))
        while len(rate) > 2 and now - rate[1][0] >= RATE_WINDOW_S:
            rate.popleft()
        (t0, n0), (t1, n1) = rate[0], rate[-1]
        if t1 - t0 < 0.2:
            return 0.0
        return (n1 - n0) / (t1 - t0)

    def _fan_out(self, ring) -> None:
        from drivers.errors import CameraTimeoutError

        while not self._stop.is_set():
            try:
                frame = ring.get(timeout_s=0.05)
            except CameraTimeoutError:
                continue
            except Exception as exc:  # noqa: BLE001 (a producer error, reported once)
                self.message.emit(f"camera stream stopped: {exc}")
                return
            self._latest = frame
            self.frames_seen += 1
            with self._lock:
                consumers = list(self._consumers.values())
            for offer in consumers:
                offer(frame)

"""Live reconstruction in a process of its own, frames and results through shared memory.

:class:`instrument.acquisition.live.LiveReconstruction` runs its solver on a thread of the caller's
process. In the GUI that thread shares the interpreter lock with the GUI thread: the
lock passes between them every few milliseconds, and a solver thread at a lower OS
priority that is descheduled while it holds the lock stalls the window until the
scheduler runs it again (on a loaded 2-core machine, up to 1.7 s in an operator's
soak). :class:`LiveReconstructionProcess` has the same interface (``start``, ``offer``,
``latest``, ``stats``, ``set_method``, ``stop``) and runs the same
:class:`~instrument.acquisition.live.LiveReconstruction` in a child process (``spawn``; it shares
no lock with the caller):

* :meth:`~LiveReconstructionProcess.offer` copies each frame into a shared
  :class:`~instrument.acquisition.shared_slot.SharedImageSlot` and wakes the child (a semaphore);
  the child takes the newest frame. Neither waits for the other.
* The child publishes each result in a second slot, which
  :meth:`~LiveReconstructionProcess.latest` reads without waiting; each result's
  timings and the child's counters come back on a pipe, read by a thread of the
  caller that keeps the statistics :meth:`~LiveReconstructionProcess.stats` returns.
* The method and iterations travel with each frame (so a switch applies to every frame
  offered after it, never to one before); stop goes down the pipe. The child runs
  ``nice`` levels below the caller's process; a child that dies is reported in
  ``stats()["last_error"]`` and ``running`` turns False (the stream goes on).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
from collections import deque
from typing import Any

import numpy as np

from diffuserlab.errors import kept_error
from diffuserlab.processes import has_ended, how_it_ended, portable_error
from drivers.camera import Frame, FrameRing
from recon.fft import check_threads
from recon.options import LiveOptions, ReconOptions
from recon.validate import as_int, positive

from .live import (
    LIVE_METHODS,
    LivePreview,
    LiveReconstruction,
    LiveReconstructionError,
    _checked,
    _method,
    drain_ring,
    note_result,
    whole_run_summary,
    window_rates,
)
from .shared_slot import SharedImageSlot

__all__ = ["LiveReconstructionProcess"]

log = logging.getLogger(__name__)

#: How long the reader waits for an ended child to be reaped so its exit status is
#: known (its pipe closes a moment before), s.
REAP_S = 2.0


def _child(conn, wake, psf, options: ReconOptions, settings: dict,
           slots: tuple[str, str, int, int], nice: int) -> None:
    """The child: build the reconstructor, feed it from the input slot, publish results."""
    from recon.live import LiveReconstructor

    try:  # from the starting thread's value; lowering it needs privileges
        os.nice(nice - os.nice(0))
    except OSError:
        pass
    frames = results = None
    try:
        try:
            frames = SharedImageSlot(slots[2], name=slots[0])
            results = SharedImageSlot(slots[3], name=slots[1])
            recon = LiveReconstructor(psf, options)
            live = LiveReconstruction(recon, settings["live"],
                                      warm_start=settings["warm_start"],
                                      threads=settings["threads"])
        except BaseException as exc:  # every failure goes back to the caller
            conn.send(("failed", portable_error(exc, "the live reconstruction process")))
            return
        send_lock = threading.Lock()

        def send(message) -> None:
            with send_lock:
                try:
                    conn.send(message)
                except (OSError, ValueError):  # the caller is gone: the main loop ends
                    pass

        def published(preview: LivePreview) -> None:
            meta = (preview.frame_index, preview.host_timestamp_s, preview.result_time_s,
                    preview.latency_s, preview.compute_s, LIVE_METHODS.index(preview.method),
                    preview.iterations, float(preview.warm))
            results.write(np.asarray(preview.image, np.float32), meta)
            send(("result", meta, live.slot.taken))

        def failed(message: str) -> None:
            send(("error", message))

        live.on_result, live.on_error = published, failed
        stop = threading.Event()

        def feed() -> None:
            seen, applied = 0, (settings["live"].method, settings["live"].iterations)
            while not stop.is_set():
                if not wake.acquire(timeout=0.1):
                    continue
                got = frames.read(after=seen)
                if got is None:
                    continue
                seen = got.sequence
                m = got.meta
                wanted = (LIVE_METHODS[int(m[6])], int(m[7]))
                if wanted != applied:  # the settings the frame was offered under
                    try:
                        live.set_method(*wanted)
                        applied = wanted
                    except Exception as exc:  # noqa: BLE001 (reported, the child goes on)
                        failed(f"set_method: {exc}")
                live.offer(Frame(got.image, int(m[0]), float(m[1]), float(m[2]), float(m[3]),
                                 float(m[4]), int(m[5])))

        live.start()
        feeder = threading.Thread(target=feed, name="live-child-feed", daemon=True)
        feeder.start()
        send(("ready", {"backend": recon.backend.label,
                        "sensor_shape": list(recon.sensor_shape), "pid": os.getpid(),
                        "nice": os.nice(0)}))
        while True:
            try:
                message = conn.recv()
            except (EOFError, OSError):  # the caller is gone
                break
            if message[0] == "stop":
                break
        stop.set()
        feeder.join(1.0)
        live.stop(timeout_s=30.0)
        send(("stopped", live.slot.taken))
    finally:
        for slot in (frames, results):
            if slot is not None:
                slot.close()


class LiveReconstructionProcess:
    """A live reconstruction (:class:`instrument.acquisition.live.LiveReconstruction`) run in a
    child
    process (see the module docstring).

    Parameters
    ----------
    psf : ndarray, (rows, cols)
        The PSF, the shape of the camera's frames (as :class:`recon.live.LiveReconstructor`).
    live : recon.options.LiveOptions, optional
        The method and iterations per frame, as
        :class:`~instrument.acquisition.live.LiveReconstruction`'s (default: the declared ones).
    options : recon.options.ReconOptions, optional
        The reconstructor's options (its dark level, binning and device, as
        :class:`recon.live.LiveReconstructor`'s; default: the declared ones); the
        reconstructor is built in the child, so a GPU's arrays live there.
    warm_start, window_s, threads
        As :class:`~instrument.acquisition.live.LiveReconstruction`'s (``threads``: the child's
        FFT and kernel threads).
    nice : int
        The child runs this many nice levels below the caller's process (at most 19).

    Raises
    ------
    ReconInputError
        Unknown method, iterations < 1, a window that is not > 0, or ``threads``
        outside 1..os.cpu_count() (the reconstructor's own errors are raised by
        :meth:`start`).
    """

    def __init__(self, psf: np.ndarray, live: LiveOptions | None = None, *,
                 options: ReconOptions | None = None, warm_start: bool = True,
                 window_s: float = 2.0, threads: int | None = 1, nice: int = 0):
        self.psf = np.asarray(psf)
        self.options = ReconOptions.from_defaults() if options is None else options
        self._method, self._iterations = _method(live)
        self.warm_start = bool(warm_start)
        self.window_s = positive(window_s, "window_s")
        self.threads = None if threads is None else check_threads(threads)
        self.nice = as_int(nice, "nice", 0)
        self.backend_label: str | None = None
        self.sensor_shape: tuple[int, int] | None = None
        self.child_info: dict = {}
        self._lock = threading.Lock()
        self._child = None
        self._conn = None
        self._reader: threading.Thread | None = None
        self._feeder: threading.Thread | None = None
        self._stopping = threading.Event()
        self._frames: SharedImageSlot | None = None
        self._results: SharedImageSlot | None = None
        self._wake = None
        self._latest: LivePreview | None = None
        self._latest_sequence = 0
        self._reset_counters()

    def _reset_counters(self) -> None:
        self.received = self.taken = self.reconstructed = self.errors = 0
        self.last_error: str | None = None
        self.error: BaseException | None = None
        self._recent: deque[tuple[float, float]] = deque()
        self._latencies: deque[float] = deque(maxlen=100_000)
        self._compute: deque[float] = deque(maxlen=100_000)

    # -- control -------------------------------------------------------------------
    def start(self, ring: FrameRing | None = None, timeout_s: float = 120.0) -> None:
        """Start the child and wait until its reconstructor is built.

        Parameters
        ----------
        ring : FrameRing, optional
            Read every frame of this ring and :meth:`offer` it (a feeder thread here).
        timeout_s : float
            How long the child may take to start, import and build, s.

        Raises
        ------
        LiveReconstructionError
            Already running, or the child did not report within ``timeout_s`` or ended.
        Exception
            What building the reconstructor raised in the child (an unreadable PSF, an
            unusable device), of the same type.
        """
        if self.running:
            raise LiveReconstructionError("live reconstruction is already running; call "
                                          "stop() first")
        self._reset_counters()
        self._latest = None
        self._stopping.clear()
        raw_bytes = int(np.prod(self.psf.shape)) * 8
        self._frames = SharedImageSlot(raw_bytes)
        self._results = SharedImageSlot(int(np.prod(self.psf.shape)) * 4)
        context = multiprocessing.get_context("spawn")
        self._wake = context.Semaphore(0)
        self._conn, child_conn = context.Pipe()
        nice = min(19, os.getpriority(os.PRIO_PROCESS, os.getpid()) + self.nice)
        settings = {"live": LiveOptions.from_defaults(method=self._method,
                                                      iterations=self._iterations),
                    "warm_start": self.warm_start, "threads": self.threads}
        child = context.Process(
            target=_child, name="diffuserlab-live",
            args=(child_conn, self._wake, self.psf, self.options, settings,
                  (self._frames.name, self._results.name, self._frames.capacity,
                   self._results.capacity), nice), daemon=True)
        child.start()
        self._child = child  # started: other threads read its state (running)
        child_conn.close()
        try:
            if not self._conn.poll(timeout_s):
                raise LiveReconstructionError(
                    f"the live reconstruction process did not start within {timeout_s:g} s; "
                    "the machine is overloaded")
            kind, value = self._conn.recv()
        except (EOFError, OSError):
            kind, value = "failed", LiveReconstructionError(
                f"the live reconstruction process ended while starting: {self._how_ended()}")
        except BaseException:
            self._end_child(1.0)
            raise
        if kind != "ready":
            self._end_child(5.0)
            raise value
        self.child_info = value
        self.backend_label = value["backend"]
        self.sensor_shape = tuple(value["sensor_shape"])
        self._reader = threading.Thread(target=self._read, name="live-proc-reader",
                                        daemon=True)
        self._reader.start()
        if ring is not None:
            self._feeder = threading.Thread(target=self._feed, args=(ring,),
                                            name="live-proc-feed", daemon=True)
            self._feeder.start()

    def stop(self, timeout_s: float = 30.0) -> None:
        """Stop the child (it finishes its frame) and wait for it; a child still running
        after ``timeout_s`` s is terminated.

        Raises
        ------
        LiveReconstructionError
            The child had to be terminated.
        """
        if self._child is None:
            return
        self._stopping.set()
        try:
            with self._lock:
                self._conn.send(("stop",))
        except (OSError, ValueError):
            pass  # the child is gone already
        terminated = self._end_child(timeout_s)
        if terminated:
            raise LiveReconstructionError(
                f"the live reconstruction process did not stop within {timeout_s:g} s and "
                "was terminated")

    def _end_child(self, timeout_s: float) -> bool:
        child, self._child = self._child, None
        terminated = not has_ended(child, timeout_s)
        if terminated:
            child.terminate()
            has_ended(child, 5.0)
        for t in (self._reader, self._feeder):
            if t is not None:
                t.join(2.0)
        self._reader = self._feeder = None
        self._conn.close()
        for slot in (self._frames, self._results):
            if slot is not None:
                slot.close()
        self._frames = self._results = None
        return terminated

    def __enter__(self) -> LiveReconstructionProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        """Whether the child is alive (and was started)."""
        child = self._child
        return child is not None and not has_ended(child) and not self._stopping.is_set()

    def _how_ended(self) -> str:
        """How the child ended, in words, once it is reaped (its pipe closes a moment
        before: waited for up to :data:`REAP_S`)."""
        child = self._child
        if child is not None:
            has_ended(child, REAP_S)
        return how_it_ended(None if child is None else child.exitcode)

    def exit_status(self) -> int | None:
        """How the child ended: its exit code, or minus the signal that ended it
        (``-9``: SIGKILL), the child reaped; None while it runs, before it started
        and after :meth:`stop`."""
        child = self._child
        if child is None or not has_ended(child):
            return None
        return child.exitcode

    def set_method(self, method: str, iterations: int | None = None) -> None:
        """Switch between the Wiener preview and ADMM: every frame offered after this call
        is solved with the new settings (they travel with the frame, so a frame never
        overtakes the switch).

        Raises
        ------
        ReconInputError
            Unknown method or iterations < 1.
        """
        self._method, self._iterations = _checked(
            method, self._iterations if iterations is None else iterations)

    # -- producer side -------------------------------------------------------------
    def offer(self, frame: Frame) -> None:
        """Copy a frame to the child's slot and wake it; returns at once."""
        slot = self._frames
        if slot is None:
            return
        self.received += 1
        try:
            slot.write(frame.image, (frame.index, frame.device_timestamp_s,
                                     frame.host_timestamp_s, frame.exposure_s, frame.gain,
                                     frame.saturated_pixels,
                                     LIVE_METHODS.index(self._method), self._iterations))
        except ValueError as exc:
            self._record_error(f"frame {frame.index}: {exc}")
            return
        self._wake.release()

    def _feed(self, ring: FrameRing) -> None:
        error = drain_ring(ring, self._stopping, self.offer)
        if error is not None:
            self.error = kept_error(error)
            self._record_error(f"feeding from the camera ring: {type(error).__name__}: "
                               f"{error}")

    def _read(self) -> None:
        conn = self._conn
        while True:
            try:
                kind, *value = conn.recv()
            except (EOFError, OSError):
                if not self._stopping.is_set():
                    self._record_error(f"the live reconstruction process ended: "
                                       f"{self._how_ended()}; start the reconstruction "
                                       "again")
                return
            if kind == "result":
                meta, taken = value
                done, latency = meta[2], meta[3]
                with self._lock:
                    self.reconstructed += 1
                    self.taken = taken
                    note_result(self, done, latency, meta[4])
            elif kind == "error":
                self._record_error(value[0])
            elif kind == "stopped":
                with self._lock:
                    self.taken = value[0]
                return

    def _record_error(self, message: str) -> None:
        with self._lock:
            self.errors += 1
            self.last_error = message
        log.warning("live reconstruction: %s", message)

    # -- results -------------------------------------------------------------------
    def latest(self) -> LivePreview | None:
        """The newest result the child published (None before the first); never waits
        for the child."""
        slot = self._results
        previous = self._latest
        if slot is not None:
            got = slot.read(after=0 if previous is None else self._latest_sequence)
            if got is not None:
                m = got.meta
                previous = LivePreview(got.image, int(m[0]), float(m[1]), float(m[2]),
                                       float(m[3]), float(m[4]), LIVE_METHODS[int(m[5])],
                                       int(m[6]), bool(m[7]))
                self._latest, self._latest_sequence = previous, got.sequence
        return previous

    def stats(self) -> dict[str, Any]:
        """Counters and rates, as :meth:`instrument.acquisition.live.LiveReconstruction.stats`
        (``skipped``: frames the child never took, the newest waiting one excepted)."""
        with self._lock:
            recent = list(self._recent)
            waiting = int(self._frames is not None and self._frames.sequence > self.taken)
            out = {"received": self.received, "reconstructed": self.reconstructed,
                   "skipped": max(self.received - self.taken - waiting, 0),
                   "errors": self.errors, "last_error": self.last_error,
                   "method": self._method, "iterations": self._iterations,
                   "latency_s": recent[-1][1] if recent else None}
        out.update(window_rates(recent), running=self.running)
        return out

    def latency_summary(self) -> dict:
        """Latency over the whole run, as
        :meth:`instrument.acquisition.live.LiveReconstruction.latency_summary`."""
        with self._lock:
            lat, comp = np.array(self._latencies), np.array(self._compute)
        return whole_run_summary(lat, comp)

"""Live reconstruction worker: the newest camera frame, reconstructed on its own thread.

Data flow (docs/architecture.md, acquisition): the camera's grab thread fills a
:class:`~drivers.camera.FrameRing`; a consumer of that stream (the recorder's fan-out,
or :meth:`LiveReconstruction.start` with ``ring=`` when nothing else reads it) hands
every frame to :meth:`LiveReconstruction.offer`, which puts it in a single-slot
mailbox (:class:`LatestFrameSlot`) and returns at once: it never waits for the
reconstruction, so the live path cannot slow the producer or the recorder. The worker
thread takes the newest frame, reconstructs it (:class:`recon.live.LiveReconstructor`:
Wiener preview by default, or K ADMM iterations warm-started from the previous frame)
and publishes the result (:meth:`LiveReconstruction.latest`) with its statistics
(:meth:`LiveReconstruction.stats`). Frames overwritten in the slot before the worker
took them are counted as skipped, never silently.

``diffuserlab benchmark live`` (``instrument.benchmarks.live``) measures the worker on the
real-time simulated camera.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from diffuserlab.errors import DiffuserLabError, kept_error
from drivers.camera import Frame, FrameRing
from drivers.errors import CameraTimeoutError
from recon.errors import ReconInputError
from recon.fft import check_threads, limited_threads
from recon.options import LiveOptions
from recon.validate import as_int, positive

__all__ = ["LatestFrameSlot", "LivePreview", "LiveReconstruction", "LiveReconstructionError",
           "lower_thread_priority"]

log = logging.getLogger(__name__)

#: Methods of the worker: the Wiener preview, or ADMM iterations per frame.
LIVE_METHODS = ("wiener", "admm")


class LiveReconstructionError(DiffuserLabError, RuntimeError):
    """The live worker could not start or stop in time."""


#: Default wait, s, of :meth:`LiveReconstruction.stop` for its threads: a guard against a
#: hang, not a deadline. A stop waits for the frame being reconstructed, and on a busy
#: machine one frame took more than the 5 s the callers gave (the live benchmark failed
#: so at load 11-12, and a recording then stopped before closing its run).
STOP_TIMEOUT_S = 60.0


def lower_thread_priority(increment: int) -> bool:
    """Run the calling thread ``increment`` nice levels below its process (lower CPU
    priority).

    On Linux a nice value belongs to a thread (``setpriority(PRIO_PROCESS, tid)``), and
    threads started from this one later (numba's and the FFT's pools, when this thread
    starts them) inherit it. Background compute (a live preview, a calibration sweep)
    then yields the cores to the threads that must keep time: the camera's grab and
    the recorder, and a GUI's event loop. An unprivileged process can only raise nice
    values, so this cannot be undone in the thread.

    The level is counted from the process's (its main thread's), not from the calling
    thread's: a thread started by an already lowered one (the live reconstruction,
    started by a GUI job at nice 10) inherits that value, and adding to it put the
    work at 19, where beside two busy loops it got about 1.5 % of a core (CFS weight
    15 against 1024). A thread already that low is left as it is.

    Parameters
    ----------
    increment : int
        Nice levels below the process's (0 does nothing; the result is capped at 19).

    Returns
    -------
    bool
        True when the priority was changed; False when the thread already ran that
        low, where per-thread priorities are not available (not Linux) or the call was
        refused.
    """
    if increment <= 0 or not sys.platform.startswith("linux"):
        return False
    tid = threading.get_native_id()
    try:
        target = min(os.getpriority(os.PRIO_PROCESS, os.getpid()) + int(increment), 19)
        if os.getpriority(os.PRIO_PROCESS, tid) >= target:
            return False
        os.setpriority(os.PRIO_PROCESS, tid, target)
    except OSError:
        return False
    return True


class LatestFrameSlot:
    """Single-slot mailbox keeping only the newest frame (thread-safe).

    :meth:`offer` never blocks beyond a short lock; a frame still in the slot when the
    next arrives is overwritten and counted in ``skipped``.

    Attributes
    ----------
    received : int
        Frames offered.
    taken : int
        Frames returned by :meth:`take`.
    skipped : int
        Frames overwritten before being taken. ``received == taken + skipped`` plus one
        when a frame waits in the slot.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._closed = False
        self.received = 0
        self.taken = 0
        self.skipped = 0

    def offer(self, frame: Frame) -> None:
        """Put ``frame`` in the slot, replacing (and counting) an untaken one."""
        with self._cond:
            self.received += 1
            if self._frame is not None:
                self.skipped += 1
            self._frame = frame
            self._cond.notify()

    def take(self, timeout_s: float) -> Frame | None:
        """The newest frame, waiting up to ``timeout_s`` s; None on timeout or close."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._frame is None and not self._closed:
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)
            frame, self._frame = self._frame, None
            if frame is not None:
                self.taken += 1
            return frame

    def close(self) -> None:
        """Wake a waiting :meth:`take` (returns None from then on when empty)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def counters(self) -> dict[str, int]:
        """``received``, ``taken``, ``skipped`` and ``waiting`` (0 or 1)."""
        with self._cond:
            return {"received": self.received, "taken": self.taken, "skipped": self.skipped,
                    "waiting": int(self._frame is not None)}


@dataclass(frozen=True)
class LivePreview:
    """The latest reconstruction the worker published.

    Attributes
    ----------
    image : ndarray, float32, (rows, cols)
        Sensor field of view of the estimate (see :class:`recon.live.LiveResult`).
    frame_index : int
        The camera frame it came from.
    host_timestamp_s : float
        That frame's host timestamp (``time.time()`` at delivery), s.
    result_time_s : float
        ``time.time()`` when the result was ready, s.
    latency_s : float
        ``result_time_s - host_timestamp_s``.
    compute_s : float
        Raw conversion plus solve, s.
    method : str
    iterations : int
    warm : bool
        ADMM started from the previous frame's state.
    """

    image: np.ndarray
    frame_index: int
    host_timestamp_s: float
    result_time_s: float
    latency_s: float
    compute_s: float
    method: str
    iterations: int
    warm: bool


def _method(live: LiveOptions | None) -> tuple[str, int]:
    """The checked method and iterations per frame of ``live`` (None: the declared)."""
    live = LiveOptions.from_defaults() if live is None else live
    return _checked(live.method, live.iterations)


def _checked(method: str, iterations) -> tuple[str, int]:
    if method not in LIVE_METHODS:
        raise ReconInputError(f"live method {method!r} is unknown; use one of "
                              f"{', '.join(LIVE_METHODS)}")
    return method, as_int(iterations, "iterations", 1)


class LiveReconstruction:
    """Worker thread reconstructing the newest frame of a stream.

    Parameters
    ----------
    reconstructor : recon.live.LiveReconstructor
        Per-PSF reconstructor (anything with its ``wiener(raw)`` and
        ``admm(raw, iterations, warm_start)`` methods returning a
        :class:`recon.live.LiveResult`).
    live : recon.options.LiveOptions, optional
        The method (``"wiener"``: the preview, or ``"admm"``: ``iterations`` ADMM
        iterations per frame, >= 1); default the declared ones.
    warm_start : bool
        ADMM from the previous frame's state (default) or from zero on every frame.
    window_s : float
        Sliding window of the fps and latency statistics, s.
    threads : int, optional
        Most threads the worker's FFTs and numba kernels use
        (:func:`recon.fft.limited_threads`), so that it leaves cores to a recorder
        running beside it; None: all cores.
    nice : int
        Raise the worker thread's nice value by this much
        (:func:`lower_thread_priority`; default 0, unchanged): a preview beside a
        recorder or a GUI then takes the CPU only when they leave it.
    on_result : callable, optional
        Called on the worker thread with each published :class:`LivePreview`
        (:class:`instrument.acquisition.live_process.LiveReconstructionProcess`'s child sends it
        on).
    on_error : callable, optional
        Called on the thread that met it with each error's one-line description.

    Raises
    ------
    ReconInputError
        Unknown method, iterations < 1, a window that is not > 0, or ``threads``
        outside 1..os.cpu_count().
    """

    def __init__(self, reconstructor, live: LiveOptions | None = None, *,
                 warm_start: bool = True, window_s: float = 2.0, threads: int | None = None,
                 nice: int = 0, on_result=None, on_error=None):
        self.reconstructor = reconstructor
        self.on_result, self.on_error = on_result, on_error
        self._method, self._iterations = _method(live)
        self.warm_start = bool(warm_start)
        self.window_s = positive(window_s, "window_s")
        self.threads = None if threads is None else check_threads(threads)
        self.nice = as_int(nice, "nice", 0)
        self.slot = LatestFrameSlot()
        self._lock = threading.Lock()
        self._latest: LivePreview | None = None
        self._recent: deque[tuple[float, float]] = deque()  # (result time, latency)
        self._latencies: deque[float] = deque(maxlen=100_000)
        self._compute: deque[float] = deque(maxlen=100_000)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.reconstructed = 0
        self.errors = 0
        self.last_error: str | None = None
        self.error: BaseException | None = None
        self.ring: FrameRing | None = None

    # -- control -------------------------------------------------------------------
    def start(self, ring: FrameRing | None = None, timeout_s: float = 2.0) -> None:
        """Start the worker (and, with ``ring``, a feeder thread draining it).

        Parameters
        ----------
        ring : FrameRing, optional
            Read every frame of this ring and :meth:`offer` it (only when nothing else
            consumes the ring: a ring has one reader). Without it, the stream's
            consumer calls :meth:`offer`.
        timeout_s : float
            How long the threads may take to come up, s.

        Raises
        ------
        LiveReconstructionError
            Already running, or a thread did not start within ``timeout_s``.
        """
        if any(t.is_alive() for t in self._threads):
            raise LiveReconstructionError("live reconstruction is already running; call "
                                          "stop() first")
        self._stop.clear()
        self.slot = LatestFrameSlot()
        self.ring = ring
        targets = [("live-recon", self._work)]
        if ring is not None:
            targets.append(("live-feed", self._feed))
        started = []
        self._threads = []
        for name, target in targets:
            ready = threading.Event()
            t = threading.Thread(target=target, args=(ready,), name=name, daemon=True)
            t.start()
            self._threads.append(t)
            started.append(ready)
        deadline = time.monotonic() + timeout_s
        if not all(r.wait(max(deadline - time.monotonic(), 0.0)) for r in started):
            self.stop(timeout_s)
            raise LiveReconstructionError(f"live reconstruction threads did not start "
                                          f"within {timeout_s:g} s; the machine is overloaded")

    def stop(self, timeout_s: float = STOP_TIMEOUT_S) -> None:
        """Stop the threads and wait for them.

        A frame being reconstructed is finished first, so ``timeout_s`` must exceed
        one frame's reconstruction time.

        Raises
        ------
        LiveReconstructionError
            A thread still runs after ``timeout_s`` s (it is a daemon thread and ends
            with its current frame).
        """
        self._stop.set()
        self.slot.close()
        deadline = time.monotonic() + timeout_s
        for t in self._threads:
            t.join(max(deadline - time.monotonic(), 0.0))
        alive = [t.name for t in self._threads if t.is_alive()]
        if alive:
            raise LiveReconstructionError(
                f"live reconstruction thread(s) {', '.join(alive)} still running after "
                f"{timeout_s:g} s; give stop() a timeout longer than one frame's "
                "reconstruction")
        self._threads = []

    def __enter__(self) -> LiveReconstruction:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def backend_label(self) -> str:
        """Where the solves run (the reconstructor's ``backend.label``)."""
        return self.reconstructor.backend.label

    @property
    def running(self) -> bool:
        """Whether the worker thread is alive."""
        return bool(self._threads) and self._threads[0].is_alive()

    def set_method(self, method: str, iterations: int | None = None) -> None:
        """Switch between the Wiener preview and ADMM (applies from the next frame).

        Switching forgets the ADMM state: the scene may have changed meanwhile, so the
        first ADMM frame after a switch starts cold.

        Raises
        ------
        ReconInputError
            Unknown method or iterations < 1.
        """
        m, k = _checked(method, self._iterations if iterations is None else iterations)
        with self._lock:
            if m != self._method and hasattr(self.reconstructor, "reset"):
                self.reconstructor.reset()
            self._method, self._iterations = m, k

    # -- producer side -------------------------------------------------------------
    def offer(self, frame: Frame) -> None:
        """Hand a frame to the worker; returns at once (never waits for the solve)."""
        self.slot.offer(frame)

    def _feed(self, ready: threading.Event) -> None:
        ready.set()
        error = drain_ring(self.ring, self._stop, self.slot.offer)
        if error is not None:
            self._record_error(error, "feeding from the camera ring")

    # -- worker --------------------------------------------------------------------
    def _work(self, ready: threading.Event) -> None:
        lower_thread_priority(self.nice)
        if self.threads is None:
            self._loop(ready)
        else:
            with limited_threads(self.threads):
                self._loop(ready)

    def _loop(self, ready: threading.Event) -> None:
        ready.set()
        while not self._stop.is_set():
            frame = self.slot.take(timeout_s=0.1)
            if frame is None:
                continue
            with self._lock:
                method, iterations = self._method, self._iterations
            try:
                if method == "wiener":
                    res = self.reconstructor.wiener(frame.image)
                else:
                    res = self.reconstructor.admm(frame.image, iterations=iterations,
                                                  warm_start=self.warm_start)
            except Exception as exc:
                self._record_error(exc, f"reconstructing frame {frame.index}")
                continue
            done = time.time()
            preview = LivePreview(res.image, frame.index, frame.host_timestamp_s, done,
                                  done - frame.host_timestamp_s, res.seconds, res.method,
                                  res.iterations, res.warm)
            with self._lock:
                self._latest = preview
                self.reconstructed += 1
                note_result(self, done, preview.latency_s, preview.compute_s)
            if self.on_result is not None:
                self.on_result(preview)

    def _record_error(self, exc: BaseException, what: str) -> None:
        with self._lock:
            self.errors += 1
            self.error = kept_error(exc)  # its traceback would hold this object: a cycle
            self.last_error = f"{what}: {type(exc).__name__}: {exc}"
        log.warning("live reconstruction: %s", self.last_error)
        if self.on_error is not None:
            self.on_error(self.last_error)

    # -- results -------------------------------------------------------------------
    def latest(self) -> LivePreview | None:
        """The newest published reconstruction (None before the first)."""
        with self._lock:
            return self._latest

    def stats(self) -> dict:
        """Counters and rates, safe to call from any thread.

        Returns
        -------
        dict
            ``received``, ``reconstructed``, ``skipped`` (overwritten in the slot before
            the worker took them), ``errors``, ``last_error`` (str or None), ``method``,
            ``iterations``, ``fps`` (results per second over the last ``window_s``; 0
            with fewer than 2), ``latency_s`` (of the newest result), ``latency_median_s``
            and ``latency_p95_s`` (over the window; None without results), ``running``.
        """
        slot = self.slot.counters()
        with self._lock:
            recent = list(self._recent)
            out = {"received": slot["received"], "reconstructed": self.reconstructed,
                   "skipped": slot["skipped"], "errors": self.errors,
                   "last_error": self.last_error, "method": self._method,
                   "iterations": self._iterations,
                   "latency_s": None if self._latest is None else self._latest.latency_s}
        out.update(window_rates(recent), running=self.running)
        return out

    def latency_summary(self) -> dict:
        """Latency over the whole run: ``count``, ``median_s``, ``p95_s``, ``max_s``, and
        ``compute_median_s`` (conversion + solve alone; its inverse is the rate the worker
        could sustain); None without results."""
        with self._lock:
            lat, comp = np.array(self._latencies), np.array(self._compute)
        return whole_run_summary(lat, comp)


def drain_ring(ring: FrameRing, stop: threading.Event, offer) -> BaseException | None:
    """Hand every frame of ``ring`` to ``offer`` until ``stop`` is set (the feeder of a
    live reconstruction started with ``ring=``).

    Returns
    -------
    BaseException or None
        The producer's error the ring reported (the feeding then ends), None when
        stopped.
    """
    while not stop.is_set():
        try:
            frame = ring.get(timeout_s=0.05)
        except CameraTimeoutError:
            continue
        except Exception as exc:  # a producer error reported through the ring
            return exc
        offer(frame)
    return None


def note_result(live, done: float, latency_s: float, compute_s: float) -> None:
    """Add one result to ``live``'s statistics (its ``_recent`` window of ``window_s``,
    ``_latencies``, ``_compute``); the caller holds its lock."""
    live._recent.append((done, latency_s))
    while live._recent and live._recent[0][0] < done - live.window_s:
        live._recent.popleft()
    live._latencies.append(latency_s)
    live._compute.append(compute_s)


def window_rates(recent: list[tuple[float, float]]) -> dict:
    """``fps``, ``latency_median_s`` and ``latency_p95_s`` of the (result time, latency)
    pairs of the statistics' window (0 fps with fewer than 2; None without results)."""
    span = recent[-1][0] - recent[0][0] if len(recent) >= 2 else 0.0
    lat = [r[1] for r in recent]
    return {"fps": (len(recent) - 1) / span if span > 0 else 0.0,
            "latency_median_s": float(np.median(lat)) if lat else None,
            "latency_p95_s": float(np.percentile(lat, 95)) if lat else None}


def whole_run_summary(lat: np.ndarray, comp: np.ndarray) -> dict:
    """:meth:`LiveReconstruction.latency_summary` of the latencies and compute times."""
    if not lat.size:
        return {"count": 0, "median_s": None, "p95_s": None, "max_s": None,
                "compute_median_s": None}
    return {"count": int(lat.size), "median_s": float(np.median(lat)),
            "p95_s": float(np.percentile(lat, 95)), "max_s": float(lat.max()),
            "compute_median_s": float(np.median(comp))}

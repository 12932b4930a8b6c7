"""Video recorder: writes a camera's frames into a run store on its own thread.

The capture loop takes frames from the camera's :class:`drivers.camera.FrameRing`
in order (never the newest only) and hands each to :meth:`Recorder.offer`, which
never blocks: the frame goes into a bounded queue, or, when the queue is full
(the disk is slower than the camera), it is lost, counted and remembered by its
camera frame index (never silently). The recorder's thread takes frames from the
queue in order, gathers one shard's worth (:attr:`RunStore.shard_frames`) and
writes it with :meth:`RunStore.write_frames` (frames, per-frame coordinates,
checksums, then done flags), so the store's files hold whole shards only.

Durability: a shard's frames become done together. A recording killed at any
moment (SIGKILL, power loss) keeps every frame of every shard written before it;
it loses the frames of the shard being filled (fewer than ``shard_frames``) and
those still queued. The store opens afterwards and :meth:`RunStore.summary` says
how many frames it holds (``frames_done``); :meth:`RunStore.verify` checks them.

Each stored frame's coordinates are :data:`VIDEO_COORDS`: the camera's frame
index (gaps show frames lost before the recorder), device and host timestamps
(s), exposure (s), gain and saturated pixel count. Frames are stored in the order
recorded (slot ``i`` is the ``i``-th recorded frame), so a run created for ``N``
slots holds at most ``N`` frames. :meth:`Recorder.close` stores the totals
(:meth:`Recorder.counters`, with the ring's when given) and the camera-index gaps
in the run's ``summary`` attribute under ``"recording"``.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from diffuserlab.errors import kept_error
from drivers.camera import Frame, FrameRing

from ..runs.runstore import RunStore, RunStoreError, utc_now
from ..runs.runstore_records import index_ranges

__all__ = ["VIDEO_COORDS", "Recorder", "index_ranges", "record_from_ring", "recording_summary"]

#: Per-frame coordinates of a video run, in this order.
VIDEO_COORDS = ("frame_index", "device_timestamp_s", "host_timestamp_s", "exposure_s",
                "gain", "saturated_pixels")

#: ``sink(start, images, coord_rows)``: stores a block of frames (default
#: :meth:`RunStore.write_frames`).
Sink = Callable[[int, np.ndarray, np.ndarray], None]

_STOP = object()


def _gaps(recorded: list[int]) -> list[list[int]]:
    """Camera indices missing between consecutive recorded ones (inclusive ranges)."""
    ordered = sorted(recorded)
    return [[a + 1, b - 1] for a, b in zip(ordered, ordered[1:], strict=False) if b > a + 1]


class Recorder:
    """Record frames into a writable run store (sharded for video) on a thread.

    Parameters
    ----------
    store : RunStore
        Opened for writing, with coordinates :data:`VIDEO_COORDS` (in any order,
        others allowed and left NaN); usually created with ``shard_frames``.
    queue_frames : int
        Frames the queue between :meth:`offer` and the writer holds (memory:
        ``queue_frames`` frames plus one shard being gathered).
    sink : callable, optional
        ``sink(start, images, coord_rows)`` storing a block; default
        ``store.write_frames`` (tests pass a slowed one).

    Raises
    ------
    RunStoreError
        Read-only store, missing video coordinates, or ``queue_frames`` < 1.
    """

    def __init__(self, store: RunStore, *, queue_frames: int = 40,
                 sink: Sink | None = None) -> None:
        store._require_writable()
        missing = [n for n in VIDEO_COORDS if n not in store.coord_names]
        if missing:
            raise RunStoreError(f"{store.path} lacks the video coordinates {missing}; create "
                                f"the run with coord_names including {list(VIDEO_COORDS)}")
        if not isinstance(queue_frames, int) or queue_frames < 1:
            raise RunStoreError(f"queue_frames={queue_frames!r} is invalid; use an integer >= 1")
        self.store = store
        self.block_frames = store.shard_frames or 1
        self._sink = sink or store.write_frames
        self._queue: queue.Queue = queue.Queue(maxsize=queue_frames)
        self._columns = [store.coord_names.index(n) for n in VIDEO_COORDS]
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._closed = False
        self.delivered = 0
        self.recorded = 0
        self.lost_indices: list[int] = []
        self.recorded_indices: list[int] = []
        self.bytes_written = 0
        self.write_s = 0.0
        self.cpu_s = 0.0
        self._started = 0.0

    # ------------------------------------------------------------------ control
    def start(self) -> None:
        """Take the store's writer lock, mark the run ``recording`` and start the thread.

        Raises
        ------
        RunStoreError
            Another writer holds the run (or a stale lock is left), or already started.
        """
        if self._thread is not None:
            raise RunStoreError("this recorder is already started; create a new one per run")
        self.store.lock()
        self.store.update_attrs(status="recording", started_utc=utc_now())
        self._started = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()

    def offer(self, frame: Frame) -> bool:
        """Hand a delivered frame to the recorder without blocking.

        Returns
        -------
        bool
            True if queued; False if the queue was full: the frame is lost, counted
            and its index kept in ``lost_indices``.

        Raises
        ------
        RunStoreError
            Not started or already closed, the run has no free slot left, or the
            writer failed (the store error, e.g. disk full).
        """
        if self._thread is None or self._closed:
            raise RunStoreError("offer() needs a started, open recorder; call start() first")
        if self._error is not None:
            raise RunStoreError(f"recording to {self.store.path} failed: {self._error}")
        with self._lock:
            if self.delivered >= self.store.n_frames:
                raise RunStoreError(f"{self.store.path} holds {self.store.n_frames} frames and "
                                    "all are taken; create the run with more frames")
            self.delivered += 1
            try:
                self._queue.put_nowait(frame)
            except queue.Full:
                self.lost_indices.append(int(frame.index))
                return False
        return True

    def close(self, *, ring: FrameRing | None = None, status: str = "complete",
              trim: bool = False) -> dict:
        """Write what is queued (the last shard may be partial), store the totals in
        the run's summary, set its status and end time, release the lock.

        Parameters
        ----------
        ring : FrameRing, optional
            The camera ring, whose counters (acquired, dropped before delivery,
            overwritten) are stored with the recorder's.
        status : str
            Run status on success (``"complete"``, or ``"stopped"`` after Ctrl-C).
        trim : bool
            Cut the run to the frames recorded (:meth:`RunStore.truncate`), so a
            recording that ended early or lost frames leaves no empty slots.

        Returns
        -------
        dict
            The ``recording`` summary (:meth:`counters` plus ``index_gaps``).

        Raises
        ------
        RunStoreError
            The writer failed (the run is marked ``failed`` with the error).
        """
        if self._thread is None or self._closed:
            raise RunStoreError("close() needs a started, open recorder")
        self._closed = True
        self._queue.put(_STOP)  # blocks until there is room: the writer is draining
        self._thread.join()
        summary = self.counters(ring)
        summary["index_gaps"] = _gaps(self.recorded_indices)
        failed = self._error is not None
        try:
            if trim and not failed:
                self.store.truncate(self.recorded)
            self.store.update_attrs(
                status="failed" if failed else status, ended_utc=utc_now(),
                error=f"recording failed: {self._error}" if failed else None,
                summary={**self.store.attrs.get("summary", {}), "recording": summary})
        finally:
            self.store.unlock()
        if failed:
            raise RunStoreError(f"recording to {self.store.path} failed: {self._error}")
        return summary

    # ------------------------------------------------------------------ counters
    def counters(self, ring: FrameRing | None = None) -> dict[str, Any]:
        """Totals so far: ``delivered`` (offered), ``recorded`` (done in the store),
        ``queued``, ``lost_by_recorder`` with ``lost_indices`` (inclusive camera-index
        ranges), ``bytes_written`` (raw frame bytes), ``write_s`` (time in the sink),
        ``thread_cpu_s`` (CPU time of the recorder thread itself, known once closed;
        zarr encodes and writes on its own worker threads, which it does not count),
        ``elapsed_s``;
        with ``ring``: ``acquired``, ``dropped_by_camera`` (lost before the ring) and
        ``skipped_by_ring`` (overwritten or discarded unread)."""
        with self._lock:
            out: dict[str, Any] = {
                "delivered": self.delivered, "recorded": self.recorded,
                "queued": self._queue.qsize(), "lost_by_recorder": len(self.lost_indices),
                "lost_indices": index_ranges(self.lost_indices),
                "bytes_written": self.bytes_written, "write_s": round(self.write_s, 4),
                "thread_cpu_s": round(self.cpu_s, 4),
                "elapsed_s": round(time.monotonic() - self._started, 4) if self._started else 0.0,
            }
        if ring is not None:
            c = ring.counters()
            out.update(acquired=c["acquired"], dropped_by_camera=c["dropped"],
                       skipped_by_ring=c["skipped"] - c["dropped"])
        return out

    # ------------------------------------------------------------------ writer thread
    def _run(self) -> None:
        block: list[Frame] = []
        try:
            while True:
                item = self._queue.get()
                if item is _STOP:
                    break
                if self._error is not None:  # failed: count the rest as lost
                    with self._lock:
                        self.lost_indices.append(int(item.index))
                    continue
                block.append(item)
                start = self.recorded
                if len(block) == self.block_frames - start % self.block_frames:
                    self._write(start, block)
                    block = []
            if block and self._error is None:
                self._write(self.recorded, block)
        finally:
            self.cpu_s = time.thread_time()

    def _write(self, start: int, block: list[Frame]) -> None:
        rows = np.full((len(block), len(self.store.coord_names)), np.nan)
        rows[:, self._columns] = [[f.index, f.device_timestamp_s, f.host_timestamp_s,
                                   f.exposure_s, f.gain, f.saturated_pixels] for f in block]
        images = np.stack([f.image for f in block])
        t0 = time.perf_counter()
        try:
            self._sink(start, images, rows)
        except Exception as exc:  # noqa: BLE001 -- reported by offer()/close()
            self._error = kept_error(exc)  # its traceback would hold the block's images
            with self._lock:
                self.lost_indices.extend(int(f.index) for f in block)
            return
        with self._lock:
            self.write_s += time.perf_counter() - t0
            self.recorded += len(block)
            self.recorded_indices.extend(int(f.index) for f in block)
            self.bytes_written += images.nbytes


def record_from_ring(recorder: Recorder, ring: FrameRing, n_frames: int, *,
                     stop: threading.Event | None = None, timeout_s: float = 1.0,
                     on_frame: Callable[[Frame], None] | None = None) -> int:
    """Take frames from ``ring`` in order (none skipped) and offer each to ``recorder``
    until ``n_frames`` are delivered or ``stop`` is set.

    Parameters
    ----------
    recorder : Recorder
        Started.
    ring : FrameRing
        The streaming camera's ring.
    n_frames : int
    stop : threading.Event, optional
        Ends the loop early (Ctrl-C, ``--seconds`` elapsed).
    timeout_s : float
        Longest wait for one frame (s).
    on_frame : callable, optional
        Called with each delivered frame (e.g. a progress line).

    Returns
    -------
    int
        Frames delivered.

    Raises
    ------
    CameraTimeoutError, DeviceError
        The ring's (no frame in time, camera lost).
    RunStoreError
        The recorder's (:meth:`Recorder.offer`).
    """
    delivered = 0
    while delivered < n_frames and not (stop is not None and stop.is_set()):
        frame = ring.get(timeout_s=timeout_s)
        recorder.offer(frame)
        delivered += 1
        if on_frame is not None:
            on_frame(frame)
    return delivered


def recording_summary(store: RunStore) -> Mapping[str, Any] | None:
    """The ``recording`` totals :meth:`Recorder.close` stored, None if it never closed
    (a killed recording: the done flags still say which frames it holds)."""
    return store.attrs.get("summary", {}).get("recording")

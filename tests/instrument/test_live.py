"""instrument.acquisition.live: the live reconstruction worker takes the newest frame, counts skips,
reports fps, latency and errors, and stops in time."""

from __future__ import annotations

import os
import sys
import threading
import time

import numpy as np
import pytest

from drivers.camera import Frame, FrameRing
from instrument.acquisition.live import (
    LatestFrameSlot,
    LiveReconstruction,
    LiveReconstructionError,
    lower_thread_priority,
)
from recon.errors import ReconInputError
from recon.live import LiveReconstructor, LiveResult
from recon.options import ReconOptions
from tests.refcycles import assert_freed_without_the_collector

SHAPE = (32, 40)

#: How long a wait for the worker's progress may take before it is called a hang (s):
#: not a speed check (beside busy processes a thread at nice 10 gets about 1 % of a
#: core); a wait ends as soon as its condition holds.
HANG_S = 120.0


def _frame(index: int, value: float = 1.0) -> Frame:
    image = np.full(SHAPE, 100 + value, np.uint16)
    image[10:20, 12:30] += 50
    return Frame(image, index, 0.01 * index, time.time(), 0.005, 0.0, 0)


class SlowReconstructor:
    """Stands in for recon.live.LiveReconstructor: sleeps, records the frames it saw."""

    def __init__(self, seconds: float, fail_on: int | None = None):
        self.seconds, self.fail_on = seconds, fail_on
        self.seen: list[int] = []
        self.resets = 0

    def _run(self, raw, method, iterations, warm):
        time.sleep(self.seconds)
        index = int(raw[0, 0]) - 100
        if index == self.fail_on:
            raise ReconInputError(f"frame {index} is bad; fix the test frame")
        self.seen.append(index)
        return LiveResult(raw.astype(np.float32), raw.astype(np.float32), None, method,
                          iterations, warm, 1.0, self.seconds)

    def wiener(self, raw):
        return self._run(raw, "wiener", 1, False)

    def admm(self, raw, iterations, warm_start):
        return self._run(raw, "admm", iterations, warm_start)

    def reset(self):
        self.resets += 1


class GatedReconstructor(SlowReconstructor):
    """A SlowReconstructor whose solves wait until the test opens ``gate``: the test,
    not the machine's speed, decides when a solve ends (a solve left waiting
    :data:`HANG_S` goes on, so a test that fails does not hang)."""

    def __init__(self, seconds: float):
        super().__init__(seconds)
        self.gate = threading.Event()

    def _run(self, raw, method, iterations, warm):
        self.gate.wait(HANG_S)
        return super()._run(raw, method, iterations, warm)


def _wait_for(condition, timeout_s=HANG_S):
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"condition not reached in {timeout_s:g} s: a hang"
        time.sleep(0.005)


def _join(thread: threading.Thread) -> None:
    thread.join(HANG_S)
    assert not thread.is_alive(), f"{thread.name} still running after {HANG_S:g} s: a hang"


def test_slot_keeps_the_newest_frame_and_counts_overwrites():
    slot = LatestFrameSlot()
    assert slot.take(0.0) is None
    for i in range(3):
        slot.offer(_frame(i))
    assert slot.counters() == {"received": 3, "taken": 0, "skipped": 2, "waiting": 1}
    assert slot.take(0.0).index == 2
    assert slot.take(0.01) is None
    got = []
    t = threading.Thread(target=lambda: got.append(slot.take(HANG_S)))
    t.start()
    slot.offer(_frame(7))
    _join(t)
    assert got[0].index == 7 and slot.counters()["skipped"] == 2
    # close wakes a take that waits (for an hour here): stop() does not wait out a poll
    t = threading.Thread(target=lambda: got.append(slot.take(3600.0)), name="waiting take")
    t.start()
    _wait_for(lambda: len(slot._cond._waiters) == 1)  # it waits (CPython's Condition)
    slot.close()
    _join(t)
    assert got[1] is None
    assert slot.take(5.0) is None  # closed: returns at once


def test_worker_fed_faster_than_it_works_takes_the_newest_and_counts_skips():
    # frame 0's solve is held while 39 more frames are offered: offer returns while the
    # worker is busy, and the worker then takes the newest, counting the rest as skipped
    slow = GatedReconstructor(0.04)
    live = LiveReconstruction(slow, window_s=HANG_S)
    live.start(timeout_s=HANG_S)
    live.offer(_frame(0, value=0))
    _wait_for(lambda: live.slot.counters()["taken"] == 1)  # frame 0 is being solved
    first_offered = time.time()
    for i in range(1, 40):
        live.offer(_frame(i, value=i))
    assert slow.seen == [] and not slow.gate.is_set()  # no offer waited for the solve
    opened = time.time()
    slow.gate.set()
    _wait_for(lambda: live.latest() is not None and live.latest().frame_index == 39)
    live.stop(timeout_s=HANG_S)
    s = live.stats()
    assert s["received"] == 40 and slow.seen == [0, 39]
    assert s["reconstructed"] == 2 and s["skipped"] == 38  # every frame accounted for
    assert s["errors"] == 0 and s["last_error"] is None and not s["running"]
    # two results 40 ms of solving apart: at most 25 per second (a lower bound would be a
    # speed check: run_live_benchmark measures the rate)
    assert 0 < s["fps"] < 26
    assert s["latency_median_s"] >= 0.04 and s["latency_p95_s"] >= s["latency_median_s"]
    summary = live.latency_summary()
    assert summary["count"] == 2 and summary["max_s"] >= opened - first_offered
    assert summary["compute_median_s"] == pytest.approx(0.04)  # the solver's own figure


def test_worker_on_a_ring_with_the_real_reconstructor():
    psf = np.full(SHAPE, 100, np.uint16)
    psf[14:18, 18:22] = 3000
    psf[8, 30] = 1500
    ring = FrameRing(8)
    live = LiveReconstruction(LiveReconstructor(psf, ReconOptions.from_defaults(dark=100.0),
                                                regularization=1e-2))
    live.start(ring=ring)
    for i in range(5):
        ring.put(_frame(i, value=i))
        time.sleep(0.02)
    # the first frame compiles the kernels (a wait, not a speed check)
    _wait_for(lambda: live.stats()["reconstructed"] >= 1 and live.stats()["received"] == 5)
    preview = live.latest()
    assert preview.method == "wiener" and preview.image.shape == SHAPE
    assert preview.latency_s > 0 and preview.result_time_s > preview.host_timestamp_s
    live.set_method("admm", iterations=3)
    ring.put(_frame(5))
    ring.put(_frame(6))
    _wait_for(lambda: live.latest().frame_index == 6)
    assert live.latest().method == "admm" and live.latest().iterations == 3
    live.stop(timeout_s=HANG_S)
    s = live.stats()
    assert s["received"] == 7 == s["reconstructed"] + s["skipped"]
    assert ring.counters()["read"] == 7 and s["latency_s"] is not None
    with pytest.raises(ReconInputError, match="unknown"):
        live.set_method("fista")


def test_errors_in_the_worker_are_reported_and_it_goes_on():
    slow = SlowReconstructor(0.0, fail_on=1)
    live = LiveReconstruction(slow)
    with live:
        live.start()
        for i in range(3):
            live.offer(_frame(i, value=i))
            _wait_for(lambda i=i: live.slot.counters()["taken"] == i + 1)
        _wait_for(lambda: live.stats()["reconstructed"] + live.stats()["errors"] == 3)
    s = live.stats()
    assert s["errors"] == 1 and s["reconstructed"] == 2
    assert "frame 1" in s["last_error"] and "ReconInputError" in s["last_error"]
    assert isinstance(live.error, ReconInputError)


def test_a_failed_ring_is_reported():
    ring = FrameRing(4)
    live = LiveReconstruction(SlowReconstructor(0.0))
    live.start(ring=ring)
    ring.fail(ConnectionError("camera unplugged"))
    _wait_for(lambda: live.stats()["errors"] == 1)
    live.stop(timeout_s=HANG_S)
    assert "camera unplugged" in live.stats()["last_error"]


def test_stop_returns_within_its_timeout_or_says_why():
    slow = GatedReconstructor(0.0)
    live = LiveReconstruction(slow)
    live.start(timeout_s=HANG_S)
    live.stop(timeout_s=HANG_S)  # idle worker: woken by the slot's close, ends
    assert not live.running
    live.start(timeout_s=HANG_S)
    live.offer(_frame(0))
    _wait_for(lambda: live.slot.counters()["taken"] == 1)  # its solve waits on the gate
    with pytest.raises(LiveReconstructionError, match="longer than one frame"):
        live.stop(timeout_s=0.05)
    assert not slow.gate.is_set() and slow.seen == []  # it returned, the solve still held
    with pytest.raises(LiveReconstructionError, match="already running"):
        live.start()
    slow.gate.set()
    live.stop(timeout_s=HANG_S)
    assert not live.running and live.stats()["reconstructed"] == 1


class ThreadProbe(SlowReconstructor):
    """Records the FFT workers and numba threads the worker thread runs with."""

    def _run(self, raw, method, iterations, warm):
        from recon.fft import fft_workers
        from recon.jit import thread_count

        self.threads_seen = (fft_workers(), thread_count())
        return super()._run(raw, method, iterations, warm)


def test_threads_caps_the_worker_and_nothing_else():
    from recon.fft import fft_workers
    from recon.jit import thread_count

    with pytest.raises(ReconInputError, match="threads=0"):
        LiveReconstruction(SlowReconstructor(0.0), threads=0)
    probe = ThreadProbe(0.0)
    live = LiveReconstruction(probe, threads=1)
    before = (fft_workers(), thread_count())
    live.start()
    try:
        live.offer(_frame(1))
        _wait_for(lambda: live.stats()["reconstructed"] == 1)
        assert probe.threads_seen == (1, 1)
        assert (fft_workers(), thread_count()) == before  # this thread keeps all cores
    finally:
        live.stop(timeout_s=HANG_S)


def test_limited_threads_restores_the_caller():
    from recon.fft import fft_workers, limited_threads
    from recon.jit import thread_count

    before = (fft_workers(), thread_count())
    with limited_threads(1):
        assert (fft_workers(), thread_count()) == (1, 1)
    assert (fft_workers(), thread_count()) == before
    with pytest.raises(ReconInputError, match="threads=99"):
        with limited_threads(99):
            pass


class NiceProbe(SlowReconstructor):
    """Records the nice value of the thread that reconstructs."""

    def _run(self, raw, method, iterations, warm):
        import os

        self.nice = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
        return super()._run(raw, method, iterations, warm)


@pytest.mark.skipif(not hasattr(os, "getpriority") or not sys.platform.startswith("linux"),
                    reason="per-thread priorities are Linux's")
def test_nice_lowers_the_worker_thread_and_nothing_else():
    mine = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    probe = NiceProbe(0.0)
    live = LiveReconstruction(probe, nice=5)
    live.start(timeout_s=HANG_S)
    try:
        live.offer(_frame(1))
        _wait_for(lambda: live.stats()["reconstructed"] == 1)
        assert probe.nice == min(mine + 5, 19)
        assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == mine
    finally:
        live.stop(timeout_s=HANG_S)
    with pytest.raises(ReconInputError, match="nice"):
        LiveReconstruction(probe, nice=-1)


@pytest.mark.skipif(not hasattr(os, "getpriority") or not sys.platform.startswith("linux"),
                    reason="per-thread priorities are Linux's")
def test_started_from_a_lowered_thread_the_worker_is_counted_from_the_process():
    """The GUI starts the live reconstruction from a job thread already at nice 10: the
    worker runs ``nice`` below the process, not below that thread (it ran at 19)."""
    process = os.getpriority(os.PRIO_PROCESS, os.getpid())
    probe = NiceProbe(0.0)
    live = LiveReconstruction(probe, nice=10)

    failed: list[BaseException] = []

    def from_a_job_thread():
        try:
            assert lower_thread_priority(10)
            assert not lower_thread_priority(10)  # already that low: left as it is
            live.start(timeout_s=HANG_S)  # at nice 10 beside busy processes: slow to come up
        except BaseException as exc:  # raised again in the test's own thread
            failed.append(exc)

    t = threading.Thread(target=from_a_job_thread, name="job")
    t.start()
    _join(t)
    if failed:
        raise failed[0]
    try:
        live.offer(_frame(1))
        _wait_for(lambda: live.stats()["reconstructed"] == 1)
        assert probe.nice == min(process + 10, 19)
    finally:
        live.stop(timeout_s=HANG_S)


def test_a_stopped_live_reconstruction_with_an_error_is_freed_without_the_collector():
    """The worker's error is kept without its traceback: the traceback's frames hold
    the live reconstruction (a cycle). Once frozen by the GUI's settle_heap such a
    cycle is never collected: the operator's day kept a stopped ADMM view's arrays."""
    ring = FrameRing(4)
    live = LiveReconstruction(SlowReconstructor(0.0, fail_on=0))
    live.start(ring=ring)
    ring.put(_frame(0, value=0))  # the reconstruction fails on it
    _wait_for(lambda lr=live: lr.stats()["errors"] == 1)
    assert "frame 0" in live.stats()["last_error"]
    ring.fail(ConnectionError("camera unplugged"))
    _wait_for(lambda lr=live: lr.stats()["errors"] == 2)
    live.stop(timeout_s=HANG_S)
    assert isinstance(live.error, ConnectionError) and "frame 0" not in live.stats()["last_error"]
    held = {"live": live}
    del live
    assert_freed_without_the_collector(held, "live", "stopped live reconstruction")

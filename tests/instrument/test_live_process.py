"""The live reconstruction in a process of its own (instrument.acquisition.live_process) and the
shared-memory slot its frames and results go through (instrument.acquisition.shared_slot): the
same results as on a thread, the child's errors back with their type, a killed child
reported while the caller goes on, its priority below the caller's, and a slot that
never hands out a half-written image while another process writes it."""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from drivers.camera import Frame
from instrument.acquisition.live import LiveReconstruction, LiveReconstructionError
from instrument.acquisition.live_process import LiveReconstructionProcess
from instrument.acquisition.shared_slot import META_FIELDS, SharedImageSlot
from recon.errors import ReconInputError
from recon.live import LiveReconstructor
from recon.operators import ConvolutionOperator
from recon.options import LiveOptions, ReconOptions

# -- the slot ---------------------------------------------------------------------------


def test_a_slot_hands_over_the_newest_image_with_its_metadata():
    slot = SharedImageSlot(4 * 6 * 8 * 3)
    other = SharedImageSlot(4 * 6 * 8 * 3, name=slot.name)
    try:
        assert other.read() is None and slot.sequence == 0
        first = np.arange(24, dtype=np.uint16).reshape(4, 6)
        assert slot.write(first, meta=[3.0, 1.5]) == 1
        colour = np.random.default_rng(0).random((4, 6, 3))
        assert slot.write(colour, meta=np.arange(META_FIELDS)) == 2
        got = other.read()
        assert got.sequence == 2 and got.image.dtype == np.float64
        np.testing.assert_array_equal(got.image, colour)
        np.testing.assert_array_equal(got.meta, np.arange(META_FIELDS))
        assert other.read(after=2) is None  # nothing newer
        slot.write(first, meta=[3.0])
        got = other.read(after=2)
        np.testing.assert_array_equal(got.image, first)
        assert got.meta[0] == 3.0 and got.meta[1] == 0.0  # unset fields are 0
        got.image[0, 0] = 99  # a private copy
        assert other.read().image[0, 0] == 0
    finally:
        other.close()
        slot.close()
    assert not Path("/dev/shm", slot.name).exists()  # the maker removed it


def test_a_slot_refuses_what_it_cannot_hold():
    slot = SharedImageSlot(64)
    try:
        with pytest.raises(ValueError, match="at most 64 bytes"):
            slot.write(np.zeros((5, 5), np.float32))
        with pytest.raises(ValueError, match="uint8, uint16, float32 or float64"):
            slot.write(np.zeros((2, 2), np.int32))
        with pytest.raises(ValueError, match="at most 12 metadata"):
            slot.write(np.zeros((2, 2), np.uint8), meta=range(13))
        assert slot.sequence == 0
    finally:
        slot.close()
    with pytest.raises(ValueError, match="at least 1 byte"):
        SharedImageSlot(0)


def test_a_read_that_races_the_writer_on_its_buffer_is_discarded():
    slot = SharedImageSlot(64)
    try:
        slot.write(np.ones((2, 2), np.float32))
        slot.write(np.full((2, 2), 2, np.float32))
        n = slot.sequence
        slot._counters[1] = n + 1  # the writer fills the other buffer: this copy is good
        assert slot.read().image[0, 0] == 2
        slot._counters[1] = n + 2  # the writer is overwriting this very buffer
        assert slot.read(attempts=3) is None
    finally:
        slot.close()


def _write_uniform(name: str, capacity: int, n: int, reads, wrote) -> None:
    """Write images ``1, 2, ...`` (every pixel and the metadata the image's number) as
    fast as it can: at least ``n``, and on until the reader has read ``MIN_READS`` of
    them while it wrote (a hang guard: ``MAX_WRITES``); ``wrote`` is the last number."""
    slot = SharedImageSlot(capacity, name=name)
    k = 0
    while k < MAX_WRITES and (k < n or reads.value < MIN_READS):
        k += 1
        slot.write(np.full((256, 256), k, np.float32), meta=[k])
    wrote.value = k
    slot.close()


#: Images the reader must have read while the writer wrote, and the writer's most.
MIN_READS, MAX_WRITES = 50, 2_000_000


def test_no_torn_image_while_another_process_writes():
    """Every image read while a child writes images as fast as it can (at least 3000,
    and until the reader has read 50 of them however the machine shares its cores) is
    one whole image: all its pixels and its metadata carry the same number."""
    slot = SharedImageSlot(256 * 256 * 4)
    ctx = multiprocessing.get_context("spawn")
    reads_shared, wrote = ctx.Value("q", 0), ctx.Value("q", 0)
    writer = ctx.Process(target=_write_uniform,
                         args=(slot.name, slot.capacity, 3000, reads_shared, wrote))
    try:
        writer.start()
        reads, last = 0, 0
        deadline = time.monotonic() + HANG_S
        while (writer.is_alive() or last < max(wrote.value, 1)) and (
                time.monotonic() < deadline):
            got = slot.read(after=last)
            if got is None:
                continue
            k = got.meta[0]
            assert got.image.min() == got.image.max() == k, "a torn image"
            assert got.sequence >= last and k == got.sequence
            last, reads = got.sequence, reads + 1
            reads_shared.value = reads
        writer.join(30)
        assert last == wrote.value >= 3000 and reads >= MIN_READS, (last, wrote.value, reads)
    finally:
        writer.join(30)
        slot.close()


# -- the live reconstruction in a child process --------------------------------------------


def _problem():
    rng = np.random.default_rng(1)
    psf = 100.0 * (rng.random((48, 64)) > 0.97)
    scene = np.zeros((96, 128), np.float32)
    scene[40:56, 50:70] = 1.0
    return psf, ConvolutionOperator(psf).forward(scene).astype(np.float32)


def _frame(image, index):
    return Frame(image, index, 0.01 * index, time.time(), 0.01, 0.0, 0)


def _index(live) -> int:
    latest = live.latest()
    return -1 if latest is None else latest.frame_index


#: How long a wait for the child's progress may take before it is called a hang (s): not
#: a speed check (the child starts, imports and solves at nice +10, which beside busy
#: processes gets about 1 % of a core); a wait ends as soon as its condition holds.
HANG_S = 600.0
#: The reconstruction's options of these tests: frames and PSF without a dark level.
DARK_0 = ReconOptions.from_defaults(dark=0.0)


def _until(condition, what, timeout_s=HANG_S):
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"no {what} in {timeout_s:g} s: a hang")
        time.sleep(0.02)


def test_the_child_gives_what_the_thread_gives():
    psf, image = _problem()
    admm4 = LiveOptions.from_defaults(method="admm", iterations=4)
    thread = LiveReconstruction(LiveReconstructor(psf, DARK_0), admm4)
    thread.start(timeout_s=HANG_S)
    proc = LiveReconstructionProcess(psf, admm4, options=DARK_0)
    proc.start(timeout_s=HANG_S)
    try:
        assert proc.backend_label == "cpu (numpy)" and proc.sensor_shape == (48, 64)
        for k in range(3):  # each frame waits for its result: warm starts match
            for live in (thread, proc):
                live.offer(_frame(image, k))
                _until(lambda live=live, k=k: _index(live) == k, f"frame {k}")
        a, b = thread.latest(), proc.latest()
        assert (b.method, b.iterations, b.warm) == ("admm", 4, True)
        np.testing.assert_array_equal(a.image, b.image)
        proc.set_method("wiener")
        proc.offer(_frame(image, 7))
        # the image comes through the shared slot, its count through the pipe, each in its
        # own time: both are waited for
        _until(lambda: _index(proc) == 7 and proc.stats()["reconstructed"] == 4,
               "the Wiener frame and its count")
        assert proc.latest().method == "wiener"
        s = proc.stats()
        assert (s["received"], s["reconstructed"], s["errors"], s["skipped"]) == (4, 4, 0, 0)
        assert s["running"] and s["method"] == "wiener"
    finally:
        thread.stop(timeout_s=HANG_S)
        proc.stop(timeout_s=HANG_S)
    assert not proc.running and proc.latency_summary()["count"] == 4


def test_a_switch_applies_to_the_very_next_frame():
    # the settings travel with the frame: a switch is never overtaken by the frame after it
    psf, image = _problem()
    with LiveReconstructionProcess(psf, LiveOptions.from_defaults(method="admm", iterations=2),
                                   options=DARK_0) as proc:
        proc.start(timeout_s=HANG_S)
        for k in range(8):
            method = ("wiener", "admm")[k % 2]
            proc.set_method(method)
            proc.offer(_frame(image, k))
            _until(lambda k=k: _index(proc) == k, f"frame {k}")
            assert proc.latest().method == method, f"frame {k}"
        assert proc.stats()["errors"] == 0
        proc.stop(timeout_s=HANG_S)


def test_the_childs_build_error_comes_back_with_its_type():
    psf, _ = _problem()
    proc = LiveReconstructionProcess(psf, options=DARK_0.replace(bin_factor=0))
    with pytest.raises(ReconInputError, match="bin"):
        proc.start(timeout_s=HANG_S)
    assert not proc.running
    proc.stop(timeout_s=HANG_S)  # nothing to stop: no error


def test_a_killed_child_is_reported_and_the_caller_goes_on():
    psf, image = _problem()
    proc = LiveReconstructionProcess(psf, options=DARK_0)
    proc.start(timeout_s=HANG_S)
    pid = proc.child_info["pid"]
    proc.offer(_frame(image, 0))
    _until(lambda: proc.latest() is not None, "a result")
    os.kill(pid, signal.SIGKILL)
    _until(lambda: not proc.running, "the child's end to be seen")
    _until(lambda: proc.stats()["last_error"] is not None, "the report")
    s = proc.stats()
    assert "process ended" in s["last_error"] and "start the reconstruction again" in (
        s["last_error"])
    # how it ended, in words (the exit status is read after the child is reaped)
    assert "killed (signal 9, SIGKILL)" in s["last_error"], s["last_error"]
    assert s["errors"] == 1 and proc.latest().frame_index == 0  # the last result stays
    proc.offer(_frame(image, 1))  # the stream's consumer is not hurt
    proc.stop(timeout_s=HANG_S)


def test_the_child_runs_below_the_callers_priority():
    psf, _ = _problem()
    proc = LiveReconstructionProcess(psf, options=DARK_0, nice=5)
    proc.start(timeout_s=HANG_S)
    try:
        process = os.getpriority(os.PRIO_PROCESS, os.getpid())
        assert proc.child_info["nice"] == min(19, process + 5)
    finally:
        proc.stop(timeout_s=HANG_S)


def test_a_frame_of_another_shape_is_an_error_not_a_crash():
    psf, image = _problem()
    proc = LiveReconstructionProcess(psf, options=DARK_0)
    proc.start(timeout_s=HANG_S)
    try:
        proc.offer(_frame(np.zeros((480, 640), np.float64), 0))  # larger than the slot
        assert "does not fit the slot" in proc.stats()["last_error"]
        proc.offer(_frame(np.zeros((24, 32), np.float32), 1))  # fits, wrong for the PSF
        _until(lambda: proc.stats()["errors"] == 2, "the child's error")
        assert "frame 1" in proc.stats()["last_error"]
        proc.offer(_frame(image, 2))
        _until(lambda: proc.latest() is not None, "a result after the errors")
        assert proc.running
    finally:
        proc.stop(timeout_s=HANG_S)
    with pytest.raises(LiveReconstructionError, match="already running"):
        proc.start(timeout_s=HANG_S)
        proc.start(timeout_s=HANG_S)
    proc.stop(timeout_s=HANG_S)


def test_the_child_is_fed_from_a_camera_ring():
    from drivers.camera import FrameRing

    psf, image = _problem()
    ring = FrameRing(8)
    proc = LiveReconstructionProcess(psf, options=DARK_0)
    proc.start(ring=ring, timeout_s=HANG_S)
    try:
        ring.put(_frame(image, 3))
        _until(lambda: _index(proc) == 3, "the ring's frame reconstructed")
        ring.fail(RuntimeError("the camera was unplugged"))
        _until(lambda: proc.stats()["last_error"] is not None, "the ring's error")
        assert "the camera was unplugged" in proc.stats()["last_error"]
    finally:
        proc.stop(timeout_s=HANG_S)


def test_a_thread_count_the_machine_has_not_is_refused_before_the_child_starts():
    psf, _ = _problem()
    with pytest.raises(ReconInputError, match="threads"):
        LiveReconstructionProcess(psf, threads=0)

"""A live stream that ends unasked is told to every client (issue 67: *Stop stream* stayed
shown after the stream died): a camera that goes silent without an error, a frame that
cannot be published. Nothing here waits on the clock but the hang guards: the silence
bound is made short after the first frames, and each test waits for the event."""

from __future__ import annotations

import queue
import threading

import pytest

from instrument.bench.bench_host import STREAM_SILENCE_FLOOR_S, STREAM_SILENCE_PERIODS, BenchHost
from instrument.bench.bench_process import BenchClient

OPEN = {"bench_path": None, "simulate": True, "seed": 0, "scene": "none"}
#: A hang guard, s: what the tests wait for comes within a second on an idle machine.
HANG_S = 120.0


# -- jobs the host runs in these tests (imported there by name) ---------------------------
def silence_camera(ctx, *, floor_s: float) -> float:
    """The camera delivers nothing from now on (every frame lost, no error) and the
    stream's silence floor is ``floor_s``; returns the bound the stream now waits."""
    ctx.bench.camera.faults.drop_frames(probability=1.0)
    ctx.host.stream_silence_floor_s = floor_s
    return ctx.host.stream_silence_s()


def camera_streaming(ctx) -> bool:
    return bool(ctx.bench.camera.is_streaming)


def hold_camera(ctx) -> str:
    """Hold the camera until stopped (a hang guard of 10 minutes)."""
    ctx.stop.wait(600.0)
    return "stopped" if ctx.stop.is_set() else "timed out"


def _declared(fn):
    from instrument.bench.bench_jobs import holding

    return holding("camera")(fn)


JOBS = {"silence_camera": silence_camera, "camera_streaming": camera_streaming,
        "hold_camera": _declared(hold_camera)}


@pytest.fixture(params=[False, True], ids=["child-process", "in-process"])
def streamed(request):
    """A client with the simulated bench open, its stream running, and a second client
    attached (a notebook beside the window) whose events are collected."""
    frames: queue.SimpleQueue = queue.SimpleQueue()
    ended, messages = threading.Event(), []
    c = BenchClient(in_process=request.param, jobs=JOBS,
                    on_frame=lambda f, m: frames.put(f), on_message=messages.append,
                    on_stream_ended=ended.set)
    other = None
    try:
        c.run_job("open_bench", OPEN)
        seen: queue.SimpleQueue = queue.SimpleQueue()
        if not c.in_process:
            other = BenchClient(address=c.address, authkey=c.authkey, name="a notebook",
                                on_event=seen.put)
        c.start_stream(16)
        for _ in range(3):
            frames.get(timeout=HANG_S)
        c.ended, c.messages, c.seen, c.other = ended, messages, seen, other
        yield c
    finally:
        if other is not None:
            other.close()
        c.close()


def _stream_event(seen: queue.SimpleQueue) -> dict:
    while True:
        event = seen.get(timeout=HANG_S)
        if event.kind == "stream":
            return event.data


def test_a_silent_camera_ends_the_stream_for_every_client(streamed):
    bound_s = streamed.run_job("silence_camera", {"floor_s": 0.2})
    assert bound_s == pytest.approx(max(0.2, STREAM_SILENCE_PERIODS / 30.0))
    assert streamed.ended.wait(HANG_S), "the window was never told the stream died"
    line = streamed.messages[-1]
    assert line.startswith("camera stream stopped: no frame from the camera for ")
    assert "check the camera's cable and power" in line and "()" not in line
    assert "frames were lost on the way" in line  # the simulated camera drops them
    assert not streamed.run_job("camera_streaming")  # the camera's stream stopped too
    if streamed.other is not None:  # the notebook beside the window sees the same end
        data = _stream_event(streamed.seen)
        assert data["state"] == "ended" and data["reason"] == line
        assert data["owner"].startswith("pid ")
    streamed.start_stream(16)  # starts again: the dead stream left nothing held
    assert streamed.run_job("camera_streaming")
    streamed.stop_stream(2.0)


def test_the_silence_bound_is_the_floor_or_ten_frame_periods_and_none_when_triggered():
    class Cam:
        trigger_mode, resulting_frame_rate_hz = "free_run", 0.25  # a 4 s exposure

    class Bench:
        camera = Cam()

    host = BenchHost(events=None, wake=None)
    assert host.stream_silence_s() == STREAM_SILENCE_FLOOR_S  # no bench: the floor
    host.bench = Bench()
    assert host.stream_silence_s() == STREAM_SILENCE_PERIODS * 4.0
    Cam.resulting_frame_rate_hz = 30.0
    assert host.stream_silence_s() == STREAM_SILENCE_FLOOR_S
    Cam.trigger_mode = "hardware"  # waiting for its trigger is not a silence
    assert host.stream_silence_s() == float("inf")


def test_a_frame_that_cannot_be_published_ends_the_stream_and_says_why():
    ended, messages = threading.Event(), []
    c = BenchClient(in_process=True, on_message=messages.append, on_stream_ended=ended.set)
    try:
        c.run_job("open_bench", OPEN)
        host, published = c.host, threading.Event()

        def full(frame, ring=None):
            published.set()
            raise OSError(28, "No space left on device")

        host.publish = full
        c.start_stream(16)
        assert ended.wait(HANG_S), "the window was never told the stream died"
        assert published.is_set()
        assert messages[-1] == "camera stream stopped: [Errno 28] No space left on device"
        assert not host.streaming and not host.bench.camera.is_streaming
    finally:
        c.close()


def test_a_stream_stopped_by_another_client_ends_for_the_one_it_ran_for(streamed):
    if streamed.other is None:
        pytest.skip("a second client attaches to a bench process of its own")
    streamed.other.stop_stream(2.0)
    assert streamed.ended.wait(HANG_S), "the window was never told its stream stopped"
    assert streamed.messages[-1] == f"live stream stopped by {streamed.other.name}"
    data = _stream_event(streamed.seen)
    assert data["state"] == "ended" and data["reason"] == streamed.messages[-1]
    streamed.ended.clear()
    streamed.start_stream(16)
    streamed.stop_stream(2.0)  # its own stop: nothing to tell
    assert streamed.run_job("camera_streaming") is False
    assert not streamed.ended.is_set()


def test_every_client_sees_a_job_take_the_stream_s_camera_and_give_it_back(streamed):
    if streamed.other is None:
        pytest.skip("a second client attaches to a bench process of its own")
    handle = streamed.other.start_job("hold_camera")
    data = _stream_event(streamed.seen)
    assert data["state"] == "yielded" and data["owner"] == streamed.name
    assert data["to"].startswith(f"job {handle.id} (hold_camera) of ")
    handle.stop()
    assert handle.result(timeout_s=HANG_S) == "stopped"
    assert _stream_event(streamed.seen) == {"state": "resumed", "owner": streamed.name}
    assert not streamed.ended.is_set()


def test_a_frame_slot_gone_before_it_is_attached_leaves_the_reader_reading():
    """The host told the client of a new frame slot that was gone (unlinked) before the
    client's reader attached it (a bench closing, or a newer slot; seen as a
    FileNotFoundError that ended the 'bench-frames' thread under load): the reader goes
    on, and the stream's frames still arrive. On the old code the thread died and no
    frame came again."""
    import time

    frames: queue.SimpleQueue = queue.SimpleQueue()
    c = BenchClient(in_process=True, on_frame=lambda f, m: frames.put(f))
    try:
        c.run_job("open_bench", OPEN)
        with c._lock:
            c._next_slot = ("dlab-0-0-gone0000", 1 << 16)  # no such block
        c.host.wake.release()
        deadline = time.monotonic() + HANG_S
        while c._next_slot is not None and time.monotonic() < deadline:
            time.sleep(0.01)  # until the reader took the event
        assert c._next_slot is None, "the reader never looked"
        c.start_stream(16)
        frames.get(timeout=HANG_S)
        reader = [t for t in c._threads if t.name == "bench-frames"]
        assert reader and reader[0].is_alive()
    finally:
        c.close()

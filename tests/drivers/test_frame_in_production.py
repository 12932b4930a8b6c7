"""A reader's wait and a frame still being made (``FrameRing.producing``): the simulated
camera renders each frame on the CPU, and at load 19 a 30 fps recording's 5.3 s wait
ran out while a frame was rendering ("no frame within 5.33333 s", the simulated
operator day)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from drivers import camera as camera_module
from drivers.camera import FrameRing
from drivers.errors import CameraTimeoutError
from drivers.simulated import SimClock, SimulatedCamera

SHAPE = (48, 64)


def _read_while_blocked(ring: FrameRing, release: threading.Event) -> dict:
    """``ring.get(timeout_s=0)`` on a thread; ``release`` is set only once that read is
    waiting past its timeout (or has ended). Returns what the read gave."""
    waiting, got = threading.Event(), {}
    wait_for = ring._cond.wait_for

    def spy(*args, **kwargs):
        waiting.set()
        return wait_for(*args, **kwargs)

    ring._cond.wait_for = spy

    def read() -> None:
        try:
            got["frame"] = ring.get(timeout_s=0.0)
        except CameraTimeoutError as exc:
            got["error"] = exc
        finally:
            waiting.set()

    reader = threading.Thread(target=read)
    reader.start()
    assert waiting.wait(60)
    release.set()
    reader.join(60)
    assert not reader.is_alive()
    return got


def test_a_frame_rendering_when_the_wait_runs_out_is_waited_for():
    rendering, release, calls = threading.Event(), threading.Event(), [0]

    def irradiance(cam):
        calls[0] += 1
        if calls[0] == 1:  # the first frame's render is slow (a busy machine)
            rendering.set()
            release.wait(60)
        return np.full(SHAPE, 1e4)

    cam = SimulatedCamera("cam0", sensor_shape=SHAPE, clock=SimClock(realtime=True),
                          max_frame_rate_hz=200.0, irradiance=irradiance)
    cam.open()
    try:
        cam.exposure_s = 0.002
        ring = FrameRing(4)
        cam.start_stream(ring)
        assert rendering.wait(60)
        got = _read_while_blocked(ring, release)
        assert "error" not in got, got
        assert got["frame"].index == 0
    finally:
        release.set()
        cam.stop_stream()
        cam.close()


def test_a_frame_that_never_comes_still_times_out_after_its_making():
    """Made and dropped (nothing put): the reader's timeout stands."""
    ring, release, started = FrameRing(2), threading.Event(), threading.Event()

    def produce() -> None:
        with ring.producing():
            started.set()
            release.wait(60)

    producer = threading.Thread(target=produce)
    producer.start()
    assert started.wait(60)
    got = _read_while_blocked(ring, release)
    producer.join(60)
    assert "no frame within 0 s" in str(got["error"])


def test_a_making_that_hangs_is_bounded(monkeypatch):
    monkeypatch.setattr(camera_module, "PRODUCING_HANG_S", 0.01)
    ring = FrameRing(2)
    with ring.producing(), pytest.raises(CameraTimeoutError):
        ring.get(timeout_s=0.0)  # the same thread: nothing can come; the guard ends it


def test_without_a_making_the_timeout_is_as_before():
    with pytest.raises(CameraTimeoutError):
        FrameRing(2).get(timeout_s=0.0)

"""The acquisition thread the streaming camera drivers share (drivers/grab_thread.py)."""

from __future__ import annotations

import logging
import threading

import pytest

from drivers.aravis_camera import AravisCamera
from drivers.errors import DeviceDisconnectedError
from drivers.grab_thread import GrabStream
from drivers.v4l2_camera import V4l2Camera


class _Ring:
    def __init__(self):
        self.failed = threading.Event()
        self.exc = None

    def fail(self, exc):
        self.exc = exc
        self.failed.set()


class _Driver(GrabStream):
    device_id = "cam9"
    _log = logging.getLogger("test_grab_thread")
    _disconnected = False


@pytest.mark.parametrize("cls", [AravisCamera, V4l2Camera])
def test_the_streaming_drivers_share_one_start_and_stop(cls):
    assert issubclass(cls, GrabStream)
    assert "_stop_grab" not in vars(cls) and "_start_grab" not in vars(cls)


def test_a_grab_thread_runs_until_stopped_and_is_named_after_the_device():
    drv, ring = _Driver(), _Ring()
    running, names = threading.Event(), []

    def loop(stop):
        names.append(threading.current_thread().name)
        running.set()
        stop.wait(120.0)

    drv._stop_grab()  # nothing runs: a no-op
    drv._start_grab(ring, loop, "test", 60.0)
    assert running.wait(120.0) and names == ["cam9-test"]
    thread = drv._grab._thread
    drv._stop_grab()
    assert drv._grab is None and not thread.is_alive() and not ring.failed.is_set()


def test_a_lost_camera_ends_the_stream_through_the_ring():
    drv, ring = _Driver(), _Ring()
    lost = DeviceDisconnectedError("cam9", "unplugged", "plug it in")

    def loop(stop):
        raise lost

    drv._start_grab(ring, loop, "test", 60.0)
    assert ring.failed.wait(120.0) and ring.exc is lost and drv._disconnected
    drv._stop_grab()


def test_a_thread_outliving_its_join_is_logged(caplog):
    drv, ring = _Driver(), _Ring()
    running, release = threading.Event(), threading.Event()

    def loop(stop):
        running.set()
        release.wait(120.0)  # stuck in a driver call: deaf to its stop

    drv._start_grab(ring, loop, "stuck", 0.01)
    assert running.wait(120.0)
    with caplog.at_level(logging.WARNING, logger="drivers"):
        drv._stop_grab()
    release.set()
    assert "cam9-stuck: the grab thread did not end" in caplog.text

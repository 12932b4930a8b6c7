"""Errors, the Device base class and FrameRing, independent of any driver."""

from __future__ import annotations

import pickle
import threading
from typing import Any

import numpy as np
import pytest

from diffuserlab.jsonio import jsonable
from drivers.base import Device
from drivers.camera import Frame, FrameRing
from drivers.errors import (
    CameraTimeoutError,
    DeviceDisconnectedError,
    DeviceError,
    DeviceStateError,
    DeviceTimeoutError,
    DeviceValueError,
    LedArrayTimeoutError,
    SlmTimeoutError,
    StageLimitError,
    StageTimeoutError,
)
from drivers.simulated import SimulatedCamera


def test_error_hierarchy_and_message():
    for cls in (CameraTimeoutError, StageTimeoutError, LedArrayTimeoutError, SlmTimeoutError):
        assert issubclass(cls, DeviceTimeoutError) and issubclass(cls, TimeoutError)
    assert issubclass(DeviceDisconnectedError, ConnectionError)
    assert issubclass(StageLimitError, DeviceError) and issubclass(StageLimitError, ValueError)
    assert issubclass(DeviceStateError, DeviceError)
    exc = StageTimeoutError("stage0", "x did not arrive within 2 s", "check the cable")
    assert str(exc) == "stage0: x did not arrive within 2 s. Fix: check the cable"
    assert (exc.device_id, exc.problem, exc.fix) == ("stage0", "x did not arrive within 2 s",
                                                     "check the cable")
    back = pickle.loads(pickle.dumps(exc))
    assert type(back) is StageTimeoutError and str(back) == str(exc)


def test_jsonable():
    out = jsonable({"a": (1, np.int64(2)), 3: np.arange(2.0), "b": {"c": np.float32(0.5)}})
    assert out == {"a": [1, 2], "3": [0.0, 1.0], "b": {"c": 0.5}}
    assert type(out["a"][1]) is int


class _Minimal(Device):
    kind = "camera"
    _SETTINGS = ("level",)

    def __init__(self, device_id: str, **params: Any) -> None:
        super().__init__(device_id, **params)
        self.calls: list[str] = []

    def _do_open(self, timeout_s):
        self.calls.append("open")
        if self.params.get("absent"):
            raise DeviceDisconnectedError(self.device_id, "no device", "plug it in")

    def _do_close(self):
        self.calls.append("close")
        if self.params.get("close_fails"):
            raise DeviceDisconnectedError(self.device_id, "gone", "nothing")

    def _do_get_info(self):
        if self.params.get("info_fails"):
            raise DeviceTimeoutError(self.device_id, "no info", "retry")
        return {}

    def _do_get_settings(self):
        return {"level": 1}

    def _do_apply(self, name, value):
        self.calls.append(f"{name}={value}")
        return value * 10 if self.params.get("clamp") else None

    def _validate_setting(self, name, value, pending):
        return self._int(name, value, low=0, high=100)


def test_device_id_must_be_a_name():
    for bad in ("", "  ", None, 3):
        with pytest.raises(DeviceValueError):
            _Minimal(bad)


def test_open_failures_leave_the_device_closed():
    dev = _Minimal("d", absent=True)
    with pytest.raises(DeviceDisconnectedError):
        dev.open()
    assert not dev.is_open
    with pytest.raises(DeviceDisconnectedError):  # remembered until a successful open
        dev.settings()
    dev.params["absent"] = False
    dev.open()
    assert dev.is_open and dev.settings() == {"level": 1}
    dev2 = _Minimal("e", info_fails=True)
    with pytest.raises(DeviceTimeoutError):
        dev2.open()
    assert not dev2.is_open and dev2.calls == ["open", "close"]


def test_close_tolerates_a_vanished_device(caplog):
    dev = _Minimal("d", close_fails=True)
    dev.open()
    dev.close()
    assert not dev.is_open and "ignored" in caplog.text


def test_apply_settings_keeps_the_read_back_value():
    dev = _Minimal("d", clamp=True)
    dev.open()
    dev.apply_settings({"level": 3})
    assert dev.settings() == {"level": 30} and dev.calls[-1] == "level=3"
    dev.reconnect()
    assert dev.calls[-1] == "level=30" and dev.settings() == {"level": 300}


def test_reconnect_of_a_never_opened_device_just_opens():
    dev = _Minimal("d")
    dev.reconnect()
    assert dev.is_open and dev.calls == ["open"]


def _frame(i: int) -> Frame:
    return Frame(np.zeros((2, 2), np.uint16), i, float(i), 0.0, 0.01, 0.0, 0)


def test_frame_ring_counts_overwrites_and_latest():
    with pytest.raises(DeviceValueError):
        FrameRing(0)
    with pytest.raises(DeviceValueError):
        FrameRing(2.5)
    ring = FrameRing(3)
    for i in range(5):
        ring.put(_frame(i))
    assert ring.counters() == {"acquired": 5, "read": 0, "skipped": 2, "dropped": 0,
                               "buffered": 3, "capacity": 3}
    assert ring.get(timeout_s=0).index == 2
    ring.mark_dropped(2)
    assert ring.get_latest(timeout_s=0).index == 4  # frame 3 skipped
    assert (ring.acquired, ring.read, ring.skipped, ring.dropped, len(ring)) == (7, 2, 5, 2, 0)
    with pytest.raises(CameraTimeoutError, match="no frame"):
        ring.get(timeout_s=0)
    ring.put(_frame(9))
    ring.clear()
    assert ring.skipped == 6 and len(ring) == 0


def test_frame_ring_reports_producer_errors_after_buffered_frames():
    ring = FrameRing(4)
    ring.put(_frame(0))
    ring.fail(DeviceDisconnectedError("cam0", "link lost", "reconnect"))
    assert ring.get(timeout_s=0).index == 0
    with pytest.raises(DeviceDisconnectedError):
        ring.get(timeout_s=5.0)  # raises at once instead of waiting
    ring.clear()
    with pytest.raises(CameraTimeoutError):
        ring.get(timeout_s=0)


def test_a_failed_ring_read_once_is_freed_without_the_collector():
    """Each reader gets a copy of the stored error: the raised one's traceback holds
    the ring, and the stored one with it would be a cycle (frozen for good in the GUI)."""
    from tests.refcycles import assert_freed_without_the_collector

    held = {"ring": FrameRing(4)}
    held["ring"].fail(DeviceDisconnectedError("cam0", "link lost", "reconnect"))
    for _ in range(2):
        with pytest.raises(DeviceDisconnectedError, match="cam0: link lost") as caught:
            held["ring"].get(timeout_s=0)
        assert caught.value.device_id == "cam0"
    del caught
    assert_freed_without_the_collector(held, "ring", "failed frame ring")


def test_frame_ring_wakes_a_waiting_reader():
    ring = FrameRing(2)
    got = []
    reader = threading.Thread(target=lambda: got.append(ring.get(timeout_s=60.0)))
    reader.start()
    ring.put(_frame(7))
    reader.join(timeout=60.0)  # a hang guard
    assert [f.index for f in got] == [7]


def test_simulated_stream_reports_a_disconnect_to_the_reader():
    cam = SimulatedCamera("cam0", sensor_shape=(8, 8))
    cam.open()
    ring = FrameRing(4)
    cam.start_stream(ring)
    ring.get(timeout_s=30.0)  # a hang guard
    cam.faults.disconnect()
    with pytest.raises(DeviceDisconnectedError):  # not the get's timeout, however late
        ring.get(timeout_s=30.0)  # the grab thread notices
    assert cam.status()["disconnected"] is True
    cam.faults.allow_reconnect()
    cam.reconnect()
    assert not cam.is_streaming


def test_info_is_a_copy_of_the_fixed_properties_and_needs_an_open_device():
    from drivers.errors import DeviceStateError
    from drivers.simulated import SimulatedCamera

    cam = SimulatedCamera("cam", sensor_shape=(8, 10))
    with pytest.raises(DeviceStateError):
        cam.info  # noqa: B018 (the property raises)
    with cam:
        info = cam.info
        lo, hi = info["exposure_range_s"]
        assert 0 < lo < hi and info["sensor_shape"] == [8, 10]
        info["sensor_shape"][0] = 99  # a copy: the device keeps its own
        assert cam.sensor_shape == (8, 10)

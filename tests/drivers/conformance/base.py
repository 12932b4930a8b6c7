"""Conformance checks common to every device kind: lifecycle, settings, timeouts."""

from __future__ import annotations

import json
import math
import time
from typing import Any

import pytest

from drivers.errors import (
    DeviceError,
    DeviceStateError,
    DeviceTimeoutError,
    DeviceValueError,
)


class DeviceConformance:
    """Lifecycle, settings and timeout behaviour common to every kind."""

    kind = ""
    timeout_error: type[DeviceTimeoutError] = DeviceTimeoutError

    # ------------------------------------------------------------- subclass hooks
    def provoke_timeout(self, device) -> None:
        raise NotImplementedError("the test class must implement provoke_timeout(device)")

    def advance_time(self, device, seconds: float) -> None:
        time.sleep(seconds)

    #: Undoes :meth:`wait_lost_reply`, once the call meant to time out has run.
    _undo_lost_reply_wait = None

    def wait_lost_reply(self, device, seconds: float = 1.0) -> None:
        """Wait ``seconds`` for the reply that ``provoke_timeout`` drops.

        The fixtures' reply timeouts are hang guards (30 s: a loaded host answers
        seconds late), too long to wait for a reply that never comes; the driver's
        own timeout is put back after the call that times out.
        """
        before = device._reply_timeout
        device._reply_timeout = seconds
        self._undo_lost_reply_wait = lambda: setattr(device, "_reply_timeout", before)

    # ------------------------------------------------------------- kind hooks
    def use(self, device) -> Any:
        """A public call that needs an open device."""
        raise NotImplementedError

    def blocking_call(self, device) -> Any:
        """A call with a timeout (to be made to time out by provoke_timeout)."""
        raise NotImplementedError

    def changed_settings(self, device) -> dict[str, Any]:
        """Valid settings that differ from the current ones in every name."""
        raise NotImplementedError

    def invalid_settings(self, device) -> list[dict[str, Any]]:
        """Settings dicts that must each be rejected with DeviceValueError."""
        raise NotImplementedError

    def assert_settings_in_effect(self, device, settings: dict[str, Any]) -> None:
        """Check, through the device's behaviour, that ``settings`` are in effect."""

    # ------------------------------------------------------------- tests
    def test_kind_and_id(self, device):
        assert device.kind == self.kind
        assert device.timeout_error is self.timeout_error
        assert isinstance(device.device_id, str) and device.device_id
        assert device.device_id in repr(device)

    def test_open_close_idempotent(self, device):
        assert device.is_open
        device.open()  # no-op
        assert device.is_open
        device.close()
        device.close()
        assert not device.is_open
        device.open()
        device.open()
        assert device.is_open
        self.use(device)

    def test_context_manager(self, device):
        device.close()
        with device as d:
            assert d is device and device.is_open
            self.use(device)
        assert not device.is_open

    def test_use_before_open_raises_state_error(self, device):
        device.close()
        for call in (self.use, lambda d: d.settings(), lambda d: d.apply_settings({})):
            with pytest.raises(DeviceStateError, match=device.device_id) as info:
                call(device)
            assert "open()" in str(info.value) and "Fix:" in str(info.value)
        status = device.status()
        assert status["is_open"] is False and status["kind"] == self.kind

    def test_open_rejects_bad_timeout(self, device):
        device.close()
        for bad in (0, -1.0, math.nan, "5"):
            with pytest.raises(DeviceValueError):
                device.open(timeout_s=bad)
        assert not device.is_open

    def test_settings_json_roundtrip(self, device):
        original = device.settings()
        assert list(original) == list(type(device)._SETTINGS)
        text = json.dumps(original)
        changed = self.changed_settings(device)
        device.apply_settings(changed)
        after = device.settings()
        for name in changed:
            assert after[name] != original[name], name
        device.apply_settings(json.loads(text))
        assert device.settings() == original

    def test_reconnect_reapplies_settings(self, device):
        changed = self.changed_settings(device)
        device.apply_settings(changed)
        before = device.settings()
        device.reconnect()
        assert device.is_open
        assert device.settings() == before
        self.assert_settings_in_effect(device, before)

    def test_reconnect_after_close(self, device):
        device.apply_settings(self.changed_settings(device))
        before = device.settings()
        device.close()
        device.reconnect()
        assert device.settings() == before

    def test_unknown_setting_rejected(self, device):
        before = device.settings()
        with pytest.raises(DeviceValueError, match="unknown settings"):
            device.apply_settings({"no_such_setting": 1})
        with pytest.raises(DeviceValueError):
            device.apply_settings([("a", 1)])
        assert device.settings() == before

    def test_invalid_settings_rejected_atomically(self, device):
        before = device.settings()
        changed = self.changed_settings(device)
        for bad in self.invalid_settings(device):
            # a valid change next to the bad one must not be applied either
            mixed = {**changed, **bad}
            with pytest.raises(DeviceValueError, match=device.device_id) as info:
                device.apply_settings(mixed)
            assert isinstance(info.value, ValueError) and "Fix:" in str(info.value)
            assert device.settings() == before, bad

    def test_status_is_json(self, device):
        status = device.status()
        json.dumps(status)
        assert status["device_id"] == device.device_id
        assert status["is_open"] is True and status["disconnected"] is False

    def test_timeout_raises_kind_error(self, device):
        self.provoke_timeout(device)
        try:
            with pytest.raises(self.timeout_error) as info:
                self.blocking_call(device)
        finally:
            undo, self._undo_lost_reply_wait = self._undo_lost_reply_wait, None
            if undo is not None:
                undo()
        exc = info.value
        assert isinstance(exc, DeviceTimeoutError) and isinstance(exc, TimeoutError)
        assert isinstance(exc, DeviceError) and exc.device_id == device.device_id
        assert "Fix:" in str(exc)
        self.blocking_call(device)  # the device works again afterwards

"""Fault injection for the simulated devices (seeded, on command)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from drivers.errors import DeviceDisconnectedError, DeviceValueError

if TYPE_CHECKING:
    from drivers.base import Device

__all__ = ["CameraFaults", "DeviceFaults", "StageFaults"]


class DeviceFaults:
    """Faults every simulated device accepts, available as ``device.faults``.

    - :meth:`timeout_next`: the next ``n`` blocking calls (camera ``snap``; stage
      moves with ``wait``, ``home``, ``wait_until_idle``; LED ``set_*``/``all_off``;
      SLM ``show_*``) spend their ``timeout_s`` of simulated time and raise the
      device's timeout error without doing anything.
    - :meth:`disconnect`: every call raises ``DeviceDisconnectedError``; ``reconnect()``
      keeps failing until :meth:`allow_reconnect` ("plugged back in").
    """

    def __init__(self, device: Device, seed: int) -> None:
        self._device = device
        self._rng = np.random.default_rng([int(seed), 0xFA])
        self._timeouts = 0
        self.connected = True
        self._reconnect_after: int | None = None

    def timeout_next(self, n: int = 1) -> None:
        """Make the next ``n`` blocking calls time out."""
        self._timeouts += self._count("n", n)

    def disconnect(self) -> None:
        """Unplug the device: every call raises ``DeviceDisconnectedError``."""
        self.connected = False
        self._reconnect_after = None

    def allow_reconnect(self, after_attempts: int = 0) -> None:
        """Plug the device back in: open attempts succeed after ``after_attempts`` failures."""
        self._reconnect_after = self._count("after_attempts", after_attempts)

    def clear(self) -> None:
        """Remove every pending fault (a disconnected device becomes reachable again)."""
        self._timeouts = 0
        if not self.connected:
            self._reconnect_after = 0

    # --------------------------------------------------------------- used by drivers
    def _take_timeout(self) -> bool:
        if self._timeouts > 0:
            self._timeouts -= 1
            return True
        return False

    def _check_connected(self) -> None:
        if not self.connected:
            raise DeviceDisconnectedError(
                self._device.device_id, "simulated disconnection (faults.disconnect())",
                "call faults.allow_reconnect(), then reconnect()",
            )

    def _try_connect(self) -> None:
        if self.connected:
            return
        if self._reconnect_after is None or self._reconnect_after > 0:
            if self._reconnect_after is not None:
                self._reconnect_after -= 1
            self._check_connected()
        self.connected = True

    def _count(self, name: str, n: int) -> int:
        if not isinstance(n, int) or isinstance(n, bool) or n < 0:
            raise DeviceValueError(self._device.device_id, f"faults: {name}={n!r}",
                                   "use an integer >= 0")
        return n


class CameraFaults(DeviceFaults):
    """Camera faults: also :meth:`drop_frames`."""

    def __init__(self, device: Device, seed: int) -> None:
        super().__init__(device, seed)
        self._drop_n = 0
        self._drop_p = 0.0

    def drop_frames(self, n: int | None = None, probability: float | None = None) -> None:
        """Lose the next ``n`` frames, or each frame with ``probability`` (seeded) until
        :meth:`clear`. Lost frames use up frame indices and are counted (camera
        ``dropped_frames``, ring ``skipped``/``dropped``)."""
        if (n is None) == (probability is None):
            raise DeviceValueError(self._device.device_id, "drop_frames needs n or probability",
                                   "pass exactly one of n=... or probability=...")
        if n is not None:
            self._drop_n += self._count("n", n)
        elif not (isinstance(probability, float | int) and 0 <= probability <= 1):
            raise DeviceValueError(self._device.device_id, f"probability={probability!r}",
                                   "use a number in [0, 1]")
        else:
            self._drop_p = float(probability)

    def clear(self) -> None:
        super().clear()
        self._drop_n, self._drop_p = 0, 0.0

    def _take_drop(self) -> bool:
        if self._drop_n > 0:
            self._drop_n -= 1
            return True
        return self._drop_p > 0 and bool(self._rng.random() < self._drop_p)


class StageFaults(DeviceFaults):
    """Stage faults: also :meth:`stick_axis`."""

    def __init__(self, device: Device, seed: int) -> None:
        super().__init__(device, seed)
        self.stuck: set[str] = set()

    def stick_axis(self, axis: str) -> None:
        """Commanded moves and homing of ``axis`` no longer happen: the axis reports
        moving forever, so waits time out (``StageTimeoutError``)."""
        self.stuck.add(axis)

    def unstick_axis(self, axis: str) -> None:
        """Let ``axis`` move again."""
        self.stuck.discard(axis)

    def clear(self) -> None:
        super().clear()
        self.stuck.clear()

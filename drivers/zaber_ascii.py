"""Zaber stage driver: the ASCII protocol, devices and axes daisy-chained on one port.

Protocol (Zaber ASCII protocol manual; notes in docs/drivers/zaber-ascii.md):
commands ``/device axis id command[:CC]\\n``, replies
``@dd a id OK|RJ BUSY|IDLE FLAG data\\r\\n``. Every command carries a message id
(1..99, cycling) and an LRC checksum; replies with another id (late answers to
an earlier, timed-out command) and info/alert lines are skipped. A rejection (``RJ``)
raises :class:`~drivers.errors.DeviceProtocolError` naming the reason (BADDATA,
BADCOMMAND, BADAXIS, ...). Moves reply ``OK BUSY`` at once; the driver polls the
empty command until every axis reports ``IDLE``, then reads the warning flags:
a fault (``F*``), an unexpected limit (``WL``) or an interrupted move (``NI``) raises
:class:`~drivers.errors.StageMotionError` and the flags are cleared. ``WR`` (no
reference position) means not homed: moves are refused until homed
(``require_homed``). Positions are microsteps; ``microstep_size`` converts them.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

from drivers.errors import (
    DeviceDisconnectedError,
    DeviceProtocolError,
    DeviceStateError,
    DeviceValueError,
    StageMotionError,
)
from drivers.stage import AXIS_UNITS, HostTableStage
from drivers.transports import BY_ID_DIR, SerialLink

__all__ = ["FLAG_MEANINGS", "MICROSTEP_SIZE", "ZaberAsciiStage", "lrc"]

#: Default microstep size per axis unit: an X-LSM linear stage (0.047625 um) and an
#: X-RSW rotary stage (0.000234375 deg). Check your product's data sheet.
MICROSTEP_SIZE: dict[str, float] = {"mm": 0.047625e-3, "deg": 0.000234375}
#: Warning flags the driver acts on, with their meaning.
FLAG_MEANINGS: dict[str, str] = {
    "FS": "stalled and stopped", "FE": "limit error", "FQ": "encoder error",
    "FO": "driver disabled", "FD": "driver disabled", "FT": "excessive twist",
    "FM": "motor temperature", "FV": "over/under-voltage", "FH": "hardware emergency stop",
    "FF": "critical system error", "WL": "unexpected limit trigger", "NI": "movement interrupted",
    "WR": "no reference position (not homed)", "WH": "not homed",
}
_REPLY_RE = re.compile(
    r"^@(\d{2}) (\d+)(?: (\d+))? (OK|RJ) (BUSY|IDLE) (\S\S) ?(.*?)(?::([0-9A-F]{2}))?$")


def lrc(text: str) -> str:
    """Zaber's LRC checksum of a message body: the two's complement of the byte sum,
    modulo 256, as two upper-case hex digits (``lrc("01 tools echo") == "8F"``)."""
    total = sum(text.encode("ascii")) & 0xFF
    return f"{((total ^ 0xFF) + 1) & 0xFF:02X}"


class ZaberAsciiStage(HostTableStage):
    """Zaber devices on one serial port, one stage axis per (device, axis).

    Parameters
    ----------
    device_id : str
        Name of the stage.
    axes : sequence of str or Mapping[str, (float, float)]
        Axis names, or names with their travel; by default the travel is read from
        the device (``limit.min``, ``limit.max``).
    port : str, optional
        Serial port (best a ``/dev/serial/by-id/...`` path).
    serial_number : str, optional
        USB serial number of the port's adapter, resolved on every open.
    baudrate : int
        115200 for the ASCII protocol (9600 on old firmware).
    device_numbers : Mapping[str, int]
        ``{axis: device address}`` (1..99, as set by ``renumber``); default 1, 2, ...
    axis_numbers : Mapping[str, int], optional
        ``{axis: axis number on its device}``; default 1.
    microstep_size : float or Mapping[str, float], optional
        Size of one microstep in the axis unit (mm or deg); default
        :data:`MICROSTEP_SIZE`.
    limits_mm, limits_deg : Mapping[str, (float, float)], optional
        Travel per axis (software limits), within the device's limits.
    speed_mm_s, speed_deg_s : float, optional
        Initial velocity (unit/s); default the device's ``maxspeed``.
    max_velocity : float
        Largest velocity allowed, unit/s.
    require_homed, home_on_open : bool
        Refuse moves of an axis showing ``WR``; home such axes at open.
    home_timeout_s : float
        Longest wait for that homing, s (default 120); an open given a ``timeout_s``
        (or a cancel event) ends it sooner.
    reply_timeout_s, poll_s : float
        Longest wait for a reply; polling period while moving.
    checksums : bool
        Send LRC checksums.
    search_dirs : sequence of str
        Link directories searched for ``serial_number``.
    """

    def __init__(
        self, device_id: str, *, axes: Sequence[str] | Mapping[str, Any] = ("x",),
        port: str | None = None, serial_number: str | None = None, baudrate: int = 115200,
        device_numbers: Mapping[str, int] | None = None,
        axis_numbers: Mapping[str, int] | None = None,
        microstep_size: float | Mapping[str, float] | None = None,
        limits_mm: Mapping[str, Sequence[float]] | None = None,
        limits_deg: Mapping[str, Sequence[float]] | None = None,
        speed_mm_s: float | None = None, speed_deg_s: float | None = None,
        max_velocity: float = 20.0, require_homed: bool = True, home_on_open: bool = False,
        home_timeout_s: float = 120.0, reply_timeout_s: float = 1.0, poll_s: float = 0.01,
        checksums: bool = True,
        search_dirs: Sequence[str] = (BY_ID_DIR,),
    ) -> None:
        super().__init__(device_id)
        if isinstance(axes, str) or not isinstance(axes, Mapping | Sequence) or not axes:
            raise self._error(DeviceValueError, f"axes={axes!r} is invalid",
                              'pass axis names, e.g. axes = ["x", "y"]')
        names = list(axes)
        bad = [a for a in names if a not in AXIS_UNITS]
        if bad:
            raise self._error(DeviceValueError, f"axis names {bad} are not supported",
                              f"use names from {list(AXIS_UNITS)}")
        limits = {**dict(limits_mm or {}), **dict(limits_deg or {})}
        if isinstance(axes, Mapping):
            limits.update(axes)
        devs = dict(device_numbers or {a: i + 1 for i, a in enumerate(names)})
        nums = dict(axis_numbers or {})
        self._addr: dict[str, tuple[int, int]] = {}
        for a in names:
            if a not in devs:
                raise self._error(DeviceValueError, f"axis {a!r} has no device number",
                                  f"add it to device_numbers, e.g. {{ {a} = 1 }}")
            self._addr[a] = (self._int(f"device_numbers[{a}]", devs[a], low=1, high=99),
                             self._int(f"axis_numbers[{a}]", nums.get(a, 1), low=1, high=9))
        if len(set(self._addr.values())) != len(self._addr):
            raise self._error(DeviceValueError, "two axes share one device and axis number",
                              "give each axis its own (device_numbers, axis_numbers)")
        size = microstep_size if isinstance(microstep_size, Mapping) else dict.fromkeys(
            names, microstep_size)
        self._step = {a: self._float(f"microstep_size[{a}]",
                                     size.get(a) or MICROSTEP_SIZE[AXIS_UNITS[a]],
                                     low=0.0, low_open=True) for a in names}
        self._limits_param = {a: tuple(limits[a]) for a in names if a in limits}
        self._vmax = self._float("max_velocity", max_velocity, low=0.0, low_open=True)
        self._speed = {a: (speed_deg_s if AXIS_UNITS[a] == "deg" else speed_mm_s) for a in names}
        self.require_homed, self.home_on_open = bool(require_homed), bool(home_on_open)
        self._home_timeout = self._float("home_timeout_s", home_timeout_s, low=0.0,
                                         low_open=True)
        self._reply_timeout = self._float("reply_timeout_s", reply_timeout_s, low=0.0,
                                          low_open=True)
        self._poll = self._float("poll_s", poll_s, low=0.0, low_open=True, high=1.0)
        self._checksums = bool(checksums)
        self._link = SerialLink(device_id, port=port, serial_number=serial_number,
                                search_dirs=search_dirs, baudrate=baudrate,
                                timeout_error=self.timeout_error)
        self._msg_id = 0
        self._command_lock = threading.RLock()
        self._travel: dict[str, tuple[float, float]] = {}
        self._hw: dict[str, Any] = {}
        self._moving: set[str] = set()  # axes the last move/home started

    # ----------------------------------------------------------- protocol
    def command(self, device: int, axis: int, text: str = "") -> tuple[str, str, str]:
        """Send one command and return ``(status, flag, data)`` of its reply.

        Parameters
        ----------
        device, axis : int
            Address (device 1..99; axis 0 = the whole device).
        text : str
            The command (``"move abs 1000"``; empty for a status poll).

        Raises
        ------
        DeviceProtocolError
            The device rejected the command (``RJ``); the message names the reason.
        StageTimeoutError
            No reply within ``reply_timeout_s``.

        Notes
        -----
        Safe from several threads: one command and its reply at a time on the port
        (another thread's ``discard_input`` or read would otherwise take this reply).
        """
        with self._command_lock:
            return self._exchange(device, axis, text)

    def _exchange(self, device: int, axis: int, text: str) -> tuple[str, str, str]:
        self._msg_id = self._msg_id % 99 + 1
        body = f"{device} {axis} {self._msg_id}" + (f" {text}" if text else "")
        line = f"/{body}:{lrc(body)}\n" if self._checksums else f"/{body}\n"
        self._link.discard_input()
        self._link.write(line.encode("ascii"))
        deadline = time.monotonic() + self._reply_timeout
        while True:
            left = max(deadline - time.monotonic(), 1e-3)
            raw = self._link.read_until(b"\n", left, what=f"reply to {line.strip()!r}")
            text_line = raw.decode("ascii", "replace").strip()
            text_line = text_line[max(text_line.rfind("@"), 0):]  # noise before a reply
            m = _REPLY_RE.match(text_line)
            if m is None:  # an info (#) or alert (!) line, or noise
                continue
            dev, ax, mid, result, status, flag, data, cc = m.groups()
            if (int(dev), int(ax)) != (device, axis) or mid is None or int(mid) != self._msg_id:
                continue  # a late reply to an earlier command
            if cc is not None and cc != lrc(text_line[1:text_line.rindex(":")]):
                raise self._error(DeviceProtocolError, f"reply {text_line!r} fails its checksum",
                                  "check the cable and the baud rate")
            if result == "RJ":
                raise self._error(
                    DeviceProtocolError,
                    f"device {device} axis {axis} rejected {text!r}: {data.strip()} "
                    f"(flag {flag})", _REJECTION_FIX.get(data.strip(), "check the command"))
            return status, flag, data.strip()

    def _axis_cmd(self, axis: str, text: str = "") -> tuple[str, str, str]:
        return self.command(*self._addr[axis], text)

    # ----------------------------------------------------------- lifecycle hooks
    def _do_open(self, timeout_s: float) -> None:
        self._moving = set()
        self._link.open()
        try:
            travel = {}
            for a in self._addr:
                lo = int(self._axis_cmd(a, "get limit.min")[2]) * self._step[a]
                hi = int(self._axis_cmd(a, "get limit.max")[2]) * self._step[a]
                if a in self._limits_param:
                    plo, phi = (self._float(f"{a} limit", v) for v in self._limits_param[a])
                    if not lo - 1e-9 <= plo < phi <= hi + 1e-9:
                        raise self._error(
                            DeviceValueError, f"limits of {a} ({plo}, {phi}) exceed the "
                            f"device's travel ({lo:g}, {hi:g})", "narrow limits_mm/limits_deg")
                    lo, hi = plo, phi
                travel[a] = (lo, hi)
            self._travel = travel
            velocity = {}
            for a in self._addr:
                v = self._speed[a]
                if v is None:
                    v = min(int(self._axis_cmd(a, "get maxspeed")[2]) / 1.6384 * self._step[a],
                            self._vmax)
                velocity[a] = self._float(f"speed of {a}", v, low=0.0, low_open=True,
                                          high=self._vmax)
                self._send_velocity(a, velocity[a])
            self._hw = {"limits": dict(travel), "velocity": velocity,
                        "backlash": dict.fromkeys(travel, 0.0)}
            if self.home_on_open:
                todo = tuple(a for a in self._addr if "WR" in self._warnings(a))
                if todo:
                    self._do_home(todo)
                    self._wait_homing_at_open(self._home_timeout)
        except BaseException:
            self._link.close()
            raise

    def _do_close(self) -> None:
        self._link.close()

    def _do_check_connection(self) -> None:
        if not self._link.is_open:
            raise self._error(DeviceDisconnectedError, f"serial port {self._link.path} is "
                              "closed (the device went away)", "call reconnect()")
        self._link.check_hangup()

    def _send_velocity(self, axis: str, velocity: float) -> None:
        data = max(1, round(velocity / self._step[axis] * 1.6384))
        self._axis_cmd(axis, f"set maxspeed {data}")
        back = int(self._axis_cmd(axis, "get maxspeed")[2])
        if back != data:
            raise self._error(DeviceProtocolError, f"axis {axis}: maxspeed read back as {back}, "
                              f"sent {data}", "check the device's speed limits")

    # ----------------------------------------------------------- motion hooks
    def _warnings(self, axis: str) -> list[str]:
        data = self._axis_cmd(axis, "warnings")[2].split()
        return data[1:]

    def _do_move(self, targets: dict[str, float]) -> None:
        if self.require_homed:
            for a in targets:
                if "WR" in self._warnings(a):
                    raise self._error(DeviceStateError,
                                      f"axis {a} is not homed (flag WR: no reference position)",
                                      "home it first (stage.home()), or set home_on_open = true")
        for a in targets:
            self._axis_cmd(a, "warnings clear")  # stale flags of earlier operations
        for a, t in targets.items():
            self._moving.add(a)
            _, flag, _ = self._axis_cmd(a, f"move abs {round(t / self._step[a])}")
            if flag == "NI":  # this move replaced a running one: expected, not a fault
                self._axis_cmd(a, "warnings clear")

    def _do_home(self, axes: tuple[str, ...]) -> None:
        for a in axes:
            self._moving.add(a)
            self._axis_cmd(a, "warnings clear")
            self._axis_cmd(a, "home")

    def _do_is_moving(self) -> bool:
        return any(self._axis_cmd(a)[0] == "BUSY" for a in self._addr)

    def _do_positions(self) -> dict[str, float]:
        return self._do_positions_of(tuple(self._addr))

    def _do_positions_of(self, axes: tuple[str, ...]) -> dict[str, float]:
        return {a: int(self._axis_cmd(a, "get pos")[2].split()[0]) * self._step[a]
                for a in axes}

    def _do_stop(self) -> None:
        """Stop every axis; an axis that does not answer does not keep the others moving."""
        failed = None
        for a in self._addr:
            try:
                self._axis_cmd(a, "stop")
            except (self.timeout_error, DeviceProtocolError) as exc:
                failed = failed or exc
        self._moving.clear()
        if failed is not None:
            raise failed

    def _do_wait(self, timeout_s: float) -> bool:
        """Wait for the axes the last move or home started (all axes when none did)."""
        deadline = time.monotonic() + timeout_s
        watched = sorted(self._moving) or list(self._addr)
        pending = set(watched)
        while pending:
            pending = {a for a in pending if self._axis_cmd(a)[0] == "BUSY"}
            if not pending:
                break
            if time.monotonic() >= deadline:
                return False
            time.sleep(min(self._poll, max(deadline - time.monotonic(), 0.0)))
        self._moving.clear()
        problems = []
        for a in watched:
            flags = [f for f in self._warnings(a) if f[0] == "F" or f in ("WL", "NI")]
            if flags:
                problems.append(f"axis {a}: " + ", ".join(
                    f"{f} ({FLAG_MEANINGS.get(f, 'see the Zaber manual')})" for f in flags)
                    + f" at {self._do_positions_of((a,))[a]:.6g} {AXIS_UNITS[a]}")
                self._axis_cmd(a, "warnings clear")
        if problems:
            raise self._error(StageMotionError, "; ".join(problems),
                              "check the travel and for obstructions; the stage is idle")
        return True

    def _do_status(self) -> dict[str, Any]:
        out = super()._do_status()
        out["warnings"] = {a: self._warnings(a) for a in self._addr}
        out["port"] = self._link.path
        return out


_REJECTION_FIX = {
    "BADDATA": "the value is out of range or malformed: check the limits and units",
    "BADCOMMAND": "the device does not know this command or setting: check its firmware",
    "BADAXIS": "the device has no such axis: check axis_numbers",
    "DEVICEONLY": "send this command to axis 0",
    "AGAIN": "retry the command",
    "STATUSBUSY": "wait until the device is idle",
    "PARKED": "unpark the device (tools parking unpark)",
    "DRIVERDISABLED": "enable the driver (driver enable) and check its power",
}

"""Emulator of a chain of Zaber devices speaking the ASCII protocol, on a pty.

Written from the Zaber ASCII protocol as summarised in hardware-protocols.md,
section 1b, and its emulator spec:

- commands ``/[device] [axis] [message-id] command [args][:CC]`` ended by CR, LF or
  CRLF; device 0 (or none) addresses every device, which all reply; axis 0 the whole
  device; the optional LRC checksum is verified (a mismatch is rejected);
- one reply per addressed device, ``@dd a [id ]OK|RJ BUSY|IDLE FLAG data\\r\\n``,
  with the highest-priority warning flag (faults F* > warnings W* > notices N*);
- ``move abs|rel|min|max`` replies ``OK BUSY`` at once and the axis moves on a
  trapezoid from ``maxspeed`` and ``accel`` (time-scaled); the empty command returns
  the live status; ``home`` clears ``WR`` when it completes; a move replacing a
  running one raises ``NI``; ``!dd a IDLE --`` alerts when ``comm.alert`` is 1;
- rejections: BADCOMMAND (unknown command or setting), BADDATA (out of range,
  not a number, bad checksum), BADAXIS (no such axis);
- speed limit: ``set maxspeed`` and ``move vel`` above the axis's limit are rejected
  (BADDATA), as the template's emulator refuses a ``VEL`` above its limit; the limit is
  the range Zaber's ASCII manual gives ``maxspeed`` (1 .. resolution x 16384, 1 048 576
  at the default 64 microsteps a step) unless the device's ``speed_limit`` sets a
  stage's own;
- faults: :meth:`stall` (``FS``), :meth:`set_limit_switch` (an unexpected limit:
  ``WL``), :meth:`silence` (a device that no longer answers), :meth:`drop_replies`,
  :meth:`unplug` / :meth:`replug`.

Positions are microsteps; speed in data units (microsteps/s x 1.6384), acceleration
in microsteps/s² x 1.6384 / 10000.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from drivers.emulators._motion import Motion
from drivers.emulators._pty import PtyEmulator, take_lines
from drivers.zaber_ascii import lrc  # the checksum is tested on its documented example

__all__ = ["ZaberAxis", "ZaberEmulator"]

_FLAG_ORDER = "FNW"  # F* before W* before N*: faults, warnings, notices
_FLAG_RANK = {"F": 0, "W": 1, "N": 2}


@dataclass
class ZaberAxis:
    """One axis: position and settings in microsteps / data units, flags, motion."""

    limit_min: int = 0
    limit_max: int = 1_066_666  # 50.8 mm of an X-LSM050 at 0.047625 um per microstep
    maxspeed: int = 153_600
    accel: int = 205
    resolution: int = 64
    position: float = 0.0
    flags: set[str] = field(default_factory=lambda: {"WR"})
    motion: Motion | None = None
    limit_switch: int | None = None
    speed_limit: int | None = None  # data units; None: resolution x 16384

    @property
    def max_speed(self) -> int:
        """The largest ``maxspeed`` (and ``move vel`` speed) accepted, data units."""
        return self.resolution * 16384 if self.speed_limit is None else self.speed_limit


class ZaberEmulator(PtyEmulator):
    """Zaber devices daisy-chained on one port.

    Parameters
    ----------
    devices : Mapping[int, int] or Mapping[int, Mapping]
        ``{address: number of axes}`` or ``{address: {"axes": n, "limit_max": ...,
        "speed_limit": ..., "device_id": ..., "serial": ...}}``; default one single-axis
        device at 1 (``speed_limit``: the largest ``maxspeed``, data units).
    link, time_scale : see :class:`PtyEmulator`.
    """

    def __init__(self, devices=None, *, link: str | Path | None = None,
                 time_scale: float = 1.0) -> None:
        super().__init__(link=link, time_scale=time_scale)
        self.devices: dict[int, dict] = {}
        for addr, spec in (devices or {1: 1}).items():
            spec = {"axes": spec} if isinstance(spec, int) else dict(spec)
            axis_kw = {k: spec[k] for k in ("limit_min", "limit_max", "maxspeed", "speed_limit")
                       if k in spec}
            self.devices[int(addr)] = {
                "axes": [ZaberAxis(**axis_kw) for _ in range(int(spec.get("axes", 1)))],
                "device_id": int(spec.get("device_id", 50081)),
                "peripheral_id": int(spec.get("peripheral_id", 0)),
                "serial": int(spec.get("serial", 33000 + int(addr))),
                "alert": 0, "silent": False,
            }
        self._line = bytearray()
        self.commands: list[str] = []

    # ------------------------------------------------------------------ faults
    def axis(self, device: int = 1, axis: int = 1) -> ZaberAxis:
        """The model of one axis (hold :attr:`lock` while changing it)."""
        return self.devices[device]["axes"][axis - 1]

    def stall(self, device: int = 1, axis: int = 1) -> None:
        """The axis stalls now: it stops where it is with fault ``FS``."""
        with self.lock:
            ax = self.axis(device, axis)
            if ax.motion is not None:
                ax.position = ax.motion.position(self.now())
                ax.motion = None
                self._alert(device, axis)
            ax.flags.add("FS")

    def set_limit_switch(self, microsteps: int | None, device: int = 1, axis: int = 1) -> None:
        """An unexpected limit at ``microsteps`` (None removes it): moves across it stop
        there with ``WL``."""
        with self.lock:
            self.axis(device, axis).limit_switch = None if microsteps is None else int(microsteps)

    def silence(self, device: int, silent: bool = True) -> None:
        """Make a device stop answering (a broken link in the chain)."""
        with self.lock:
            self.devices[device]["silent"] = silent

    # ------------------------------------------------------------------ parsing
    def on_replug(self) -> None:
        """A new USB connection: bytes of a message cut by the unplug are gone."""
        self._line.clear()

    def on_bytes(self, data: bytes) -> None:
        self._line += data
        for raw in take_lines(self._line):
            if raw.startswith("/"):
                self.commands.append(raw)
                self._command(raw[1:])

    def _command(self, body: str) -> None:
        checksum_ok = True
        if ":" in body:
            body, cc = body.rsplit(":", 1)
            checksum_ok = cc.strip().upper() == lrc(body)
        tokens = body.split()
        nums = []
        while tokens and len(nums) < 3 and re.fullmatch(r"\d+", tokens[0]):
            nums.append(int(tokens.pop(0)))
        device, axis = (nums + [0, 0])[:2]
        msg_id = nums[2] if len(nums) > 2 else None
        targets = sorted(self.devices) if device == 0 else [device]
        for addr in targets:
            dev = self.devices.get(addr)
            if dev is None or dev["silent"]:
                continue
            reply = self._execute(addr, axis, tokens) if checksum_ok else ("RJ", "BADDATA")
            self._reply(addr, axis, msg_id, *reply)

    def _status_of(self, addr: int, axis: int) -> tuple[str, str]:
        every = self.devices[addr]["axes"]
        axes = every if not 0 < axis <= len(every) else [self.axis(addr, axis)]
        busy = any(a.motion is not None for a in axes)
        flags = set().union(*(a.flags for a in axes))
        flag = min(flags, key=lambda f: (_FLAG_RANK.get(f[0], 3), f)) if flags else "--"
        return ("BUSY" if busy else "IDLE"), flag

    def _reply(self, addr: int, axis: int, msg_id: int | None, result: str, data: str) -> None:
        busy, flag = self._status_of(addr, axis)
        ident = "" if msg_id is None else f" {msg_id}"
        self.reply(f"@{addr:02d} {axis}{ident} {result} {busy} {flag} {data}\r\n".encode())

    def _alert(self, addr: int, axis: int) -> None:
        if self.devices[addr]["alert"]:
            busy, flag = self._status_of(addr, axis)
            self.emit(f"!{addr:02d} {axis} {busy} {flag}\r\n".encode())

    # ------------------------------------------------------------------ commands
    def _execute(self, addr: int, axis: int, tokens: list[str]) -> tuple[str, str]:
        dev = self.devices[addr]
        if axis > len(dev["axes"]):
            return "RJ", "BADAXIS"
        axes = list(range(1, len(dev["axes"]) + 1)) if axis == 0 else [axis]
        now = self.now()
        for a in axes:
            self._advance(addr, a, now)
        if not tokens:
            return "OK", "0"
        verb, args = tokens[0], tokens[1:]
        if verb == "home":
            for a in axes:
                self._start(addr, a, now, float(self.axis(addr, a).limit_min), "home")
            return "OK", "0"
        if verb == "move" and args:
            return self._move(addr, axes, now, args)
        if verb in ("stop", "estop"):
            for a in axes:
                ax = self.axis(addr, a)
                if ax.motion is not None:
                    ax.position, ax.motion = ax.motion.position(now), None
                    self._alert(addr, a)
            return "OK", "0"
        if verb == "get" and len(args) == 1:
            return self._get(addr, axes, args[0])
        if verb == "set" and len(args) == 2:
            return self._set(addr, axes, args[0], args[1])
        if verb == "tools" and args[:1] == ["echo"]:
            return "OK", " ".join(args[1:]) or "0"
        if verb == "system" and args == ["reset"]:
            for a in range(1, len(dev["axes"]) + 1):
                ax = self.axis(addr, a)
                ax.motion = None
                ax.flags = {"WR"}
            return "OK", "0"
        if verb == "warnings":
            flags = sorted(set().union(*(self.axis(addr, a).flags for a in axes)))
            if args == ["clear"]:
                for a in axes:
                    self.axis(addr, a).flags -= {f for f in flags if f != "WR"}
            elif args:
                return "RJ", "BADDATA"
            return "OK", " ".join([f"{len(flags):02d}", *flags])
        return "RJ", "BADCOMMAND"

    def _move(self, addr: int, axes: list[int], now: float, args: list[str]) -> tuple[str, str]:
        mode = args[0]
        for a in axes:
            ax = self.axis(addr, a)
            if mode == "vel" and len(args) == 2 and re.fullmatch(r"-?\d+", args[1]):
                speed = int(args[1])
                if abs(speed) > min(ax.maxspeed, ax.max_speed):
                    return "RJ", "BADDATA"
                if speed == 0:
                    if ax.motion is not None:
                        ax.position, ax.motion = ax.motion.position(now), None
                    continue
                self._start(addr, a, now, float(ax.limit_max if speed > 0 else ax.limit_min),
                            "vel", speed=abs(speed))
                continue
            if mode in ("min", "max") and len(args) == 1:
                target = ax.limit_min if mode == "min" else ax.limit_max
            elif mode in ("abs", "rel") and len(args) == 2 and re.fullmatch(r"-?\d+", args[1]):
                n = int(args[1])
                cur = ax.motion.position(now) if ax.motion else ax.position
                target = n if mode == "abs" else round(cur) + n
                if not ax.limit_min <= target <= ax.limit_max:
                    return "RJ", "BADDATA"
            elif mode in ("abs", "rel", "min", "max", "vel"):
                return "RJ", "BADDATA"
            else:
                return "RJ", "BADCOMMAND"
            self._start(addr, a, now, float(target), "move")
        return "OK", "0"

    _SETTINGS = {"pos", "maxspeed", "accel", "limit.min", "limit.max", "resolution",
                 "encoder.pos"}

    def _get(self, addr: int, axes: list[int], name: str) -> tuple[str, str]:
        dev = self.devices[addr]
        if name in ("device.id", "deviceid"):
            return "OK", str(dev["device_id"])
        if name == "system.axiscount":
            return "OK", str(len(dev["axes"]))
        if name == "comm.packet.size.max":
            return "OK", "80"
        if name == "peripheralid":
            return "OK", " ".join(str(dev["peripheral_id"]) for _ in axes)
        if name == "system.serial":
            return "OK", str(dev["serial"])
        if name == "version":
            return "OK", "7.38"
        if name == "comm.alert":
            return "OK", str(dev["alert"])
        if name not in self._SETTINGS:
            return "RJ", "BADCOMMAND"
        attr = {"limit.min": "limit_min", "limit.max": "limit_max", "encoder.pos": "position",
                "pos": "position"}.get(name, name)
        return "OK", " ".join(str(round(getattr(self.axis(addr, a), attr))) for a in axes)

    def _set(self, addr: int, axes: list[int], name: str, value: str) -> tuple[str, str]:
        if not re.fullmatch(r"-?\d+", value):
            return "RJ", "BADDATA"
        v = int(value)
        if name == "comm.alert":
            if v not in (0, 1):
                return "RJ", "BADDATA"
            self.devices[addr]["alert"] = v
            return "OK", "0"
        attr = {"limit.min": "limit_min", "limit.max": "limit_max", "pos": "position"}.get(
            name, name)
        if name not in self._SETTINGS or name == "encoder.pos":
            return "RJ", "BADCOMMAND"
        if name in ("maxspeed", "accel", "resolution") and v <= 0:
            return "RJ", "BADDATA"
        if name == "maxspeed" and any(v > self.axis(addr, a).max_speed for a in axes):
            return "RJ", "BADDATA"  # above the stage's speed limit
        for a in axes:
            setattr(self.axis(addr, a), attr, float(v) if attr == "position" else v)
        return "OK", "0"

    # ------------------------------------------------------------------ motion
    def _start(self, addr: int, axis: int, now: float, target: float, kind: str,
               speed: int | None = None) -> None:
        ax = self.axis(addr, axis)
        if ax.motion is not None:
            ax.position = ax.motion.position(now)
            ax.flags.add("NI")  # the running move was interrupted
        ax.flags.discard("FS")
        ax.flags.discard("WL")
        speed = (speed or ax.maxspeed) / 1.6384
        accel = ax.accel * 10000 / 1.6384
        ax.motion = Motion(now, ax.position, target, speed, accel, kind)

    def _advance(self, addr: int, axis: int, now: float) -> None:
        ax = self.axis(addr, axis)
        m = ax.motion
        if m is None:
            return
        pos = m.position(now)
        sw = ax.limit_switch
        if sw is not None and m.kind != "home" and ((m.p0 < sw <= pos) or (pos <= sw < m.p0)):
            ax.position, ax.motion = float(sw), None
            ax.flags.add("WL")
            self._alert(addr, axis)
            return
        if not m.done(now):
            ax.position = pos
            return
        ax.position, ax.motion = m.p1, None
        if m.kind == "home":
            ax.flags.discard("WR")
            ax.position = float(ax.limit_min)
        self._alert(addr, axis)

    def on_tick(self, now: float) -> None:
        for addr, dev in self.devices.items():
            for i in range(len(dev["axes"])):
                self._advance(addr, i + 1, now)

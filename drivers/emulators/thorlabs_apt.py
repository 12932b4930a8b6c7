"""Emulator of a Thorlabs APT motion controller (KDC101, KST101 or BSC20x) on a pty.

Written from the APT host-controller protocol as summarised in
hardware-protocols.md, section 1a, and its emulator spec:

- framing: a 6-byte header (message id u16 LE, param1, param2, dest, source); bit 7
  of dest set means a data packet of ``param1 | param2 << 8`` bytes follows; bytes that
  do not start a plausible header are skipped one at a time (resync);
- REQ -> GET replies with their exact lengths (GET_STATUSUPDATE of the stepper
  profiles carries 28 bytes, as in the 2025 document, so a driver must frame by the
  header's length); SET and MOVE messages are silent; MOVE_COMPLETED, MOVE_HOMED and
  MOVE_STOPPED arrive when the (time-scaled, trapezoidal) motion ends, interleaved
  with any reply;
- status updates every ``update_period_s`` after START_UPDATEMSGS, silenced after 50
  without an ACK (KDC101, KST101) or 5 s whatever the ACKs (BSC20x);
- a channel that is disabled ignores moves; a BSC20x powers up disabled with tiny
  velocities (the "stuck" quirk); moves beyond the travel, or across an injected
  limit switch, stop at the switch with the limit bit set and MOVE_STOPPED;
- the messages third-party clients send (thorlabs-apt-device, pylablib): jog
  parameters and MOVE_JOG (single step or continuous, jog status bits), MOVE_VELOCITY
  (to the end of the travel), direction 1 forward to larger counts and 2 reverse, as
  the protocol document defines them (both clients' KDC101 defaults take them the other
  way: docs/drivers/thorlabs-apt.md), power, limit-switch and trigger parameters (stored and
  read back); messages the model does not know are ignored without a reply, as a
  controller does (listed in :attr:`AptEmulator.unknown`);
- HW_GET_INFO carries the model string (``model`` overrides the profile's, e.g. a
  legacy "BSC103") and, for a KDC101, the stage id in bytes 76-77 (``stage_id``);
  ``velocity_quantum`` rounds stored velocities as a controller may;
- speed limit: a SET_VELPARAMS (or jog parameters) whose maximum velocity exceeds the
  stage's limit (``max_velocity`` units/s, default the profile's: 2.6 mm/s for a
  KDC101 with its Z8 actuator, 5 for the steppers) is clamped to it, as Thorlabs
  controllers keep a stage within its limit (the value read back shows it; a real unit
  should confirm clamping against ignoring);
- faults: :meth:`drop_replies`, :meth:`stall`, :meth:`set_limit_switch`,
  :meth:`rich_response`, :meth:`garbage`, :meth:`unplug` / :meth:`replug`.

The emulator works in encoder counts / microsteps only: it knows nothing about
millimetres, so a driver's counts-per-mm constant is checked, not mirrored.
"""

from __future__ import annotations

import logging
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

from drivers.emulators._motion import Motion
from drivers.emulators._pty import PtyEmulator

__all__ = ["PROFILES", "AptChannel", "AptEmulator"]

log = logging.getLogger("drivers.emulators.apt")

HOST = 0x01
RACK = 0x11
USB_UNIT = 0x50
_T_DC = 2048 / 6e6  # DC servo velocity time unit, s

#: Controller profiles: model string, serial prefix, stepper or DC, channel endpoints.
PROFILES: dict[str, dict] = {
    "kdc101": {"model": "KDC101", "serial": 27000001, "stepper": False, "hw_type": 16,
               "enabled": True, "acks": True, "max_velocity": 2.6},
    "kst101": {"model": "KST101", "serial": 26000001, "stepper": True, "hw_type": 16,
               "enabled": True, "acks": True, "max_velocity": 5.0},
    "bsc20x": {"model": "BSC203", "serial": 70000001, "stepper": True, "hw_type": 44,
               "enabled": False, "acks": False, "max_velocity": 5.0},
}

# status bits
FWD_LIMIT, REV_LIMIT = 0x1, 0x2
MOVING_FWD, MOVING_REV = 0x10, 0x20
JOG_FWD, JOG_REV = 0x40, 0x80
MOTOR_CONNECTED, HOMING, HOMED = 0x100, 0x200, 0x400
ENABLED = 0x80000000


@dataclass
class AptChannel:
    """The state of one channel (a K-cube's motor, or one bay of a BSC20x)."""

    address: int
    travel: tuple[int, int]
    enabled: bool
    velocity: tuple[int, int, int]  # min, accel, max (device units)
    position: float = 0.0
    homed: bool = False
    home_params: tuple[int, int, int, int] = (2, 1, 0, 0)  # dir, switch, velocity, offset
    rel_distance: int = 0
    abs_position: int = 0
    backlash: int = 0
    motion: Motion | None = None
    limit_switch: int | None = None
    limit_hit: int = 0
    stalled: bool = False
    end_offset: int = 0  # a servo settling this many counts off its target
    end_messages: bool = True
    jog: tuple[int, ...] = (2, 0, 0, 0, 0, 2)  # mode, step, vmin, accel, vmax, stop mode
    power: tuple[int, int] = (10, 30)  # rest factor, move factor
    limit_params: bytes = field(default=struct.pack("<HHiiH", 2, 2, 0, 0, 1))
    trigger: bytes = field(default=bytes(20))
    trigger_mode: int = 0


class AptEmulator(PtyEmulator):
    """A Thorlabs APT controller: one K-cube channel or a BSC20x with ``channels`` bays.

    Parameters
    ----------
    profile : str
        "kdc101" (DC servo, USTATUSUPDATE 0x0491), "kst101" or "bsc20x" (stepper,
        STATUSUPDATE 0x0481 with 28 data bytes).
    serial_number : int, optional
        Default: the profile's (27000001, 26000001, 70000001).
    channels : int
        Bays of a BSC20x (endpoints 0x21, 0x22, ...); K-cubes have one (0x50).
    travel_counts : (int, int)
        Travel of every channel in counts.
    counts_per_unit : float
        Only used to pick plausible power-up velocities (2 units/s, 1.5 units/s²) and
        the speed limit (``max_velocity``) in counts.
    update_period_s : float
        Period of the status updates, real seconds (100 ms on the hardware).
    model : str, optional
        Model string of HW_GET_INFO (default the profile's: KDC101, KST101, BSC203).
    stage_id : int
        Stage id a KDC101 reports in HW_GET_INFO bytes 76-77 (6 = PRM1-Z8, 0 none).
    velocity_quantum : int
        Stored velocities are rounded to a multiple of this (controller units).
    max_velocity : float, optional
        The stage's speed limit, units/s (with ``counts_per_unit``); a larger maximum
        velocity sent is clamped to it. Default: the profile's (2.6 KDC101, 5 steppers).
    link, time_scale : see :class:`PtyEmulator`.
    """

    def __init__(
        self, profile: str = "kdc101", *, serial_number: int | None = None, channels: int = 1,
        travel_counts: tuple[int, int] = (0, 863874), counts_per_unit: float = 34554.96,
        update_period_s: float = 0.1, model: str | None = None, stage_id: int = 0,
        velocity_quantum: int = 1, max_velocity: float | None = None,
        link: str | Path | None = None, time_scale: float = 1.0,
    ) -> None:
        super().__init__(link=link, time_scale=time_scale)
        if profile not in PROFILES:
            raise ValueError(f"unknown APT profile {profile!r}; use one of {list(PROFILES)}")
        self.profile = profile
        self.spec = PROFILES[profile]
        self.serial_number = int(serial_number or self.spec["serial"])
        self.model = str(model or self.spec["model"])
        self.stage_id = int(stage_id)
        self.velocity_quantum = max(1, int(velocity_quantum))
        self.stepper = self.spec["stepper"]
        self.max_velocity = float(max_velocity or self.spec["max_velocity"])
        #: The speed limit in device units (the largest maximum velocity stored).
        self.max_velocity_units = self.velocity_units(self.max_velocity * counts_per_unit,
                                                      1.0)[0]
        self.update_period_s = float(update_period_s)
        bay = profile == "bsc20x"
        addresses = [0x21 + i for i in range(channels)] if bay else [USB_UNIT]
        if self.spec["enabled"]:
            vel = self.velocity_units(2.0 * counts_per_unit, 1.5 * counts_per_unit)
        else:  # BSC20x power-up: tiny velocity and acceleration (the "stuck" quirk)
            vel = self.velocity_units(1.0, 1.0)
        self.channels = {
            a: AptChannel(a, tuple(int(v) for v in travel_counts), self.spec["enabled"],
                          (0, vel[1], vel[0]))
            for a in addresses
        }
        self._rx = bytearray()
        self.updates_on = False
        self._updates_since_ack = 0
        self._updates_started = 0.0
        self._next_update = 0.0
        self.acks = 0
        self.updates_sent = 0  # periodic status updates sent (of every channel at once)
        self.resyncs = 0
        self.unknown: list[int] = []

    # ------------------------------------------------------------------ units
    def velocity_units(self, counts_per_s: float, counts_per_s2: float) -> tuple[int, int]:
        """(velocity, acceleration) in this controller's device units."""
        if self.stepper:
            return round(counts_per_s * 53.68), max(1, round(counts_per_s2 / 90.9))
        return (round(counts_per_s * _T_DC * 65536),
                max(1, round(counts_per_s2 * _T_DC * _T_DC * 65536)))

    def counts_per_s(self, vel_units: int, acc_units: int) -> tuple[float, float]:
        """Inverse of :meth:`velocity_units`: counts/s and counts/s²."""
        if self.stepper:
            return vel_units / 53.68, acc_units * 90.9
        return vel_units / (_T_DC * 65536), acc_units / (_T_DC * _T_DC * 65536)

    # ------------------------------------------------------------------ faults
    def stall(self, address: int | None = None, stalled: bool = True) -> None:
        """Make a channel's moves never progress (its moving bits stay on)."""
        with self.lock:
            self._channel(address).stalled = stalled

    def set_limit_switch(self, counts: int | None, address: int | None = None) -> None:
        """Put a limit switch at ``counts`` (None removes it): a move across it stops there."""
        with self.lock:
            self._channel(address).limit_switch = None if counts is None else int(counts)

    def rich_response(self, code: int, notes: str, address: int | None = None) -> None:
        """Send a spontaneous MGMSG_HW_RICHRESPONSE (0x0081) with ``code`` and ``notes``."""
        with self.lock:
            data = struct.pack("<HH", 0, code) + notes.encode()[:63].ljust(64, b"\0")
            self.emit(self._data_msg(0x0081, data, self._channel(address).address))

    def garbage(self, data: bytes = b"\xff\x13\x00") -> None:
        """Send bytes that are not a message (the driver must resynchronise)."""
        with self.lock:
            self.emit(data)

    def position(self, address: int | None = None) -> int:
        """A channel's position now, counts."""
        with self.lock:
            ch = self._channel(address)
            self._advance(ch, self.now())
            return round(ch.position)

    def _channel(self, address: int | None) -> AptChannel:
        return self.channels[next(iter(self.channels)) if address is None else address]

    # ------------------------------------------------------------------ framing
    def _data_msg(self, msg_id: int, data: bytes, source: int) -> bytes:
        return struct.pack("<HHBB", msg_id, len(data), HOST | 0x80, source) + data

    def _short_msg(self, msg_id: int, p1: int, p2: int, source: int) -> bytes:
        return struct.pack("<HBBBB", msg_id, p1, p2, HOST, source)

    def _valid_dest(self, dest: int) -> bool:
        return dest in self.channels or dest in (RACK, USB_UNIT)

    def on_replug(self) -> None:
        """A new USB connection: bytes of a message cut by the unplug are gone."""
        self._rx.clear()

    def on_bytes(self, data: bytes) -> None:
        self._rx += data
        while len(self._rx) >= 6:
            msg_id, p1, p2, dest, src = struct.unpack_from("<HBBBB", self._rx)
            long = bool(dest & 0x80)
            if not self._valid_dest(dest & 0x7F) or src != HOST:
                del self._rx[0]
                self.resyncs += 1
                continue
            n = p1 | (p2 << 8) if long else 0
            if n > 255:
                del self._rx[0]
                self.resyncs += 1
                continue
            if len(self._rx) < 6 + n:
                return
            payload = bytes(self._rx[6:6 + n])
            del self._rx[:6 + n]
            self._handle(msg_id, p1, p2, dest & 0x7F, payload if long else None)

    # ------------------------------------------------------------------ messages
    def _status_bits(self, ch: AptChannel) -> int:
        bits = ch.limit_hit
        if ch.motion is not None:
            bits |= MOVING_FWD if ch.motion.direction >= 0 else MOVING_REV
            if ch.motion.kind == "home":
                bits |= HOMING
            if ch.motion.kind == "jog":
                bits |= JOG_FWD if ch.motion.direction >= 0 else JOG_REV
        lo, hi = ch.travel
        if ch.motion is None and round(ch.position) <= lo:
            bits |= REV_LIMIT
        if ch.motion is None and round(ch.position) >= hi:
            bits |= FWD_LIMIT
        if ch.homed:
            bits |= HOMED
        if ch.enabled:
            bits |= ENABLED
        if self.stepper:
            bits |= MOTOR_CONNECTED
        return bits

    def _status_block(self, ch: AptChannel) -> bytes:
        """The 14-byte status block (and 14 more for the stepper's 28-byte update)."""
        pos = round(ch.position)
        if self.stepper:
            return struct.pack("<HiiI", 1, pos, pos, self._status_bits(ch))
        vel = 0 if ch.motion is None else min(32767, ch.velocity[2] >> 8)
        return struct.pack("<HiHhI", 1, pos, vel, 0, self._status_bits(ch))

    def _status_update(self, ch: AptChannel) -> bytes:
        if self.stepper:
            return self._data_msg(0x0481, self._status_block(ch) + bytes(14), ch.address)
        return self._data_msg(0x0491, self._status_block(ch), ch.address)

    def _info(self, source: int) -> bytes:
        fw = bytes([2, 0, 3, 0])  # minor, interim, major, unused
        data = (struct.pack("<i", self.serial_number) + self.model.encode()[:8].ljust(8, b"\0")
                + struct.pack("<H", self.spec["hw_type"]) + fw + bytes(58)
                + struct.pack("<H", self.stage_id) + struct.pack("<HHH", 1, 0, len(self.channels)))
        return self._data_msg(0x0006, data, source)

    def _handle(self, msg_id: int, p1: int, p2: int, dest: int, data: bytes | None) -> None:
        now = self.now()
        if msg_id == 0x0005:  # HW_REQ_INFO
            self.reply(self._info(dest))
            return
        if msg_id in (0x0002, 0x0223):  # HW_DISCONNECT, MOD_IDENTIFY
            return
        if msg_id == 0x0011:
            self.updates_on, self._updates_since_ack = True, 0
            self._updates_started = self._next_update = now / self.time_scale
            return
        if msg_id == 0x0012:
            self.updates_on = False
            return
        if msg_id == 0x0492:  # ACK_USTATUSUPDATE (server alive)
            self.acks += 1
            if self.spec["acks"]:
                self._updates_since_ack = 0
            return
        if dest not in self.channels:
            if dest == USB_UNIT or dest == RACK:
                dest = next(iter(self.channels))
            else:
                return
        ch = self.channels[dest]
        self._advance(ch, now)
        src = ch.address
        if msg_id == 0x0210:  # SET_CHANENABLESTATE
            ch.enabled = p2 == 0x01
        elif msg_id == 0x0211:
            self.reply(self._short_msg(0x0212, 1, 1 if ch.enabled else 2, src))
        elif msg_id == 0x0411:  # REQ_POSCOUNTER
            self.reply(self._data_msg(0x0412, struct.pack("<Hi", 1, round(ch.position)), src))
        elif msg_id == 0x0410 and data is not None:
            ch.position = float(struct.unpack_from("<Hi", data)[1])
        elif msg_id == 0x0413 and data is not None and len(data) >= 14:
            _, vmin, acc, vmax = struct.unpack_from("<Hiii", data)
            q = self.velocity_quantum
            vmax = min(vmax, self.max_velocity_units)  # the stage's limit
            ch.velocity = (vmin, acc, max(q, round(vmax / q) * q))
        elif msg_id == 0x0414:
            self.reply(self._data_msg(0x0415, struct.pack("<Hiii", 1, *ch.velocity), src))
        elif msg_id == 0x0440 and data is not None and len(data) >= 14:
            ch.home_params = struct.unpack_from("<HHii", data, 2)
        elif msg_id == 0x0441:
            self.reply(self._data_msg(0x0442, struct.pack("<HHHii", 1, *ch.home_params), src))
        elif msg_id == 0x043A and data is not None:
            ch.backlash = struct.unpack_from("<Hi", data)[1]
        elif msg_id == 0x043B:
            self.reply(self._data_msg(0x043C, struct.pack("<Hi", 1, ch.backlash), src))
        elif msg_id == 0x0445 and data is not None:
            ch.rel_distance = struct.unpack_from("<Hi", data)[1]
        elif msg_id == 0x0450 and data is not None:
            ch.abs_position = struct.unpack_from("<Hi", data)[1]
        elif msg_id == 0x0443:  # MOVE_HOME
            self._start(ch, now, ch.travel[0], "home")
        elif msg_id == 0x0448:  # MOVE_RELATIVE
            dist = ch.rel_distance if data is None else struct.unpack_from("<Hi", data)[1]
            self._start(ch, now, round(ch.position) + dist, "move")
        elif msg_id == 0x0453:  # MOVE_ABSOLUTE
            pos = ch.abs_position if data is None else struct.unpack_from("<Hi", data)[1]
            self._start(ch, now, pos, "move")
        elif msg_id == 0x0465:  # MOVE_STOP
            if ch.motion is not None:
                ch.position = ch.motion.position(now)
                ch.motion = None
                self._event(0x0466, ch)
        elif msg_id == 0x0429:  # REQ_STATUSBITS
            self.reply(self._data_msg(0x042A, struct.pack("<HI", 1, self._status_bits(ch)), src))
        elif msg_id == 0x0490 and not self.stepper:
            self.reply(self._data_msg(0x0491, self._status_block(ch), src))
        elif msg_id == 0x0480 and self.stepper:
            self.reply(self._status_update(ch))
        elif msg_id == 0x0416 and data is not None and len(data) >= 22:
            jog = struct.unpack_from("<HiiiiH", data, 2)
            ch.jog = (*jog[:4], min(jog[4], self.max_velocity_units), jog[5])  # the limit
        elif msg_id == 0x0417:
            self.reply(self._data_msg(0x0418, struct.pack("<HHiiiiH", 1, *ch.jog), src))
        elif msg_id == 0x046A:  # MOVE_JOG: p2 1 forward, 2 reverse
            self._jog(ch, now, 1 if p2 == 1 else -1)
        elif msg_id == 0x0457:  # MOVE_VELOCITY: to the end of the travel
            sign = 1 if p2 == 1 else -1
            self._start(ch, now, sign * 1e12, "velocity")
        elif msg_id == 0x0426 and data is not None and len(data) >= 6:
            ch.power = struct.unpack_from("<HH", data, 2)
        elif msg_id == 0x0427:
            self.reply(self._data_msg(0x0428, struct.pack("<HHH", 1, *ch.power), src))
        elif msg_id == 0x0423 and data is not None and len(data) >= 16:
            ch.limit_params = bytes(data[2:16])
        elif msg_id == 0x0424:
            self.reply(self._data_msg(0x0425, struct.pack("<H", 1) + ch.limit_params, src))
        elif msg_id == 0x0523 and data is not None and not self.stepper:
            ch.trigger = bytes(data[2:22]).ljust(20, b"\0")
        elif msg_id == 0x0524 and not self.stepper:
            self.reply(self._data_msg(0x0525, struct.pack("<H", 1) + ch.trigger, src))
        elif msg_id == 0x0500:
            ch.trigger_mode = p2
        elif msg_id == 0x0501:
            self.reply(self._short_msg(0x0502, 1, ch.trigger_mode, src))
        elif msg_id == 0x046B:
            ch.end_messages = False
        elif msg_id == 0x046C:
            ch.end_messages = True
        else:
            self.unknown.append(msg_id)
            log.debug("APT emulator: ignored message 0x%04x", msg_id)

    # ------------------------------------------------------------------ motion
    def _jog(self, ch: AptChannel, now: float, sign: int) -> None:
        """MOVE_JOG with the jog parameters: one step (mode 2) or on to the end of the
        travel until stopped (mode 1), at the jog velocity."""
        mode, step, _, acc, vmax, _ = ch.jog
        velocity = ch.velocity
        if vmax > 0:
            ch.velocity = (0, acc or velocity[1], vmax)
        p0 = ch.motion.position(now) if ch.motion is not None else ch.position
        target = sign * 1e12 if mode == 1 else round(p0) + sign * step
        self._start(ch, now, target, "jog")
        ch.velocity = velocity

    def _start(self, ch: AptChannel, now: float, target: float, kind: str) -> None:
        if not ch.enabled:
            log.debug("APT emulator: channel 0x%02x disabled, move ignored", ch.address)
            return
        vel, acc = self.counts_per_s(ch.velocity[2], ch.velocity[1])
        if kind == "home":
            vel = self.counts_per_s(ch.home_params[2] or ch.velocity[2], 1)[0]
            ch.homed = False
        lo, hi = ch.travel
        p0 = ch.motion.position(now) if ch.motion is not None else ch.position
        ch.position = p0
        ch.limit_hit = 0
        ch.motion = Motion(now, p0, float(min(max(target, lo), hi)), max(vel, 1e-9),
                           max(acc, 1e-9), kind)
        ch.motion.wanted = float(target)  # type: ignore[attr-defined]

    def _advance(self, ch: AptChannel, now: float) -> None:
        m = ch.motion
        if m is None:
            return
        if ch.stalled:
            m.t0 += now - getattr(m, "_last", now)
            m._last = now  # type: ignore[attr-defined]
            return
        pos = m.position(now)
        switch = ch.limit_switch
        crossed = switch is not None and m.kind != "home" and (
            (m.p0 < switch <= pos) or (pos <= switch < m.p0))
        if crossed:
            ch.position, ch.motion = float(switch), None
            ch.limit_hit = FWD_LIMIT if m.direction > 0 else REV_LIMIT
            self._event(0x0466, ch)
            return
        if not m.done(now):
            ch.position = pos
            return
        ch.position, ch.motion = m.p1, None
        if m.kind == "home":
            ch.position, ch.homed = 0.0 if ch.travel[0] <= 0 else float(ch.travel[0]), True
            if ch.end_messages:
                self.emit(self._short_msg(0x0444, 1, 0, ch.address))
            return
        if getattr(m, "wanted", m.p1) != m.p1:  # beyond the travel: stopped at the switch
            ch.limit_hit = FWD_LIMIT if m.direction > 0 else REV_LIMIT
            self._event(0x0466, ch)
            return
        if m.kind == "move":
            ch.position += ch.end_offset
        self._event(0x0464, ch)

    def _event(self, msg_id: int, ch: AptChannel) -> None:
        if ch.end_messages:
            self.emit(self._data_msg(msg_id, self._status_block(ch), ch.address))
            self._updates_since_ack += 1

    def on_tick(self, now: float) -> None:
        for ch in self.channels.values():
            self._advance(ch, now)
        real = now / self.time_scale
        if not self.updates_on or real < self._next_update or self._master is None:
            return
        self._next_update = real + self.update_period_s
        silent = (self._updates_since_ack >= 50 if self.spec["acks"]
                  else real - self._updates_started > 5.0)
        if silent:
            return
        for ch in self.channels.values():
            self.emit(self._status_update(ch))
        self._updates_since_ack += 1
        self.updates_sent += 1

    @staticmethod
    def counts(value: float, counts_per_unit: float) -> int:
        """``value`` in counts (rounded), a helper for tests."""
        return int(math.floor(value * counts_per_unit + 0.5))

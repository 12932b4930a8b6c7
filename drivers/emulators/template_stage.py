"""Emulator of the template's line-based stage controller, on a pty.

The device the driver template (:mod:`drivers.template`) speaks to; copy it with the
template when writing a driver for a new serial device. Written from the protocol
table in the template's module docstring:

- one command per line (``\\n``, ``\\r`` or ``\\r\\n``), one reply line per command,
  ended by ``\\r\\n``; a refused command gets ``ERR <code> <text>`` (1 unknown
  command, 2 value out of range, 3 no such axis);
- ``MOVE`` and ``HOME`` reply ``OK`` at once and the axis moves on a trapezoid at its
  velocity (time-scaled); ``MOVE`` during a move replaces it; ``STOP`` stops every
  axis where it is; the velocity is kept in 0.001 mm/s steps;
- faults: :meth:`set_limit_switch` (a move across the point stops there and
  ``FAULT?`` reports ``1 limit switch``), :meth:`silence` (the controller no longer
  answers), and from :class:`PtyEmulator` :meth:`drop_replies`, :meth:`unplug` /
  :meth:`replug` (the model keeps its state, as a controller with its own power
  supply does when the USB cable is pulled).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.emulators._motion import Motion
from drivers.emulators._pty import PtyEmulator, take_lines

__all__ = ["TemplateAxis", "TemplateStageEmulator"]

_ERRORS = {1: "unknown command", 2: "value out of range", 3: "no such axis"}


@dataclass
class TemplateAxis:
    """One axis of the model: travel, velocity and position in mm (mm/s)."""

    low_mm: float = 0.0
    high_mm: float = 50.0
    velocity_mm_s: float = 5.0
    position_mm: float = 0.0
    motion: Motion | None = None
    fault: str = "0"
    limit_switch_mm: float | None = None


class TemplateStageEmulator(PtyEmulator):
    """A controller of ``axes`` linear axes speaking the template's protocol.

    Parameters
    ----------
    axes : int
        Number of axes (numbered from 1).
    travel_mm : (float, float)
        Travel of every axis, mm.
    vmax_mm_s : float
        Largest velocity accepted, mm/s.
    accel_mm_s2 : float
        Acceleration of every move, mm/s².
    serial : str
        Serial number in the ``*IDN?`` reply.
    model : str
        Model in the ``*IDN?`` reply (another one plays a wrong device on the port).
    link, time_scale : see :class:`PtyEmulator`.
    """

    def __init__(self, axes: int = 2, *, travel_mm: tuple[float, float] = (0.0, 50.0),
                 vmax_mm_s: float = 20.0, accel_mm_s2: float = 100.0, serial: str = "TS0001",
                 model: str = "TPL-STAGE", link: str | Path | None = None,
                 time_scale: float = 1.0) -> None:
        super().__init__(link=link, time_scale=time_scale)
        lo, hi = (float(v) for v in travel_mm)
        self.axes = [TemplateAxis(lo, hi, position_mm=lo) for _ in range(int(axes))]
        self.vmax_mm_s = float(vmax_mm_s)
        self.accel_mm_s2 = float(accel_mm_s2)
        self.serial, self.model = serial, model
        self.silent = False
        self.commands: list[str] = []  # every command line received, for tests
        self._line = bytearray()

    # ------------------------------------------------------------------ faults
    def set_limit_switch(self, axis: int, position_mm: float | None) -> None:
        """A limit switch at ``position_mm`` on ``axis`` (None removes it)."""
        with self.lock:
            self.axes[axis - 1].limit_switch_mm = position_mm

    def silence(self, silent: bool = True) -> None:
        """Make the controller stop answering (it still executes what it receives)."""
        with self.lock:
            self.silent = silent

    # ------------------------------------------------------------------ parsing
    def on_replug(self) -> None:
        """A new connection: a command cut by the unplug is gone."""
        self._line.clear()

    def on_bytes(self, data: bytes) -> None:
        self._line += data
        for text in take_lines(self._line):
            self.commands.append(text)
            reply = self._execute(text.split())
            if not self.silent:
                self.reply(f"{reply}\r\n".encode("ascii"))

    # ------------------------------------------------------------------ commands
    def _execute(self, tokens: list[str]) -> str:
        now = self.now()
        for n in range(len(self.axes)):
            self._advance(n, now)
        verb, args = tokens[0].upper(), tokens[1:]
        if verb == "*IDN?" and not args:
            return f"{self.model} {self.serial} 1.0"
        if verb == "AXES?" and not args:
            return str(len(self.axes))
        if verb == "VMAX?" and not args:
            return f"{self.vmax_mm_s:g}"
        if verb == "MOVING?" and not args:
            return "1" if any(ax.motion is not None for ax in self.axes) else "0"
        if verb == "STOP" and not args:
            for ax in self.axes:
                if ax.motion is not None:
                    ax.position_mm, ax.motion = ax.motion.position(now), None
            return "OK"
        per_axis = {"TRAVEL?": 0, "VEL?": 0, "POS?": 0, "FAULT?": 0, "HOME": 0, "VEL": 1,
                    "MOVE": 1}
        if verb not in per_axis or len(args) != 1 + per_axis[verb]:
            return self._err(1)
        if not args[0].isdigit() or not 1 <= int(args[0]) <= len(self.axes):
            return self._err(3)
        ax = self.axes[int(args[0]) - 1]
        value = None
        if per_axis[verb]:
            try:
                value = float(args[1])
            except ValueError:
                return self._err(2)
        if verb == "TRAVEL?":
            return f"{ax.low_mm:g} {ax.high_mm:g}"
        if verb == "VEL?":
            return f"{ax.velocity_mm_s:.3f}"
        if verb == "POS?":
            pos = ax.motion.position(now) if ax.motion is not None else ax.position_mm
            return f"{pos:.6f}"
        if verb == "FAULT?":
            return ax.fault
        if verb == "VEL":
            if not 0 < value <= self.vmax_mm_s:
                return self._err(2)
            ax.velocity_mm_s = round(value, 3) or 0.001
            return "OK"
        target = ax.low_mm if verb == "HOME" else value
        if not ax.low_mm <= target <= ax.high_mm:
            return self._err(2)
        start = ax.motion.position(now) if ax.motion is not None else ax.position_mm
        ax.position_mm, ax.fault = start, "0"
        ax.motion = Motion(now, start, target, ax.velocity_mm_s, self.accel_mm_s2,
                           verb.lower())
        return "OK"

    @staticmethod
    def _err(code: int) -> str:
        return f"ERR {code} {_ERRORS[code]}"

    # ------------------------------------------------------------------ motion
    def _advance(self, n: int, now: float) -> None:
        ax = self.axes[n]
        m = ax.motion
        if m is None:
            return
        pos = m.position(now)
        sw = ax.limit_switch_mm
        if sw is not None and m.kind == "move" and (m.p0 < sw <= pos or pos <= sw < m.p0):
            ax.position_mm, ax.motion, ax.fault = sw, None, "1 limit switch"
            return
        if m.done(now):
            ax.position_mm, ax.motion = m.p1, None

    def on_tick(self, now: float) -> None:
        for n in range(len(self.axes)):
            self._advance(n, now)

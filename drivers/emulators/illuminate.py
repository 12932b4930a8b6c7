"""Emulator of an LED array running the "illuminate" firmware (v1.32), on a pty.

Written from the command set summarised in hardware-protocols.md, section 2a:

- a command ends at ``\\n`` only; every other byte (``\\r`` too) belongs to it, so
  ``bf\\r`` is an unknown command; the only argument delimiter is ``.``; a command
  longer than 20 characters or an argument longer than 10 is refused;
- one command at a time: bytes that arrive while a command executes (here: in the
  same write as the command) are discarded, then the terminator ``-==-\\n`` follows
  the output of *every* command;
- ``human`` (default) and ``machine`` output modes; machine replies such as
  ``NA.25``, ``SB.128``, ``CO.255.0.0``, ``AC.0``, ``DZ.50`` (uint8: wraps above
  255 mm); errors print ``ERROR ...``; unknown commands ``Command [x] is not
  implemented yet.``;
- LED values are ``ceil(colour * brightness / 255)`` per channel; ``l`` lights the
  listed LEDs (after clearing when autoclear is on), ``x`` clears, ``ff`` fills,
  ``bf`` / ``df`` / ``dpc`` draw from the NA geometry; ``pp``, ``pledpos`` and
  ``pvals`` print JSON (parameters, LED positions, LED values).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from drivers.emulators._pty import PtyEmulator
from drivers.led_array import grid_positions

__all__ = ["IlluminateEmulator"]

TERMINATOR = b"-==-\n"
_COLOURS = {"red": (255, 0, 0), "green": (0, 255, 0), "blue": (0, 0, 255),
            "white": (255, 255, 255)}
_BRIGHTNESS = {"max": 255, "min": 1, "half": 128, "quarter": 64}


class IlluminateEmulator(PtyEmulator):
    """An illuminate LED array: a ``shape`` grid at ``pitch_mm``, ``distance_mm`` away.

    Parameters
    ----------
    shape : (int, int)
        LED rows and columns.
    pitch_mm, distance_mm : float
        LED pitch; LED-to-sample distance.
    channels : int
        1 or 3 colour channels.
    serial_number : str
        Reported by ``pp``.
    link, time_scale : see :class:`PtyEmulator`.
    """

    def __init__(self, shape: tuple[int, int] = (8, 8), *, pitch_mm: float = 4.0,
                 distance_mm: float = 50.0, channels: int = 3, serial_number: str = "IL0042",
                 link: str | Path | None = None, time_scale: float = 1.0) -> None:
        super().__init__(link=link, time_scale=time_scale)
        self.shape = (int(shape[0]), int(shape[1]))
        self.positions = grid_positions(*self.shape, float(pitch_mm))
        self.led_count = self.shape[0] * self.shape[1]
        self.channels = int(channels)
        self.serial_number = serial_number
        self.distance_mm = float(distance_mm)
        self.values = np.zeros((self.led_count, self.channels), dtype=np.int64)
        self.colour = (255,) * self.channels
        self.brightness = 255
        self.na, self.inner_na = 0.25, 0.0
        self.autoclear = True
        self.machine = False
        self._line = bytearray()
        self.commands: list[bytes] = []

    # ------------------------------------------------------------------ parsing
    def on_replug(self) -> None:
        """A new USB connection: bytes of a message cut by the unplug are gone."""
        self._line.clear()

    def on_bytes(self, data: bytes) -> None:
        self._line += data
        i = self._line.find(b"\n")
        if i < 0:
            return
        raw = bytes(self._line[:i])
        self._line.clear()  # the rest arrived while the command executes: discarded
        self.commands.append(raw)
        self.reply(self._execute(raw) + TERMINATOR)

    def _execute(self, raw: bytes) -> bytes:
        text = raw.decode("latin-1")
        parts = text.split(".") if text else [""]
        cmd, args = parts[0], parts[1:]
        if len(cmd) > 20:
            return b"ERROR: Command was too long!\n"
        if any(len(a) > 10 for a in args):
            return b"ERROR: Optional element was too long!\n"
        handler = getattr(self, "_cmd_" + _ALIASES.get(cmd, cmd), None) if cmd else None
        if handler is None or not cmd.replace("_", "").isalnum():
            return f"Command [{cmd}] is not implemented yet.\n".encode("latin-1")
        try:
            out = handler(args)
        except _Error as exc:
            return f"ERROR (LedArray::{exc.args[0]}): {exc.args[1]}\n".encode()
        return (out + "\n").encode() if out else b""

    def _out(self, machine: str, human: str) -> str:
        return machine if self.machine else human

    # ------------------------------------------------------------------ commands
    def _cmd_machine(self, args):
        self.machine = True
        return ""

    def _cmd_human(self, args):
        self.machine = False
        return ""

    def _cmd_ver(self, args):
        return "1.32"

    def _cmd_pp(self, args):
        wl = {"r": 0.625, "g": 0.525, "b": 0.465} if self.channels == 3 else {"w": 0.53}
        return json.dumps({
            "device_name": "illuminate-emulator", "led_count": self.led_count,
            "color_channels": list(wl), "color_channel_center_wavelengths": wl,
            "trigger_input_count": 1, "trigger_output_count": 1, "bit_depth": 8,
            "serial_number": self.serial_number, "part_number": "EMU", "mac_address": "",
            "interface_version": 1.32,
        })

    def _cmd_pledpos(self, args):
        pos = {str(i): [round(float(x), 3), round(float(y), 3), round(self.distance_mm, 3)]
               for i, (x, y) in enumerate(self.positions)}
        return json.dumps({"led_position_list_cartesian": pos})

    def _cmd_pvals(self, args):
        lo = int(args[0]) if args else 0
        hi = int(args[1]) if len(args) > 1 else self.led_count - 1
        return json.dumps({"led_values": {str(i): self.values[i].tolist()
                                          for i in range(lo, hi + 1)}})

    def _cmd_ac(self, args):
        self.autoclear = (not self.autoclear) if not args else self._int(args[0], 0, 1,
                                                                          "setAutoClear") == 1
        return self._out(f"AC.{int(self.autoclear)}", f"Auto clear is {self.autoclear}")

    def _cmd_na(self, args):
        if args:
            digits = args[0]
            v = self._int(digits, 1, 99, "setNa")
            self.na = v / (10 if len(digits) == 1 else 100)
            if not 0 < self.na < 1:
                raise _Error("setNa", "invalid objective NA.")
        return self._out(f"NA.{round(self.na * 100):02d}", f"Current NA is {self.na:.2f}")

    def _cmd_nai(self, args):
        if args:
            self.inner_na = self._int(args[0], 0, 99, "setInnerNa") / 100
        return self._out(f"NAI.{round(self.inner_na * 100):02d}", f"Inner NA {self.inner_na}")

    def _cmd_sb(self, args):
        if args:
            v = _BRIGHTNESS.get(args[0])
            self.brightness = v if v is not None else self._int(args[0], 0, 255,
                                                                 "setBrightness")
        return self._out(f"SB.{self.brightness}", f"Brightness is {self.brightness}")

    def _cmd_sc(self, args):
        if len(args) == 1 and args[0] in _COLOURS:
            self.colour = _COLOURS[args[0]][:self.channels]
        elif len(args) == 1:
            self.colour = (self._int(args[0], 0, 255, "setColor"),) * self.channels
        elif len(args) == 3 and self.channels == 3:
            self.colour = tuple(self._int(a, 0, 255, "setColor") for a in args)
        elif args:
            raise _Error("setColor", "invalid number of color arguments")
        return self._out("CO." + ".".join(map(str, self.colour)), f"Color is {self.colour}")

    def _cmd_sad(self, args):
        if args:
            self.distance_mm = float(self._int(args[0], 1, 1000, "setArrayDistance"))
        return self._out(f"DZ.{int(self.distance_mm) % 256}", f"Distance {self.distance_mm}")

    def _cmd_x(self, args):
        self.values[:] = 0
        return ""

    def _cmd_ff(self, args):
        self._draw(np.arange(self.led_count), clear=True)
        return ""

    def _cmd_l(self, args):
        if not args:
            raise _Error("drawLedList", "no LED numbers given")
        idx = np.array([self._int(a, 0, self.led_count - 1, "drawLedList") for a in args])
        self._draw(idx, clear=self.autoclear)
        return ""

    def _na_of_leds(self) -> np.ndarray:
        r = np.hypot(self.positions[:, 0], self.positions[:, 1])
        return r / np.hypot(r, self.distance_mm)

    def _cmd_bf(self, args):
        na = self._na_of_leds()
        self._draw(np.flatnonzero((na <= self.na) & (na >= self.inner_na)), clear=True)
        return ""

    def _cmd_df(self, args):
        self._draw(np.flatnonzero(self._na_of_leds() > self.na), clear=True)
        return ""

    def _cmd_dpc(self, args):
        side = (args[0] if args else "t")[0]
        if side not in "tblr":
            raise _Error("drawDpc", "invalid DPC type")
        x, y = self.positions[:, 0], self.positions[:, 1]
        half = {"t": y >= 0, "b": y < 0, "l": x < 0, "r": x >= 0}[side]
        self._draw(np.flatnonzero(half & (self._na_of_leds() <= self.na)), clear=True)
        return ""

    # ------------------------------------------------------------------ helpers
    def _draw(self, idx: np.ndarray, *, clear: bool) -> None:
        if clear:
            self.values[:] = 0
        value = [math.ceil(c * self.brightness / 255) for c in self.colour]
        self.values[idx] = value

    @staticmethod
    def _int(text: str, low: int, high: int, where: str) -> int:
        if not text.isdigit() or not low <= int(text) <= high:
            raise _Error(where, f"invalid value {text!r} (expected {low}..{high})")
        return int(text)

    def lit(self) -> dict[int, tuple[int, ...]]:
        """``{led: channel values}`` of the LEDs that are on (a test helper)."""
        with self.lock:
            return {int(i): tuple(int(v) for v in self.values[i])
                    for i in np.flatnonzero(self.values.any(axis=1))}


class _Error(Exception):
    """An error the firmware prints (``ERROR (LedArray::where): what``)."""


_ALIASES = {"led": "l", "xx": "x", "fillArray": "ff", "brightfield": "bf", "darkfield": "df",
            "halfCircle": "dpc", "setNa": "na", "setInnerNa": "nai", "setColor": "sc",
            "setBrightness": "sb", "setArrayDistance": "sad", "autoClear": "ac",
            "printParams": "pp", "printVals": "pvals", "version": "ver"}

"""Emulator of a DIY LED array speaking LEDMX (docs/drivers/arduino-led-protocol.md).

Line commands ended by ``\\n`` (``\\r`` ignored), one reply line each (``OK [data]``
or ``ERR <code> <message>``), ``READY`` printed at start-up and after a re-plug,
length-checked binary ``FRAME`` updates, a frame buffer latched by ``SHOW`` (or after
every command with ``AUTO 1``), global brightness. ``boot_s`` models a board that
resets when the port opens: commands sent during the boot are lost.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from drivers.emulators._pty import PtyEmulator

__all__ = ["ArduinoLedEmulator"]


class ArduinoLedEmulator(PtyEmulator):
    """A ``shape`` LED grid with ``channels`` (1 or 3) channels.

    Parameters
    ----------
    shape : (int, int)
        Rows and columns.
    channels : int
        1 (mono) or 3 (RGB).
    model, firmware : str
        Reported by ``*IDN?``.
    boot_s : float
        Real seconds after start/re-plug during which input is ignored (then READY).
    link, time_scale : see :class:`PtyEmulator`.
    """

    def __init__(self, shape: tuple[int, int] = (8, 8), *, channels: int = 3,
                 model: str = "emu-ws2812", firmware: str = "1.0", boot_s: float = 0.0,
                 link: str | Path | None = None, time_scale: float = 1.0) -> None:
        super().__init__(link=link, time_scale=time_scale)
        self.rows, self.cols = int(shape[0]), int(shape[1])
        self.channels = int(channels)
        self.model, self.firmware = model, firmware
        self.boot_s = float(boot_s)
        self.n = self.rows * self.cols
        self.buffer = np.zeros((self.n, self.channels), dtype=np.uint8)
        self.shown = np.zeros_like(self.buffer)
        self.brightness = 255
        self.auto = False
        self.lines: list[str] = []
        self._rx = bytearray()
        self._frame: tuple[int, float] | None = None  # (bytes expected, deadline)
        self._booted_at = 0.0
        self._ready_sent = False

    def start(self) -> ArduinoLedEmulator:
        self._boot()
        return super().start()  # type: ignore[return-value]

    def on_replug(self) -> None:
        self._boot()

    def _boot(self) -> None:
        self._booted_at = time.monotonic() + self.boot_s
        self._ready_sent = False
        self._rx.clear()
        self._frame = None

    @property
    def booted_at(self) -> float:
        """``time.monotonic()`` at which the board answers again (its last start or
        replug plus ``boot_s``): nothing sent before it is read."""
        return self._booted_at

    def output(self) -> np.ndarray:
        """``(rows * cols, channels)`` uint8 light output now (brightness applied)."""
        with self.lock:
            return (self.shown.astype(np.int64) * self.brightness // 255).astype(np.uint8)

    # ------------------------------------------------------------------ I/O
    def on_tick(self, now: float) -> None:
        if not self._ready_sent and time.monotonic() >= self._booted_at and self.plugged:
            self._ready_sent = True
            self.emit(b"READY\n")
        if self._frame is not None and time.monotonic() > self._frame[1]:
            self._frame = None
            self._rx.clear()
            self.reply(b"ERR 5 frame timeout\n")

    def on_bytes(self, data: bytes) -> None:
        if time.monotonic() < self._booted_at:
            return  # still booting: lost
        self._rx += data
        while True:
            if self._frame is not None:
                n = self._frame[0]
                if len(self._rx) < n:
                    return
                raw = bytes(self._rx[:n])
                del self._rx[:n]
                self._frame = None
                self._reply(self._load_frame(raw))
                continue
            i = self._rx.find(b"\n")
            if i < 0:
                return
            line = bytes(self._rx[:i]).decode("ascii", "replace").rstrip("\r")
            del self._rx[:i + 1]
            self.lines.append(line)
            self._reply(self._command(line))

    def _reply(self, text: str | None) -> None:
        if text is not None:
            self.reply((text + "\n").encode())

    # ------------------------------------------------------------------ commands
    def _command(self, line: str) -> str | None:
        tokens = line.split(" ") if line else [""]
        cmd, args = tokens[0], tokens[1:]
        try:
            values = [int(a) for a in args] if cmd not in ("FRAME",) else []
        except ValueError:
            return "ERR 3 value out of range"
        rgb = self.channels
        if cmd == "*IDN?":
            return f"OK LEDMX,{self.model},{self.rows}x{self.cols},{self.channels},{self.firmware}"
        if cmd == "CLR" and not args:
            self.buffer[:] = 0
        elif cmd == "PIX" and len(values) == 1 + rgb:
            if not (0 <= values[0] < self.n and all(0 <= v <= 255 for v in values[1:])):
                return "ERR 3 value out of range"
            self.buffer[values[0]] = values[1:]
        elif cmd == "FILL" and len(values) == rgb:
            if not all(0 <= v <= 255 for v in values):
                return "ERR 3 value out of range"
            self.buffer[:] = values
        elif cmd == "BRI" and len(values) == 1:
            if not 0 <= values[0] <= 255:
                return "ERR 3 value out of range"
            self.brightness = values[0]
        elif cmd == "SHOW" and not args:
            self.shown = self.buffer.copy()
            return "OK"
        elif cmd == "AUTO" and len(values) == 1:
            if values[0] not in (0, 1):
                return "ERR 3 value out of range"
            self.auto = bool(values[0])
        elif cmd == "GET" and len(values) == 1:
            if not 0 <= values[0] < self.n:
                return "ERR 3 value out of range"
            return "OK " + " ".join(str(int(v)) for v in self.buffer[values[0]])
        elif cmd == "FRAME" and len(args) == 1:
            if not args[0].isdigit():
                return "ERR 3 value out of range"
            self._frame = (int(args[0]), time.monotonic() + 1.0)
            return None  # the reply follows the data
        elif cmd in ("CLR", "PIX", "FILL", "BRI", "SHOW", "AUTO", "GET", "FRAME"):
            return "ERR 2 bad argument count"
        else:
            return "ERR 1 unknown command"
        if self.auto:
            self.shown = self.buffer.copy()
        return "OK"

    def _load_frame(self, raw: bytes) -> str:
        if len(raw) != self.buffer.size:
            return "ERR 4 frame length mismatch"
        self.buffer[:] = np.frombuffer(raw, dtype=np.uint8).reshape(self.buffer.shape)
        if self.auto:
            self.shown = self.buffer.copy()
        return "OK"

"""LED array driver for DIY arrays speaking LEDMX (docs/drivers/arduino-led-protocol.md).

One text command per line, one reply line each (``OK [data]`` or ``ERR code
message``). At open the driver repeats ``*IDN?`` until the board answers (a board
with a USB-serial bridge resets when the port opens and needs ~2 s; its ``READY``
banner and anything else before the identity are skipped), reads the geometry
(rows x cols, channels), turns auto-show off, sets brightness 255 and shows an
empty frame. A lit state is sent as one binary ``FRAME`` (rows x cols x channels
bytes, row-major) followed by ``SHOW``, so the LEDs change at once.
"""

from __future__ import annotations

import re
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from drivers.errors import DeviceProtocolError
from drivers.led_array import SerialLedArray, grid_positions
from drivers.transports import BY_ID_DIR, SerialLink

__all__ = ["ArduinoLedArray"]

_IDN_RE = re.compile(r"^OK LEDMX,([^,]*),(\d+)x(\d+),([13]),(\S+)$")
#: Default centre wavelengths (nm) of an RGB array's channels (WS2812B-like).
DEFAULT_WAVELENGTHS_NM: dict[str, float] = {"red": 625.0, "green": 522.0, "blue": 465.0}


class ArduinoLedArray(SerialLedArray):
    """A DIY LED grid on a serial port, speaking LEDMX.

    Parameters
    ----------
    device_id : str
        Name of the array.
    port : str, optional
        Serial port (``/dev/ttyACMn`` / ``/dev/ttyUSBn``; prefer ``/dev/serial/by-id``).
    serial_number : str, optional
        USB serial number of the board, resolved on every open.
    baudrate : int
        115200.
    pitch_mm, distance_mm : float
        LED pitch; LED-to-sample distance (the protocol does not carry them).
    shape : (int, int), optional
        Expected rows and columns (checked against ``*IDN?``).
    wavelengths_nm : Mapping[str, float], optional
        Centre wavelength of each channel of an RGB array (red, green, blue); a mono
        array has the single colour "white".
    ready_timeout_s : float
        How long to keep asking ``*IDN?`` at open (a resetting board boots for ~2 s).
    reply_timeout_s : float
        Longest wait for one reply.
    search_dirs : sequence of str
        Link directories searched for ``serial_number``.
    """

    def __init__(
        self, device_id: str, *, port: str | None = None, serial_number: str | None = None,
        baudrate: int = 115200, pitch_mm: float = 4.0, distance_mm: float = 50.0,
        shape: Sequence[int] | None = None, wavelengths_nm: Mapping[str, float] | None = None,
        ready_timeout_s: float = 3.0, reply_timeout_s: float = 1.0,
        search_dirs: Sequence[str] = (BY_ID_DIR,),
    ) -> None:
        super().__init__(device_id)
        self._pitch = self._float("pitch_mm", pitch_mm, low=0.0, low_open=True)
        self._distance = self._float("distance_mm", distance_mm, low=0.0, low_open=True)
        self._shape = None if shape is None else self._int_pair("shape", shape, high=4096)
        self._wl = dict(DEFAULT_WAVELENGTHS_NM if wavelengths_nm is None else wavelengths_nm)
        self._ready_timeout = self._float("ready_timeout_s", ready_timeout_s, low=0.0,
                                          low_open=True)
        self._reply_timeout = self._float("reply_timeout_s", reply_timeout_s, low=0.0,
                                          low_open=True)
        self._link = SerialLink(device_id, port=port, serial_number=serial_number,
                                search_dirs=search_dirs, baudrate=baudrate,
                                timeout_error=self.timeout_error)
        self.identity: dict[str, Any] = {}
        self._hw: dict[str, Any] = {}
        self._info_cache: dict[str, Any] = {}

    # ----------------------------------------------------------- protocol
    def command(self, text: str, payload: bytes = b"", timeout_s: float | None = None) -> str:
        """Send one command (and a ``FRAME``'s payload); return the data after ``OK``.

        Raises
        ------
        DeviceProtocolError
            An ``ERR`` reply (its code and message quoted) or a line that is neither.
        LedArrayTimeoutError
            No reply line within the timeout.
        """
        self._link.discard_input()
        self._link.write(text.encode("ascii") + b"\n" + payload)
        deadline = time.monotonic() + (timeout_s or self._reply_timeout)
        while True:
            left = max(deadline - time.monotonic(), 1e-3)
            line = self._link.read_until(b"\n", left, what=f"reply to {text!r}")
            reply = line.decode("ascii", "replace").strip()
            if reply == "READY":  # the board reset (brown-out, re-enumeration)
                continue
            if reply == "OK" or reply.startswith("OK "):
                return reply[3:]
            if reply.startswith("ERR"):
                raise self._error(DeviceProtocolError, f"the array refused {text!r}: {reply}",
                                  "see the error codes in docs/drivers/arduino-led-protocol.md")
            raise self._error(DeviceProtocolError, f"{text!r} answered {reply!r}",
                              "check that the sketch speaks LEDMX and the baud rate")

    # ----------------------------------------------------------- lifecycle hooks
    def _do_open(self, timeout_s: float) -> None:
        self._link.open()
        try:
            m = self._handshake(min(timeout_s, self._ready_timeout))
            model, rows, cols, channels, fw = m.groups()
            rows, cols, channels = int(rows), int(cols), int(channels)
            if self._shape is not None and self._shape != (rows, cols):
                raise self._error(DeviceProtocolError, f"the array is {rows}x{cols}, the bench "
                                  f"file says {self._shape[0]}x{self._shape[1]}",
                                  "fix shape in the bench file, or check the port")
            self.identity = {"model": model, "rows": rows, "cols": cols, "channels": channels,
                             "firmware": fw}
            colours: dict[str, float | None] = (
                {**{k: float(v) for k, v in self._wl.items()}, "white": None}
                if channels == 3 else {"white": None})
            self._info_cache = {"positions_mm": grid_positions(rows, cols, self._pitch),
                                "pitch_mm": self._pitch, "distance_mm": self._distance,
                                "colours": colours}
            self.command("AUTO 0")
            self.command("BRI 255")
            self._send_frame({})
            self._hw = {"na_illum": 0.25, "colour": "white", "brightness": 1.0}
        except BaseException:
            self._link.close()
            raise

    def _handshake(self, timeout_s: float) -> re.Match:
        deadline = time.monotonic() + timeout_s
        seen = b""
        while time.monotonic() < deadline:
            self._link.write(b"*IDN?\n")
            try:
                end = min(time.monotonic() + 0.5, deadline)
                while time.monotonic() < end:
                    line = self._link.read_until(b"\n", max(end - time.monotonic(), 1e-3))
                    seen = line[-80:]
                    m = _IDN_RE.match(line.decode("ascii", "replace").strip())
                    if m:
                        return m
            except self.timeout_error:
                continue
        raise self._timeout(f"no LEDMX identity within {timeout_s:g} s (last line {seen!r})",
                            "check the port, that the sketch speaks LEDMX and has booted, "
                            "and raise ready_timeout_s for a slow board")

    def _clear(self) -> None:
        self._send_frame({})

    def _do_get_info(self) -> dict[str, Any]:
        return dict(self._info_cache)

    def _do_apply(self, name: str, value: Any) -> Any:
        self._hw[name] = value  # pattern defaults: the board has no such setting
        return None

    # ----------------------------------------------------------- display
    def _frame(self, state: dict[int, tuple[str, float]]) -> bytes:
        ch = self.identity["channels"]
        frame = np.zeros((self.identity["rows"] * self.identity["cols"], ch), dtype=np.uint8)
        names = list(self._wl)[:3]
        for i, (colour, brightness) in state.items():
            level = round(255 * brightness)
            if ch == 1 or colour == "white":
                frame[i] = level
            else:
                frame[i, names.index(colour)] = level
        return frame.tobytes()

    def _send_frame(self, state: dict[int, tuple[str, float]], timeout_s: float = 1.0) -> None:
        raw = self._frame(state)
        self.command(f"FRAME {len(raw)}", raw, timeout_s)
        self.command("SHOW", timeout_s=timeout_s)

    def _do_show(self, state: dict[int, tuple[str, float]], timeout_s: float) -> None:
        self._send_frame(state, timeout_s)

    def _do_status(self) -> dict[str, Any]:
        return {**super()._do_status(), "port": self._link.path, **self.identity}

"""LED array driver for the "illuminate" firmware (Waller Lab / SCI Microscopy arrays).

Serial command set (firmware v1.32; notes in docs/drivers/illuminate.md): one command
per line ended by ``\\n`` alone (a ``\\r`` would become part of the command), arguments
separated by ``.`` only (``sc.255.0.0``, ``l.0.5.12``), and after each command's
output the firmware prints ``-==-\\n``. Bytes sent while a command executes are
discarded, so the driver never pipelines: it clears the input, writes one command,
reads up to the terminator (with a timeout) and only then sends the next. Any reply
holding ``ERROR``/``ERR:`` or "is not implemented" raises
:class:`~drivers.errors.DeviceProtocolError` with the reply.

At open the driver switches the firmware to ``machine`` output, reads the parameters
(``pp``: LED count, colour channels and wavelengths) and the LED positions
(``pledpos``: x, y, z in mm; z is the array distance), turns autoclear off (``ac.0``)
and every LED off (``x``). A lit state is drawn as ``x``, then per (colour,
brightness) group ``sc.r.g.b`` and ``l.i.j...`` (the firmware's LED value is
``ceil(colour x brightness / 255)``; brightness stays at 255 and the colour carries
the level).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np

from drivers.errors import DeviceError, DeviceProtocolError, DeviceValueError
from drivers.led_array import SerialLedArray
from drivers.transports import BY_ID_DIR, SerialLink

__all__ = ["IlluminateLedArray"]

TERMINATOR = b"-==-\n"
_CHANNEL_NAMES = {"r": "red", "g": "green", "b": "blue"}
_MAX_ARGS = 200  # LEDs per "l" command (the firmware takes up to 1500 arguments)


class IlluminateLedArray(SerialLedArray):
    """An LED array running the illuminate firmware, on a (USB CDC) serial port.

    Parameters
    ----------
    device_id : str
        Name of the array.
    port : str, optional
        Serial port (a Teensy is ``/dev/ttyACMn``; prefer ``/dev/serial/by-id/...``).
    serial_number : str, optional
        USB serial number of the board, resolved on every open.
    baudrate : int
        Ignored by native USB boards; 115200.
    shape : (int, int), optional
        Expected LED rows and columns: the device's LED count must match.
    pitch_mm : float, optional
        LED pitch; default the median nearest-neighbour distance of the positions.
    distance_mm : float, optional
        LED-to-sample distance; default the z the device reports. Given, it is also
        sent (``sad``) when at most 255 mm (the firmware prints it as a uint8).
    reply_timeout_s : float
        Longest wait for a command's terminator.
    search_dirs : sequence of str
        Link directories searched for ``serial_number``.
    """

    def __init__(
        self, device_id: str, *, port: str | None = None, serial_number: str | None = None,
        baudrate: int = 115200, shape: Sequence[int] | None = None,
        pitch_mm: float | None = None, distance_mm: float | None = None,
        reply_timeout_s: float = 2.0, search_dirs: Sequence[str] = (BY_ID_DIR,),
    ) -> None:
        super().__init__(device_id)
        self._shape = None if shape is None else self._int_pair("shape", shape, high=4096)
        self._pitch = None if pitch_mm is None else self._float("pitch_mm", pitch_mm, low=0.0,
                                                                low_open=True)
        self._distance = None if distance_mm is None else self._float(
            "distance_mm", distance_mm, low=0.0, low_open=True)
        self._reply_timeout = self._float("reply_timeout_s", reply_timeout_s, low=0.0,
                                          low_open=True)
        self._link = SerialLink(device_id, port=port, serial_number=serial_number,
                                search_dirs=search_dirs, baudrate=baudrate,
                                timeout_error=self.timeout_error)
        self._geometry: dict[str, Any] = {}
        self._hw: dict[str, Any] = {}
        self.parameters: dict[str, Any] = {}

    # ----------------------------------------------------------- protocol
    def command(self, text: str, timeout_s: float | None = None) -> str:
        """Send one command and return its output (without the terminator).

        Raises
        ------
        DeviceProtocolError
            The output reports an error or an unknown command.
        LedArrayTimeoutError
            No terminator within the timeout.
        """
        if "\n" in text or "\r" in text:
            raise self._error(DeviceValueError, f"command {text!r} holds a line break",
                              "send one command without CR/LF")
        self._link.discard_input()
        self._link.write(text.encode("ascii") + b"\n")
        raw = self._link.read_until(TERMINATOR, timeout_s or self._reply_timeout,
                                    what=f"reply to {text[:40]!r}")
        out = raw[:-len(TERMINATOR)].decode("ascii", "replace").strip()
        if "ERROR" in out or "ERR:" in out or "not implemented" in out:
            raise self._error(DeviceProtocolError, f"the array refused {text[:40]!r}: {out}",
                              "check the command, its arguments and the firmware version")
        return out

    def _expect(self, text: str, prefix: str) -> str:
        out = self.command(text)
        if not out.startswith(prefix):
            raise self._error(DeviceProtocolError, f"{text!r} answered {out!r}, expected "
                              f"{prefix}...", "check that the firmware is illuminate v1.3x")
        return out[len(prefix):]

    # ----------------------------------------------------------- lifecycle hooks
    def _do_open(self, timeout_s: float) -> None:
        self._link.open()
        try:
            self.command("machine", timeout_s)
            self.parameters = json.loads(self.command("pp"))
            positions = json.loads(self.command("pledpos"))["led_position_list_cartesian"]
            self._set_geometry(positions)
            self._expect("ac.0", "AC.")
            self._expect("sb.255", "SB.")
            self.command("x")
            if self._distance is not None and self._distance <= 255:
                self._expect(f"sad.{round(self._distance)}", "DZ.")
            self._hw = {"na_illum": float(self._expect("na", "NA.")) / 100,
                        "colour": "white" if "white" in self._geometry["colours"]
                        else next(iter(self._geometry["colours"])), "brightness": 1.0}
        except DeviceError:
            self._link.close()
            raise
        except (ValueError, KeyError, TypeError) as exc:
            self._link.close()
            raise self._error(DeviceProtocolError, f"unexpected reply while opening: {exc}",
                              "check that the firmware is illuminate v1.3x") from exc
        except BaseException:
            self._link.close()
            raise

    def _set_geometry(self, positions: dict[str, Sequence[float]]) -> None:
        n = int(self.parameters["led_count"])
        xyz = np.array([positions[str(i)] for i in range(n)], dtype=float)
        if self._shape is not None and self._shape[0] * self._shape[1] != n:
            raise self._error(DeviceValueError, f"the array has {n} LEDs, shape {self._shape} "
                              f"expects {self._shape[0] * self._shape[1]}",
                              "fix shape in the bench file, or check the port")
        pitch = self._pitch
        if pitch is None:
            d = np.hypot(*(xyz[:, None, :2] - xyz[None, :, :2]).transpose(2, 0, 1))
            np.fill_diagonal(d, np.inf)
            pitch = float(np.median(d.min(axis=1)))
        channels = list(self.parameters.get("color_channels", ["w"]))
        wl = self.parameters.get("color_channel_center_wavelengths", {}) or {}
        colours: dict[str, float | None] = {}
        for c in channels:
            w = wl.get(c)
            w = None if w is None else float(w) * (1000.0 if float(w) < 10 else 1.0)  # um->nm
            colours[_CHANNEL_NAMES.get(c, c)] = w
        if len(channels) >= 3:
            colours["white"] = None
        self._channels = channels
        self._geometry = {"positions_mm": xyz[:, :2], "pitch_mm": pitch,
                          "distance_mm": self._distance or float(np.median(xyz[:, 2])),
                          "colours": colours}

    def _clear(self) -> None:
        self.command("x", 0.5)

    def _do_get_info(self) -> dict[str, Any]:
        return dict(self._geometry)

    def _do_apply(self, name: str, value: Any) -> Any:
        if name == "na_illum" and value < 1.0:  # keep the firmware's own patterns in step
            hundredths = max(1, round(value * 100))
            got = self._expect(f"na.{hundredths:02d}", "NA.")
            if int(got) != hundredths:
                raise self._error(DeviceProtocolError, f"NA read back as {got}, sent "
                                  f"{hundredths}", "check the firmware")
        self._hw[name] = value
        return None

    # ----------------------------------------------------------- display
    def _rgb(self, colour: str, brightness: float) -> list[int]:
        level = round(255 * brightness)
        if len(self._channels) < 3:
            return [level]
        if colour == "white":
            return [level] * 3
        return [level if _CHANNEL_NAMES.get(c) == colour else 0 for c in self._channels[:3]]

    def _do_show(self, state: dict[int, tuple[str, float]], timeout_s: float) -> None:
        self.command("x", timeout_s)
        groups: dict[tuple[str, float], list[int]] = {}
        for i, key in sorted(state.items()):
            groups.setdefault(key, []).append(i)
        for (colour, brightness), leds in groups.items():
            self._expect("sc." + ".".join(map(str, self._rgb(colour, brightness))), "CO.")
            for k in range(0, len(leds), _MAX_ARGS):
                self.command("l." + ".".join(map(str, leds[k:k + _MAX_ARGS])), timeout_s)

    def _do_status(self) -> dict[str, Any]:
        return {**super()._do_status(), "port": self._link.path,
                "serial_number": self.parameters.get("serial_number")}

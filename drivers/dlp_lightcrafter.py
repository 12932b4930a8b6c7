"""TI DLP LightCrafter 4500 (DLPC350 controller) as a :class:`~drivers.dmd.Dmd`, over USB HID.

Transport: hidapi (cython-hidapi, ``pip install hidapi``), USB 0451:6401, 64-byte
reports written with the report id 0 (:class:`~drivers.transports.HidLink`); the
kernel's hidraw driver stays bound, no detach. ``transport="pyusb"`` uses pyusb on the
interrupt endpoints 0x01/0x81 instead (:class:`~drivers.transports.UsbLink`, the
kernel driver detached). Notes: docs/drivers/dlp-lightcrafter.md.

Message (TI DLPC350 programmer's guide): ``flags`` (bit 7 read, bit 6 reply wanted,
bit 5 set by the device on NACK), ``sequence`` (echoed), ``length`` (u16 LE: the
bytes that follow), the command word little-endian (CMD3 then CMD2), the payload;
zero-padded to 64 bytes, longer messages continued in raw 64-byte reports. Every
write asks for a reply, so a refused command (NACK) raises
:class:`~drivers.errors.DeviceProtocolError` at once; replies carrying another
sequence number (late answers) are skipped.

Commands used: LED currents (0x0B01, PWM 0-255 per colour), main status (0x1A0C),
display mode (0x1A1B: 1 = pattern mode), pattern source (0x1A22: 3 flash, 0 video),
trigger mode (0x1A23), start/stop (0x1A24: 2 start, 0 stop), exposure and period
(0x1A29, u32 microseconds each), pattern configuration (0x1A31), the mailbox
(0x1A32-0x1A34: pattern LUT entries, image LUT), LED enables (0x1A07) and
validation (0x1A1A, polled until not busy). The controller requires exposure ==
period or period - exposure >= 230 us, and a stopped sequence while its
configuration changes: changing the exposure of a running sequence stops it,
re-validates and starts it again.
"""

from __future__ import annotations

import struct
import threading
import time
from typing import Any

from drivers.dmd import Dmd, PatternEntry
from drivers.errors import DeviceProtocolError, DeviceValueError
from drivers.transports import HidLink, UsbLink

__all__ = ["LightCrafter4500", "pattern_lut_entry"]

VENDOR_ID, PRODUCT_ID = 0x0451, 0x6401
#: LED colours of the LightCrafter 4500 (OSRAM LEDs), nm; and their select bits.
COLOURS: dict[str, float] = {"red": 624.0, "green": 520.0, "blue": 455.0}
_LED_BITS = {"red": 0x1, "green": 0x2, "blue": 0x4}
_VALIDATION = {0x01: "exposure or frame period out of range",
               0x02: "pattern numbers out of range for their bit depth",
               0x10: "frame period - exposure is under 230 us"}
_MIN_DARK_US = 230


def pattern_lut_entry(entry: PatternEntry, *, first_of_image: bool) -> bytes:
    """The 3 mailbox bytes of one pattern LUT entry (DLPC350 command 0x1A34).

    Byte 0: trigger type (bits 1:0; 0 internal for the first pattern of an image,
    3 = continue) and pattern number (bits 7:2); byte 1: bit depth (bits 3:0) and
    LED select (bits 7:4: red, green, blue); byte 2: invert (bit 0), buffer swap
    (bit 2) when the pattern starts a new image.
    """
    trig = 0 if first_of_image else 3
    return bytes([trig | (entry.bit << 2), entry.bit_depth | (_LED_BITS[entry.colour] << 4),
                  int(entry.invert) | (int(first_of_image) << 2)])


class LightCrafter4500(Dmd):
    """A DLP LightCrafter 4500 evaluation module driven as a pattern sequencer.

    Parameters
    ----------
    device_id : str
        Name of the DMD.
    serial_number : str, optional
        USB serial number of the unit to open (when several are plugged in).
    reply_timeout_s : float
        Longest wait for one reply (TI's host waits 2 s).
    validation_timeout_s : float
        Longest wait for the sequence validation to finish.
    transport : {"hidapi", "pyusb"}
        hidapi through the kernel's hidraw driver (default), or pyusb (libusb) on the
        interrupt endpoints with the kernel driver detached.
    hid_backend, usb_backend : module-like, optional
        Replace ``import hid`` / ``import usb`` (tests pass an emulator's fakes).
    """

    def __init__(self, device_id: str, *, serial_number: str | None = None,
                 reply_timeout_s: float = 2.0, validation_timeout_s: float = 2.0,
                 transport: str = "hidapi", hid_backend: Any = None,
                 usb_backend: Any = None) -> None:
        super().__init__(device_id)
        self._reply_timeout = self._float("reply_timeout_s", reply_timeout_s, low=0.0,
                                          low_open=True)
        self._validation_timeout = self._float("validation_timeout_s", validation_timeout_s,
                                               low=0.0, low_open=True)
        transport = self._choice("transport", transport, ("hidapi", "pyusb"))
        ids = {"vendor_id": VENDOR_ID, "product_id": PRODUCT_ID, "serial_number": serial_number,
               "interface": 0, "timeout_error": self.timeout_error}
        self._link = (HidLink(device_id, hid_module=hid_backend, **ids) if transport == "hidapi"
                      else UsbLink(device_id, usb_module=usb_backend, **ids))
        self._seq = 0
        self._command_lock = threading.RLock()
        self._hw: dict[str, Any] = {}
        self.version: bytes = b""

    # ----------------------------------------------------------- protocol
    def command(self, cmd: int, payload: bytes = b"", *, read: bool = False,
                timeout_s: float | None = None) -> bytes:
        """Send one command and return the reply's data (empty for a write).

        Parameters
        ----------
        cmd : int
            Command word ``CMD2 << 8 | CMD3`` (e.g. 0x1A24).
        payload : bytes
            Parameters of a write (or of a read that takes some).
        read : bool
            A read request (the reply carries data).

        Raises
        ------
        DeviceProtocolError
            The controller refused the command (NACK) or a read returned no data.
        DmdTimeoutError
            No reply within the timeout.

        Notes
        -----
        Safe from several threads: one command and its reply at a time (a reply read
        by another thread would be skipped there as a late one and lost here).
        """
        with self._command_lock:
            return self._exchange(cmd, payload, read, timeout_s)

    def _exchange(self, cmd: int, payload: bytes, read: bool,
                  timeout_s: float | None) -> bytes:
        self._seq = (self._seq + 1) & 0xFF
        flags = 0xC0 if read else 0x40
        msg = bytes([flags, self._seq]) + struct.pack("<HH", 2 + len(payload), cmd) + payload
        for k in range(0, len(msg), 64):
            self._link.write(msg[k:k + 64])
        deadline = time.monotonic() + (timeout_s or self._reply_timeout)
        while True:
            report = self._link.read(max(deadline - time.monotonic(), 1e-3))
            if len(report) < 4 or report[1] != self._seq:
                continue  # a late reply to an earlier command
            length = struct.unpack_from("<H", report, 2)[0]
            if report[0] & 0x20:
                raise self._error(DeviceProtocolError,
                                  f"the controller refused command 0x{cmd:04X} "
                                  f"(payload {payload.hex(' ') or 'none'}): NACK",
                                  "check the value and the mode (stop the sequence before "
                                  "changing its configuration)")
            if read and length == 0:
                raise self._error(DeviceProtocolError, f"read 0x{cmd:04X} returned no data",
                                  "check the controller firmware")
            return bytes(report[4:4 + length])

    def main_status(self) -> int:
        """Main status byte (0x1A0C): bit 0 DMD parked, bit 1 sequencer running, bit 2
        frame buffer frozen, bit 3 gamma correction on."""
        return self.command(0x1A0C, read=True)[0]

    # ----------------------------------------------------------- lifecycle hooks
    def _do_open(self, timeout_s: float) -> None:
        self._link.open()
        try:
            self.version = self.command(0x0205, read=True, timeout_s=min(timeout_s, 5.0))
            self.command(0x1A24, b"\x00")  # a known state: sequence stopped
            exposure_us, period_us = struct.unpack("<II", self.command(0x1A29, read=True)[:8])
            currents = self.command(0x0B01, read=True)[:3]
            self._hw = {"exposure_s": exposure_us / 1e6, "period_s": period_us / 1e6,
                        "led_currents": {c: v / 255 for c, v in zip(COLOURS, currents,
                                                                      strict=True)}}
        except BaseException:
            self._link.close()
            raise

    def _do_close(self) -> None:
        self._link.close()

    def _do_get_info(self) -> dict[str, Any]:
        return {"resolution": (1140, 912), "colours": dict(COLOURS), "max_entries": 128,
                "max_image": 63, "sources": ("flash", "video")}

    def _do_get_settings(self) -> dict[str, Any]:
        return {k: (dict(v) if isinstance(v, dict) else v) for k, v in self._hw.items()}

    def _check_settings(self, pending: dict[str, Any]) -> None:
        super()._check_settings(pending)
        exp, per = round(pending["exposure_s"] * 1e6), round(pending["period_s"] * 1e6)
        if exp != per and per - exp < _MIN_DARK_US:
            raise self._error(DeviceValueError, f"period_s - exposure_s = {per - exp} us",
                              "make the exposure equal to the period, or at least 230 us "
                              "shorter (a DLPC350 rule)")

    def _do_apply(self, name: str, value: Any) -> Any:
        if name == "led_currents":
            pwm = bytes(round(255 * value[c]) for c in COLOURS)
            self.command(0x0B01, pwm)
            back = self.command(0x0B01, read=True)[:3]
            if back != pwm:
                raise self._error(DeviceProtocolError, f"LED currents read back as "
                                  f"{list(back)}, sent {list(pwm)}", "check the controller")
            self._hw[name] = {c: v / 255 for c, v in zip(COLOURS, back, strict=True)}
            return self._hw[name]
        pair = {"exposure_s": self._hw["exposure_s"], "period_s": self._hw["period_s"],
                name: value}
        running = self._do_running()
        if running:
            self.command(0x1A24, b"\x00")
        us = (round(pair["exposure_s"] * 1e6), round(pair["period_s"] * 1e6))
        self.command(0x1A29, struct.pack("<II", *us))
        self._hw["exposure_s"], self._hw["period_s"] = us[0] / 1e6, us[1] / 1e6
        if running:
            self.validate()
            self.command(0x1A24, b"\x02")
        return self._hw[name]

    # ----------------------------------------------------------- sequences
    def _do_load(self, entries: tuple[PatternEntry, ...], repeat: bool, source: str,
                 timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        images = [] if source == "video" else list(dict.fromkeys(e.image for e in entries))
        n = len(entries)
        self.command(0x1A24, b"\x00")  # stop
        self.command(0x1A1B, b"\x01")  # pattern mode
        self.command(0x1A22, b"\x03" if source == "flash" else b"\x00")
        self.command(0x1A31, bytes([n - 1, int(repeat), n - 1, len(images)]))
        self.command(0x1A23, b"\x01" if source == "flash" else b"\x00")
        us = (round(self._hw["exposure_s"] * 1e6), round(self._hw["period_s"] * 1e6))
        self.command(0x1A29, struct.pack("<II", *us))
        self.command(0x1A07, b"\x0f")  # the sequencer switches the LEDs
        self.command(0x1A33, b"\x02")  # pattern LUT mailbox
        previous = None
        for i, entry in enumerate(entries):
            self.command(0x1A32, bytes([i]))
            self.command(0x1A34, pattern_lut_entry(entry, first_of_image=entry.image != previous))
            previous = entry.image
        self.command(0x1A33, b"\x00")
        if images:
            self.command(0x1A33, b"\x01")  # image LUT mailbox
            self.command(0x1A32, b"\x00")
            for image in images:
                self.command(0x1A34, bytes([image, 0, 0]))
            self.command(0x1A33, b"\x00")
        self.validate(max(deadline - time.monotonic(), self._reply_timeout))

    def validate(self, timeout_s: float | None = None) -> None:
        """Have the controller validate the loaded sequence (0x1A1A), wait while it is
        busy, and raise on a failure.

        Raises
        ------
        DeviceProtocolError
            The controller found the sequence invalid (the reasons named).
        DmdTimeoutError
            Still busy after the timeout.
        """
        self.command(0x1A1A)
        deadline = time.monotonic() + (timeout_s or self._validation_timeout)
        while True:
            status = self.command(0x1A1A, read=True)[0]
            if not status & 0x80:
                break
            if time.monotonic() > deadline:
                raise self._timeout("the pattern sequence validation did not finish",
                                    "check the controller; reload the sequence")
            time.sleep(0.005)
        problems = [text for bit, text in _VALIDATION.items() if status & bit]
        if problems:
            raise self._error(DeviceProtocolError, "the controller rejected the sequence: "
                              + "; ".join(problems) + f" (status 0x{status:02X})",
                              "fix the exposure/period or the pattern entries")
        if status & 0x0C:
            self._log.warning("%s: sequence validation warnings (status 0x%02X)",
                              self.device_id, status)

    def _do_start(self, timeout_s: float) -> None:
        self.command(0x1A24, b"\x02", timeout_s=timeout_s)
        if not self.main_status() & 0x02:
            raise self._error(DeviceProtocolError, "the sequencer did not start",
                              "reload the sequence")

    def _do_stop(self, timeout_s: float) -> None:
        self.command(0x1A24, b"\x00", timeout_s=timeout_s)

    def _do_running(self) -> bool:
        return bool(self.main_status() & 0x02)

    def _do_status(self) -> dict[str, Any]:
        return {**super()._do_status(), "main_status": self.main_status()}

"""TI DLP LightCrafter 4500 (DLPC350 controller) as a :class:`~drivers.dmd.Dmd`, over USB HID.

Transport: hidapi (cython-hidapi, ``pip install hidapi``), USB 0451:6401, 64-byte
reports written with the report id 0 (:class:`~drivers.usb_transports.HidLink`).
``transport="hidapi"`` uses the package's ``hid`` module, built on libusb: it detaches
the kernel's usbhid driver from interface 0 and claims it while open (a second
program's claim is refused). ``transport="hidraw"`` uses the same package's ``hidraw``
module: the kernel's hidraw driver stays bound. ``transport="pyusb"`` uses pyusb on
the interrupt endpoints 0x01/0x81 (:class:`~drivers.usb_transports.UsbLink`, the
kernel driver detached). Whichever transport, the unit is locked while open
(:class:`~drivers.device_access.DeviceLock`, by its serial number): replies are
matched by sequence number only, so a second program on the unit is refused, named.
Notes: docs/drivers/dlp-lightcrafter.md.

Message (TI DLPC350 programmer's guide): ``flags`` (bit 7 read, bit 6 reply wanted,
bit 5 set by the device on NACK), ``sequence`` (echoed), ``length`` (u16 LE: the
bytes that follow), the command word little-endian (CMD3 then CMD2), the payload;
zero-padded to 64 bytes, longer messages continued in raw 64-byte reports. Every
write asks for a reply, so a refused command (NACK) raises
:class:`~drivers.errors.DeviceProtocolError` at once; replies carrying another
sequence number (late answers) are skipped.

Commands used (framing and payloads checked against TI's host code,
``dlpc350_api.cpp``, and the LightCrafter modules of slstudio, QDSpy and
pycrafter4500; docs/drivers/dlp-lightcrafter.md has the verification matrix):
LED PWM polarity (0x1A05, set to normal at open) and LED currents (0x0B01, one byte
per colour written as ``255 - pwm``: the EVM's LED drivers invert the PWM, as
slstudio and QDSpy write them), main status (0x1A0C), display mode (0x1A1B: 1 =
pattern mode), pattern source (0x1A22: 3 flash, 0 video), trigger mode (0x1A23),
start/stop (0x1A24: 2 start, 0 stop), exposure and period (0x1A29, u32 microseconds
each), pattern configuration (0x1A31: entries - 1, repeat, patterns - 1, images - 1;
the firmware takes 0-based counts), the mailbox (0x1A33 open/close, 0x1A32 address,
0x1A34 data: the whole pattern LUT as one message of 3 bytes per entry, the image
LUT as one message of 1 byte per image, the two entries of a 2-image LUT in swapped
order as TI's ``DLPC350_SendImageLut`` sends them), LED enables (0x1A07) and
validation (0x1A1A with one data byte, polled until not busy). After a stop, a mode
change and a start the driver polls the state until the controller reports it (the
controller takes a moment to switch). The controller requires exposure == period or
period - exposure >= 230 us, and a stopped sequence while its configuration changes:
changing the exposure of a running sequence stops it, re-validates and starts it
again.
"""

from __future__ import annotations

import struct
import threading
import time
from typing import Any

from drivers.dmd import Dmd, PatternEntry
from drivers.errors import DeviceProtocolError, DeviceValueError
from drivers.usb_transports import HidLink, UsbLink

__all__ = ["LightCrafter4500", "image_lut_payload", "led_pwm", "pattern_lut_entry"]

VENDOR_ID, PRODUCT_ID = 0x0451, 0x6401
#: LED colours of the LightCrafter 4500 (OSRAM LEDs), nm; and their select bits.
COLOURS: dict[str, float] = {"red": 624.0, "green": 520.0, "blue": 455.0}
_LED_BITS = {"red": 0x1, "green": 0x2, "blue": 0x4}
_VALIDATION = {0x01: "exposure or frame period out of range",
               0x02: "pattern numbers out of range for their bit depth",
               0x10: "frame period - exposure is under 230 us"}
_MIN_DARK_US = 230
#: Pause between two reads of a state (mode, sequencer) the driver waits for, s.
_STATE_POLL_S = 0.005


def led_pwm(fraction: float) -> int:
    """The 0x0B01 byte for an LED current ``fraction`` (0 off .. 1 full) with the PWM
    polarity normal (0x1A05 = 0): the EVM's LED drivers invert the PWM, so the byte is
    ``255 - round(255 * fraction)`` (slstudio's ``ProjectorLC4500``, QDSpy's
    ``setLEDCurrents``)."""
    return 255 - round(255 * float(fraction))


def image_lut_payload(images: list[int]) -> bytes:
    """The MBOX_DATA (0x1A34) payload of an image LUT: one byte per flash image index,
    the two entries of a 2-entry LUT swapped (TI ``DLPC350_SendImageLut``)."""
    return bytes([images[1], images[0]] if len(images) == 2 else images)


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
    transport : {"hidapi", "hidraw", "pyusb"}
        hidapi's ``hid`` module (default; libusb: the kernel driver detached and the
        interface claimed while open), hidapi's ``hidraw`` module (the kernel's hidraw
        driver stays bound), or pyusb (libusb) on the interrupt endpoints with the
        kernel driver detached.
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
        transport = self._choice("transport", transport, ("hidapi", "hidraw", "pyusb"))
        ids = {"vendor_id": VENDOR_ID, "product_id": PRODUCT_ID, "serial_number": serial_number,
               "interface": 0, "timeout_error": self.timeout_error}
        self._link = (UsbLink(device_id, usb_module=usb_backend, **ids) if transport == "pyusb"
                      else HidLink(device_id, hid_module=hid_backend, **ids,
                                   module="hid" if transport == "hidapi" else "hidraw"))
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
            self._stop_sequence(timeout_s)  # a known state: sequence stopped
            self.command(0x1A05, b"\x00")  # PWM polarity normal (the currents map below)
            exposure_us, period_us = struct.unpack("<II", self.command(0x1A29, read=True)[:8])
            currents = self.command(0x0B01, read=True)[:3]
            self._hw = {"exposure_s": exposure_us / 1e6, "period_s": period_us / 1e6,
                        "led_currents": self._fractions(currents)}
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
            pwm = bytes(led_pwm(value[c]) for c in COLOURS)
            self.command(0x0B01, pwm)
            back = self.command(0x0B01, read=True)[:3]
            if back != pwm:
                raise self._error(DeviceProtocolError, f"LED currents read back as "
                                  f"{list(back)}, sent {list(pwm)}", "check the controller")
            self._hw[name] = self._fractions(back)
            return self._hw[name]
        pair = {"exposure_s": self._hw["exposure_s"], "period_s": self._hw["period_s"],
                name: value}
        running = self._do_running()
        if running:
            self._stop_sequence(self._reply_timeout)
        us = (round(pair["exposure_s"] * 1e6), round(pair["period_s"] * 1e6))
        self.command(0x1A29, struct.pack("<II", *us))
        self._hw["exposure_s"], self._hw["period_s"] = us[0] / 1e6, us[1] / 1e6
        if running:
            self.validate()
            self._do_start(self._reply_timeout)
        return self._hw[name]

    @staticmethod
    def _fractions(pwm: bytes) -> dict[str, float]:
        return {c: (255 - v) / 255 for c, v in zip(COLOURS, pwm, strict=True)}

    def _await(self, read: Any, want: Any, what: str, timeout_s: float) -> None:
        """Poll ``read()`` until it returns ``want`` (the controller switches a mode or
        the sequencer a moment after the command), or raise the timeout error."""
        deadline = time.monotonic() + timeout_s
        while True:
            got = read()
            if got == want:
                return
            if time.monotonic() > deadline:
                raise self._timeout(f"the controller still reports {what} = {got!r} "
                                    f"{timeout_s:g} s after the change (wanted {want!r})",
                                    "check the controller's status; reconnect it")
            time.sleep(_STATE_POLL_S)

    def _stop_sequence(self, timeout_s: float) -> None:
        self.command(0x1A24, b"\x00")
        self._await(self._do_running, False, "sequencer running", timeout_s)

    # ----------------------------------------------------------- sequences
    def _do_load(self, entries: tuple[PatternEntry, ...], repeat: bool, source: str,
                 timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        images = [] if source == "video" else list(dict.fromkeys(e.image for e in entries))
        n = len(entries)
        self._stop_sequence(timeout_s)
        self.command(0x1A1B, b"\x01")  # pattern mode
        self._await(lambda: self.command(0x1A1B, read=True)[0] & 1, 1, "display mode",
                    max(deadline - time.monotonic(), self._reply_timeout))
        self.command(0x1A22, b"\x03" if source == "flash" else b"\x00")
        # 0-based counts (TI DLPC350_SetPatternConfig: "firmware command takes 0-based
        # indices"); the image count is irrelevant for the video source
        self.command(0x1A31, bytes([n - 1, int(repeat), n - 1, max(len(images), 1) - 1]))
        self.command(0x1A23, b"\x01" if source == "flash" else b"\x00")
        us = (round(self._hw["exposure_s"] * 1e6), round(self._hw["period_s"] * 1e6))
        self.command(0x1A29, struct.pack("<II", *us))
        self.command(0x1A07, b"\x0f")  # the sequencer switches the LEDs
        lut, previous = bytearray(), None
        for entry in entries:
            lut += pattern_lut_entry(entry, first_of_image=entry.image != previous)
            previous = entry.image
        self._mailbox(2, bytes(lut))  # pattern LUT: one message, 3 bytes per entry
        if images:
            self._mailbox(1, image_lut_payload(images))  # image LUT: 1 byte per image
        self.validate(max(deadline - time.monotonic(), self._reply_timeout))

    def _mailbox(self, box: int, data: bytes) -> None:
        """Open mailbox ``box`` (1 image LUT, 2 pattern LUT), write ``data`` from address
        0 as one MBOX_DATA message, close it (TI DLPC350_SendPatLut/SendImageLut)."""
        self.command(0x1A33, bytes([box]))
        self.command(0x1A32, b"\x00")
        self.command(0x1A34, data)
        self.command(0x1A33, b"\x00")

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
        self.command(0x1A1A, b"\x00")
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
        self._await(self._do_running, True, "sequencer running", timeout_s)

    def _do_stop(self, timeout_s: float) -> None:
        self._stop_sequence(timeout_s)

    def _do_running(self) -> bool:
        return bool(self.main_status() & 0x02)

    def _do_status(self) -> dict[str, Any]:
        return {**super()._do_status(), "main_status": self.main_status()}

"""Emulator of a TI DLP LightCrafter 4500 (DLPC350) behind a fake hidapi module.

Written from the DLPC350 host protocol as summarised in hardware-protocols.md,
section 3b, and checked against TI's host code (``dlpc350_api.cpp`` as copied in
slstudio) and the clients labs use (pycrafter4500, QDSpy): it takes their framing
and refuses bytes they would not send.

- :class:`FakeHid` has the surface of cython-hidapi's ``hid`` module
  (``enumerate(vid, pid)``, ``device()`` with ``open_path``, ``write``, ``read``,
  ``close``); ``write`` is hidapi's ``hid_write``: the first byte is the report id,
  which the DLPC350 (no numbered reports) takes as 0 and hidapi does not send, while a
  non-zero first byte is sent as data; what is sent reaches the controller as reports
  of at most 64 bytes (the interrupt OUT packets), a shorter one as it is, so a write
  without its report id loses a leading 0 byte; like cython-hidapi, ``write`` returns
  -1 (it does not raise) once the device is unplugged, ``read(max_length, timeout_ms)``
  takes whole milliseconds (a float is truncated, as Cython's ``int`` parameter does:
  0.5 becomes 0), returns a list of ints, empty on timeout, blocks until a report comes
  when ``timeout_ms`` is 0 or less (``hid_read``), and raises ``OSError`` after an
  unplug; both raise ``ValueError("not open")`` on a handle not open.
  As the wheel's ``hid`` module (libusb, the default ``backend``), an open detaches
  the usbhid driver and claims the interface (``usbhid_bound`` false, ``claimed`` set
  until closed) and a second open while it is claimed fails with ``OSError("open
  failed")``; as the ``hidraw`` module, the kernel driver stays bound and any number of
  handles may be open;
- :class:`FakeUsb` has the surface of pyusb (``core.find``, ``core.USBError``,
  ``core.USBTimeoutError``, ``util.claim_interface`` ...) for the same controller on
  its interrupt endpoints 0x01 / 0x81 (``USBError`` with errno 19 after an unplug,
  ``USBTimeoutError`` on timeout, the kernel driver attached until detached; like
  pyusb, a read or write claims the interface itself once no kernel driver holds it);
  as libusb, a timeout is whole milliseconds (a float raises ``TypeError``, as ctypes
  does; 0 waits for ever) and a read buffer shorter than the 64-byte packet raises
  ``USBError("Overflow")`` (errno 75) and loses the packet;
- a message is ``flags, sequence, length (u16 LE), CMD3, CMD2, payload``, continued
  in further 64-byte reports when longer (reassembled by the length field); a reply
  comes only when the flags ask for one (bit 6) or for a read (bit 7): ``flags | 0x20``
  (NACK) on error, the same sequence, the length of the data, data from byte 4;
- NACK for an unknown command, a wrong payload length (0x1A1A takes one byte), or a
  command not allowed in the current state (pattern configuration, exposure or
  mailbox while the sequence runs; start before a successful validation);
- the mailbox (0x1A33 open, 0x1A32 address, 0x1A34 data): a data message writes its
  entries from the address, which then advances past them, so TI's framing (the
  whole LUT in one message, 3 bytes per pattern entry, 1 byte per image index) and
  one entry per message (pycrafter4500, QDSpy) both work; a 2-byte image LUT message
  holds its entries swapped (TI's ``DLPC350_SendImageLut`` sends them so);
- validation (write 0x1A1A) is busy for ``validation_polls`` reads of 0x1A1A, then
  reports bit 0 (exposure longer than the period), bit 1 (bad pattern numbers, fewer
  pattern LUT entries written than configured, or, with the flash source, an image LUT
  of another length than the configured image count) and bit 4 (period - exposure <
  230 us);
- a display mode change and a start/stop take ``settle_polls`` reads to show in the
  status reads (0x1A1B, 0x1A0C, 0x1A24), as a controller that takes a moment;
- LED currents (0x0B01) are PWM bytes; with the PWM polarity normal (0x1A05 = 0, the
  power-up state) the EVM's LED drivers invert them (:meth:`led_fractions`).
"""

from __future__ import annotations

import math
import struct
import threading
import time
from collections import deque

__all__ = ["Dlpc350Emulator", "FakeHid", "FakeUsb"]

VID, PID = 0x0451, 0x6401
#: Bytes of the controller's HID reports (in and out), the interrupt endpoints' packet size.
REPORT_SIZE = 64
#: Payload length of each command the emulator knows, by command word (CMD2 << 8 | CMD3).
#: ``None``: variable (the mailbox data).
PAYLOAD: dict[int, int | None] = {
    0x0200: 1, 0x0205: 0, 0x0609: 1, 0x0B01: 3, 0x100A: 1, 0x1A00: 1, 0x1A05: 1,
    0x1A07: 1, 0x1A0A: 0, 0x1A0B: 0, 0x1A0C: 0, 0x1A0E: 1, 0x1A1A: 1, 0x1A1B: 1, 0x1A22: 1,
    0x1A23: 1, 0x1A24: 1, 0x1A29: 8, 0x1A31: 4, 0x1A32: 1, 0x1A33: 1, 0x1A34: None,
}
_LOCKED_WHILE_RUNNING = {0x1A29, 0x1A31, 0x1A32, 0x1A33, 0x1A34, 0x1A22, 0x1A23, 0x1A1B}


class Dlpc350Emulator:
    """The state machine of a DLPC350 controller.

    Parameters
    ----------
    serial_number : str
        Reported by ``enumerate``.
    validation_polls : int
        Reads of 0x1A1A that still show "busy" after a validation request.
    reply_latency_s : float
        Delay before a reply can be read (a full-speed USB interrupt endpoint is polled
        every 1 ms; 0 answers at once).
    settle_polls : int
        Status reads after a display mode change or a start/stop that still show the
        previous state.
    """

    def __init__(self, serial_number: str = "LC4500-0001", validation_polls: int = 2,
                 reply_latency_s: float = 0.0, settle_polls: int = 1) -> None:
        self.serial_number = serial_number
        self.validation_polls = int(validation_polls)
        self.reply_latency_s = float(reply_latency_s)
        self.settle_polls = int(settle_polls)
        self.lock = threading.Lock()
        self.plugged = True
        self.claimed: object | None = None  # the libusb handle holding interface 0
        self.usbhid_bound = True  # the kernel's HID driver (detached by libusb)
        self.standby = False
        self.display_mode = 0  # 0 video, 1 pattern
        self.input_source = 0
        self.led_enables = 0x0F
        self.led_currents = [104, 135, 130]
        self.pwm_invert = 0
        self.gamma = 0
        self.parked = False
        self.frozen = False
        self.pattern_source = 0
        self.trigger_mode = 0
        self.exposure_us, self.period_us = 8333, 8333
        self.pattern_config = (0, 0, 0, 0)
        self.mailbox = 0
        self.mailbox_address = 0
        self.pattern_lut: list[bytes] = [bytes(3)] * 128
        self.image_lut: list[int] = [0] * 64
        self.written = {1: 0, 2: 0}  # entries written since each mailbox was opened
        self._shown = {"mode": 0, "running": False}  # what the status reads report
        self._settle = {"mode": 0, "running": 0}
        self.validation_status = 0x00
        self.validated = False
        self._busy_polls = 0
        self.running = False
        self.replies: deque[tuple[float, bytes]] = deque()  # (readable from, report)
        self.log: list[tuple[int, bytes]] = []  # (command, payload) of every message
        self.reports: list[bytes] = []  # every 64-byte report written
        self._partial: bytearray | None = None
        self._partial_need = 0
        self.drop = 0
        self.held = 0  # replies still to be held back (hold_replies)
        self.cond = threading.Condition(self.lock)

    # ------------------------------------------------------------------ faults
    def unplug(self) -> None:
        """Disconnect: open handles fail, ``enumerate`` finds nothing."""
        with self.lock:
            self.plugged = False
            self.claimed, self.usbhid_bound = None, True  # gone with the device
            self.cond.notify_all()

    def replug(self) -> None:
        """Connect again (the controller kept its state: USB only)."""
        with self.lock:
            self.plugged = True
            self.replies.clear()

    def drop_replies(self, n: int = 1) -> None:
        """Lose the next ``n`` replies (the driver's reads time out)."""
        with self.lock:
            self.drop += int(n)

    def hold_replies(self, n: int = 1) -> None:
        """Hold the next ``n`` replies back until :meth:`release_replies`: a controller
        answering after the driver's read timed out (the reply arrives late, ahead of the
        replies to later commands)."""
        with self.lock:
            self.held += int(n)

    def release_replies(self) -> None:
        """Make the held replies readable now, in the order they were queued."""
        with self.lock:
            now = time.monotonic()
            self.replies = deque((now if t == math.inf else t, r) for t, r in self.replies)
            self.cond.notify_all()

    def next_reply(self, deadline: float) -> bytes | None:
        """Wait (holding :attr:`cond`) for the oldest reply until ``deadline``
        (``time.monotonic()``; ``math.inf``: no timeout); None on timeout. Raises
        OSError once unplugged."""
        while True:
            if not self.plugged:
                raise OSError("the device is unplugged")
            now = time.monotonic()
            if self.replies and self.replies[0][0] <= now:
                return self.replies.popleft()[1]
            left = deadline - now
            if left <= 0:
                return None
            if self.replies:
                left = min(left, self.replies[0][0] - now)
            self.cond.wait(None if left == math.inf else left)  # inf: hid_read blocks

    # ------------------------------------------------------------------ transport
    def feed(self, report: bytes) -> None:
        """One report from the host as it arrived (64 bytes; a short packet as it is)."""
        self.reports.append(bytes(report))
        if self._partial is not None:  # continuation of a long message
            self._partial += report
            if len(self._partial) >= self._partial_need:
                msg = bytes(self._partial[:self._partial_need])
                self._partial = None
                self._message(msg)
            return
        if len(report) < 4:
            return  # no header: nothing the firmware can frame
        need = 4 + struct.unpack_from("<H", report, 2)[0]
        if need > len(report):
            self._partial, self._partial_need = bytearray(report), need
            return
        self._message(bytes(report[:need]))

    def _message(self, msg: bytes) -> None:
        flags, seq, length = msg[0], msg[1], struct.unpack_from("<H", msg, 2)[0]
        if length < 2:
            self._reply(flags, seq, b"", nack=True)
            return
        cmd = msg[5] << 8 | msg[4]
        payload = msg[6:4 + length]
        self.log.append((cmd, payload))
        read = bool(flags & 0x80)
        data, ok = self._execute(cmd, payload, read)
        if read or flags & 0x40:
            self._reply(flags, seq, data if ok else b"", nack=not ok)

    def _reply(self, flags: int, seq: int, data: bytes, *, nack: bool) -> None:
        if self.drop > 0:
            self.drop -= 1
            return
        out = bytes([flags | (0x20 if nack else 0), seq]) + struct.pack("<H", len(data)) + data
        ready = time.monotonic() + self.reply_latency_s
        if self.held > 0:
            self.held -= 1
            ready = math.inf
        self.replies.append((ready, out.ljust(64, b"\0")))
        self.cond.notify_all()

    # ------------------------------------------------------------------ commands
    def _execute(self, cmd: int, p: bytes, read: bool) -> tuple[bytes, bool]:
        if cmd not in PAYLOAD:
            return b"", False
        if read:
            return self._read(cmd)
        if PAYLOAD[cmd] is not None and len(p) != PAYLOAD[cmd]:
            return b"", False
        if self.running and cmd in _LOCKED_WHILE_RUNNING:
            return b"", False
        simple = {0x0B01: "led_currents", 0x1A00: "input_source", 0x1A07: "led_enables",
                  0x1A22: "pattern_source", 0x1A23: "trigger_mode", 0x1A0E: "gamma",
                  0x1A05: "pwm_invert"}
        if cmd in simple:
            setattr(self, simple[cmd], list(p) if cmd == 0x0B01 else p[0])
        elif cmd == 0x0200:
            self.standby = bool(p[0])
        elif cmd == 0x0609:
            self.parked = bool(p[0] & 1)
        elif cmd == 0x100A:
            self.frozen = bool(p[0] & 1)
        elif cmd == 0x1A1B:
            self.display_mode = p[0] & 1
            self._settle["mode"] = self.settle_polls
            self.validated = False
        elif cmd == 0x1A24:
            return self._sequence_control(p[0])
        elif cmd == 0x1A29:
            self.exposure_us, self.period_us = struct.unpack("<II", p)
            self.validated = False
        elif cmd == 0x1A31:
            self.pattern_config = (p[0] & 0x7F, p[1], p[2], p[3])
            self.validated = False
        elif cmd == 0x1A32:
            self.mailbox_address = p[0]
        elif cmd == 0x1A33:
            if p[0] > 3:
                return b"", False
            self.mailbox = p[0]
            self.mailbox_address = 0
            if p[0] in self.written:
                self.written[p[0]] = 0
        elif cmd == 0x1A34:
            return self._mailbox_data(p)
        elif cmd == 0x1A1A:
            self._busy_polls = self.validation_polls
            self.validation_status = self._validate()
            self.validated = self.validation_status & 0x13 == 0
        return b"", True

    def _status_read(self, key: str) -> object:
        """What a status read shows: the previous state until ``settle_polls`` reads
        after the change have passed."""
        if self._settle[key] > 0:
            self._settle[key] -= 1
        else:
            self._shown[key] = self.display_mode if key == "mode" else self.running
        return self._shown[key]

    def _read(self, cmd: int) -> tuple[bytes, bool]:
        if cmd == 0x0205:
            return struct.pack("<IIII", 0x02070100, 0x00000000, 0x03000200, 0), True
        if cmd == 0x1A0C:
            running = bool(self._status_read("running"))
            status = (int(self.parked) | int(running) << 1 | int(self.frozen) << 2
                      | int(bool(self.gamma & 0x80)) << 3)
            return bytes([status]), True
        if cmd == 0x1A24:
            return bytes([2 if self._status_read("running") else 0]), True
        if cmd == 0x1A1B:
            return bytes([int(self._status_read("mode"))]), True
        if cmd in (0x1A0A, 0x1A0B):
            return bytes([0x01]), True  # initialisation done, no errors / memory ok
        if cmd == 0x1A1A:
            if self._busy_polls > 0:
                self._busy_polls -= 1
                return bytes([0x80]), True
            return bytes([self.validation_status]), True
        if cmd == 0x1A29:
            return struct.pack("<II", self.exposure_us, self.period_us), True
        if cmd == 0x1A31:
            return bytes(self.pattern_config), True
        single = {0x0200: lambda: int(self.standby), 0x1A05: lambda: self.pwm_invert,
                  0x1A07: lambda: self.led_enables, 0x1A22: lambda: self.pattern_source,
                  0x1A23: lambda: self.trigger_mode, 0x1A0E: lambda: self.gamma}
        if cmd in single:
            return bytes([single[cmd]()]), True
        if cmd == 0x0B01:
            return bytes(self.led_currents), True
        return b"", False

    def _sequence_control(self, op: int) -> tuple[bytes, bool]:
        if op == 2:
            if self.display_mode != 1 or not self.validated:
                return b"", False
            self.running = True
        elif op in (0, 1):
            self.running = False
        else:
            return b"", False
        self._settle["running"] = self.settle_polls
        return b"", True

    def _mailbox_data(self, p: bytes) -> tuple[bytes, bool]:
        """Entries from the current address, the address advancing past them."""
        if self.mailbox == 2:
            if not p or len(p) % 3 or self.mailbox_address + len(p) // 3 > 128:
                return b"", False
            for k in range(0, len(p), 3):
                self.pattern_lut[self.mailbox_address] = bytes(p[k:k + 3])
                self.mailbox_address += 1
            self.written[2] += len(p) // 3
        elif self.mailbox == 1:
            if not p or self.mailbox_address + len(p) > 64:
                return b"", False
            entries = [p[1], p[0]] if len(p) == 2 else list(p)  # TI's 2-entry order
            for image in entries:
                self.image_lut[self.mailbox_address] = image
                self.mailbox_address += 1
            self.written[1] += len(entries)
        else:
            return b"", False
        self.validated = False
        return b"", True

    def _validate(self) -> int:
        bits = 0
        if self.exposure_us > self.period_us:
            bits |= 0x01
        if self.exposure_us != self.period_us and self.period_us - self.exposure_us < 230:
            bits |= 0x10
        n = self.pattern_config[0] + 1
        for entry in self.pattern_lut[:n]:
            depth = (entry[1] & 0x0F) or 1
            if (entry[0] >> 2) > 24 // depth - 1 or not 1 <= depth <= 8:
                bits |= 0x02
        if self.written[2] < n:
            bits |= 0x02  # configured entries never written
        if self.pattern_source == 3 and self.written[1] != self.pattern_config[3] + 1:
            bits |= 0x02  # image LUT length is not the configured image count
        return bits

    def led_fractions(self) -> list[float]:
        """The LED currents the EVM drives, as fractions of full (red, green, blue): its
        LED drivers invert the PWM, so with the polarity normal (0x1A05 = 0) a byte b
        gives ``(255 - b) / 255``, with it inverted ``b / 255`` (slstudio and QDSpy
        write ``255 - current``; this needs a real EVM to confirm)."""
        return [(b if self.pwm_invert & 1 else 255 - b) / 255 for b in self.led_currents]

    def lut_entries(self) -> list[dict[str, int]]:
        """The pattern LUT as loaded: ``[{"pattern", "bit_depth", "leds", "invert",
        "swap"}]`` for the configured number of entries (a test helper)."""
        n = self.pattern_config[0] + 1
        return [{"pattern": e[0] >> 2, "trigger": e[0] & 3, "bit_depth": e[1] & 0x0F,
                 "leds": e[1] >> 4, "invert": e[2] & 1, "swap": (e[2] >> 2) & 1}
                for e in self.pattern_lut[:n]]


class FakeHid:
    """A stand-in for the ``hid`` module (cython-hidapi) serving one :class:`Dlpc350Emulator`.

    ``backend``: ``"libusb"`` (the wheel's ``hid`` module: exclusive claim) or
    ``"hidraw"`` (its ``hidraw`` module: shared)."""

    def __init__(self, emulator: Dlpc350Emulator | None = None,
                 backend: str = "libusb") -> None:
        if backend not in ("libusb", "hidraw"):
            raise ValueError(f"backend={backend!r}: 'libusb' or 'hidraw'")
        self.emulator = emulator or Dlpc350Emulator()
        self.backend = backend

    def enumerate(self, vendor_id: int = 0, product_id: int = 0) -> list[dict]:
        """Like ``hid.enumerate``: the emulated device while plugged in."""
        emu = self.emulator
        if not emu.plugged or (vendor_id, product_id) not in ((0, 0), (VID, PID)):
            return []
        return [{"path": b"fake-hidraw0", "vendor_id": VID, "product_id": PID,
                 "serial_number": emu.serial_number, "interface_number": 0,
                 "product_string": "DLPC350"}]

    def device(self) -> _FakeDevice:
        """Like ``hid.device()``."""
        return _FakeDevice(self.emulator, self.backend == "libusb")


class _FakeDevice:
    def __init__(self, emu: Dlpc350Emulator, claims: bool) -> None:
        self.emu = emu
        self.claims = claims
        self.opened = False

    def open_path(self, path: bytes) -> None:
        with self.emu.lock:
            if not self.emu.plugged or (self.claims and self.emu.claimed is not None):
                raise OSError("open failed")  # cython-hidapi's words for any refusal
            if self.claims:
                self.emu.claimed, self.emu.usbhid_bound = self, False
            self.opened = True

    def write(self, data) -> int:
        data = bytes(data)
        with self.emu.lock:
            if not self.opened:
                raise ValueError("not open")  # cython-hidapi's words
            if not (data and self.emu.plugged):
                return -1  # hid_write's failure (an unplug, "Zero buffer/length"): no raise
            # hid_write: data[0] is the report id; 0 (no numbered reports) is not sent,
            # anything else is (hidapi strips only a 0)
            wire = data[1:] if data[0] == 0 else data
            for k in range(0, len(wire), REPORT_SIZE):  # interrupt OUT packets
                self.emu.feed(wire[k:k + REPORT_SIZE])
        return len(data)

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        # cython-hidapi's ``int`` parameters: a float is truncated (0.5 -> 0); a timeout
        # of 0 or less is hid_read, which blocks until a report comes (or an unplug)
        max_length, timeout_ms = int(max_length), int(timeout_ms)
        deadline = time.monotonic() + timeout_ms / 1000 if timeout_ms > 0 else math.inf
        with self.emu.cond:
            if not self.opened:
                raise ValueError("not open")
            try:
                report = self.emu.next_reply(deadline)
            except OSError:
                raise OSError("read error") from None
            return [] if report is None else list(report[:max_length])  # hid_read truncates

    def close(self) -> None:
        with self.emu.lock:
            if self.emu.claimed is self:
                self.emu.claimed, self.emu.usbhid_bound = None, True
            self.opened = False


class _UsbError(OSError):
    def __init__(self, strerror, error_code=None, errno=None):
        super().__init__(errno, strerror)
        self.backend_error_code = error_code


class _UsbTimeoutError(_UsbError):
    pass


class FakeUsb:
    """A stand-in for the ``usb`` package (pyusb) serving one :class:`Dlpc350Emulator`."""

    def __init__(self, emulator: Dlpc350Emulator | None = None) -> None:
        self.emulator = emulator or Dlpc350Emulator()
        self.kernel_driver = True
        fake = self

        class core:  # noqa: N801 (module-like namespace)
            USBError = _UsbError
            USBTimeoutError = _UsbTimeoutError

            @staticmethod
            def find(idVendor=None, idProduct=None, custom_match=None, **kw):  # noqa: N803
                if not fake.emulator.plugged or (idVendor, idProduct) != (VID, PID):
                    return None
                dev = _FakeUsbDevice(fake)
                return dev if custom_match is None or custom_match(dev) else None

        class util:  # noqa: N801
            @staticmethod
            def get_string(dev, index, langid=None):
                return fake.emulator.serial_number if index == dev.iSerialNumber else ""

            @staticmethod
            def claim_interface(dev, interface):
                if fake.kernel_driver:
                    raise _UsbError("Resource busy", errno=16)
                dev.claimed = True

            @staticmethod
            def release_interface(dev, interface):
                dev.claimed = False

            @staticmethod
            def dispose_resources(dev):
                dev.claimed = False

        self.core, self.util = core, util


class _FakeUsbDevice:
    iSerialNumber = 3

    def __init__(self, fake: FakeUsb) -> None:
        self.fake = fake
        self.emu = fake.emulator
        self.claimed = False

    def is_kernel_driver_active(self, interface: int) -> bool:
        return self.fake.kernel_driver

    def detach_kernel_driver(self, interface: int) -> None:
        self.fake.kernel_driver = False

    def attach_kernel_driver(self, interface: int) -> None:
        self.fake.kernel_driver = True

    def set_configuration(self) -> None:
        if not self.emu.plugged:
            raise _UsbError("No such device (it may have been disconnected)", errno=19)

    def _auto_claim(self) -> None:
        """pyusb claims the interface itself on the first transfer (and fails while a
        kernel driver holds it)."""
        if not self.claimed and not self.fake.kernel_driver:
            self.claimed = True

    def reset(self) -> None:
        """Like ``usb.core.Device.reset``: the interface is released."""
        self.claimed = False

    @staticmethod
    def _timeout_s(timeout: int | None) -> float:
        """Seconds of pyusb's ``timeout`` in ms (None: its default 1000 ms) as libusb
        takes it: a C unsigned int (a float is refused, as ctypes refuses it), 0 = no
        timeout (inf)."""
        if timeout is None:
            return 1.0
        if not isinstance(timeout, int) or isinstance(timeout, bool) or timeout < 0:
            raise TypeError(f"timeout {timeout!r}: libusb takes whole milliseconds "
                            "(ctypes.ArgumentError: wrong type)")
        return math.inf if timeout == 0 else timeout / 1000

    def write(self, endpoint: int, data, timeout: int | None = None) -> int:
        self._timeout_s(timeout)
        self._auto_claim()
        with self.emu.lock:
            if not (self.claimed and self.emu.plugged) or endpoint != 0x01:
                raise _UsbError("No such device (it may have been disconnected)", errno=19)
            self.emu.feed(bytes(data)[:64])
        return len(data)

    def read(self, endpoint: int, size: int, timeout: int | None = None) -> bytes:
        self._auto_claim()
        deadline = time.monotonic() + self._timeout_s(timeout)
        with self.emu.cond:
            if not self.claimed or endpoint != 0x81:
                raise _UsbError("No such device (it may have been disconnected)", errno=19)
            try:
                report = self.emu.next_reply(deadline)
            except OSError:
                raise _UsbError("No such device (it may have been disconnected)",
                                errno=19) from None
            if report is None:
                raise _UsbTimeoutError("Operation timed out", errno=110)
            if len(report) > size:  # libusb: a packet larger than the buffer is lost
                raise _UsbError("Overflow", error_code=-8, errno=75)  # EOVERFLOW
            return report

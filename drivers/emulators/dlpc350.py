"""Emulator of a TI DLP LightCrafter 4500 (DLPC350) behind a fake hidapi module.

Written from the DLPC350 host protocol as summarised in hardware-protocols.md,
section 3b, and its emulator spec (a fake transport, not a pty):

- :class:`FakeHid` has the surface of cython-hidapi's ``hid`` module
  (``enumerate(vid, pid)``, ``device()`` with ``open_path``, ``write``, ``read``,
  ``close``); ``write`` takes 65 bytes (report id 0 + 64) or 64; ``read(size,
  timeout_ms)`` returns a list of ints, empty on timeout, and raises ``OSError`` after
  an unplug, like hidapi;
- :class:`FakeUsb` has the surface of pyusb (``core.find``, ``core.USBError``,
  ``core.USBTimeoutError``, ``util.claim_interface`` ...) for the same controller on
  its interrupt endpoints 0x01 / 0x81 (``USBError`` with errno 19 after an unplug,
  ``USBTimeoutError`` on timeout, the kernel driver attached until detached);
- a message is ``flags, sequence, length (u16 LE), CMD3, CMD2, payload``, continued
  in further 64-byte reports when longer (reassembled by the length field); a reply
  comes only when the flags ask for one (bit 6) or for a read (bit 7): ``flags | 0x20``
  (NACK) on error, the same sequence, the length of the data, data from byte 4;
- NACK for an unknown command, a wrong payload length, or a command not allowed in
  the current state (pattern configuration, exposure or mailbox while the sequence
  runs; start before a successful validation);
- validation (write 0x1A1A) is busy for ``validation_polls`` reads of 0x1A1A, then
  reports bit 0 (exposure longer than the period), bit 1 (bad pattern numbers or
  LUT size) and bit 4 (period - exposure < 230 us).
"""

from __future__ import annotations

import struct
import threading
import time
from collections import deque

__all__ = ["Dlpc350Emulator", "FakeHid", "FakeUsb"]

VID, PID = 0x0451, 0x6401
#: Payload length of each command the emulator knows, by command word (CMD2 << 8 | CMD3).
PAYLOAD = {
    0x0200: 1, 0x0205: 0, 0x0B01: 3, 0x1A00: 1, 0x1A07: 1, 0x1A0A: 0, 0x1A0B: 0, 0x1A0C: 0,
    0x1A1A: 0, 0x1A1B: 1, 0x1A22: 1, 0x1A23: 1, 0x1A24: 1, 0x1A29: 8, 0x1A31: 4, 0x1A32: 1,
    0x1A33: 1, 0x1A34: 3,
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
    """

    def __init__(self, serial_number: str = "LC4500-0001", validation_polls: int = 2,
                 reply_latency_s: float = 0.0) -> None:
        self.serial_number = serial_number
        self.validation_polls = int(validation_polls)
        self.reply_latency_s = float(reply_latency_s)
        self.lock = threading.Lock()
        self.plugged = True
        self.standby = False
        self.display_mode = 0  # 0 video, 1 pattern
        self.input_source = 0
        self.led_enables = 0x0F
        self.led_currents = [104, 135, 130]
        self.pattern_source = 0
        self.trigger_mode = 0
        self.exposure_us, self.period_us = 8333, 8333
        self.pattern_config = (0, 0, 0, 0)
        self.mailbox = 0
        self.mailbox_address = 0
        self.pattern_lut: list[bytes] = [bytes(3)] * 128
        self.image_lut: list[int] = [0] * 64
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
        self.cond = threading.Condition(self.lock)

    # ------------------------------------------------------------------ faults
    def unplug(self) -> None:
        """Disconnect: open handles fail, ``enumerate`` finds nothing."""
        with self.lock:
            self.plugged = False
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

    def next_reply(self, deadline: float) -> bytes | None:
        """Wait (holding :attr:`cond`) for the oldest reply until ``deadline``
        (``time.monotonic()``); None on timeout. Raises OSError once unplugged."""
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
            self.cond.wait(left)

    # ------------------------------------------------------------------ transport
    def feed(self, report: bytes) -> None:
        """One report from the host (64 bytes, report id removed)."""
        self.reports.append(bytes(report))
        if self._partial is not None:  # continuation of a long message
            self._partial += report
            if len(self._partial) >= self._partial_need:
                msg = bytes(self._partial[:self._partial_need])
                self._partial = None
                self._message(msg)
            return
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
        self.replies.append((time.monotonic() + self.reply_latency_s, out.ljust(64, b"\0")))
        self.cond.notify_all()

    # ------------------------------------------------------------------ commands
    def _execute(self, cmd: int, p: bytes, read: bool) -> tuple[bytes, bool]:
        if cmd not in PAYLOAD:
            return b"", False
        if read:
            return self._read(cmd)
        if len(p) != PAYLOAD[cmd] and cmd != 0x1A1A:
            return b"", False
        if self.running and cmd in _LOCKED_WHILE_RUNNING:
            return b"", False
        if cmd == 0x0200:
            self.standby = bool(p[0])
        elif cmd == 0x0B01:
            self.led_currents = list(p)
        elif cmd == 0x1A00:
            self.input_source = p[0]
        elif cmd == 0x1A07:
            self.led_enables = p[0]
        elif cmd == 0x1A1B:
            self.display_mode = p[0] & 1
            self.validated = False
        elif cmd == 0x1A22:
            self.pattern_source = p[0]
        elif cmd == 0x1A23:
            self.trigger_mode = p[0]
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
            self.mailbox = p[0]
        elif cmd == 0x1A34:
            return self._mailbox_data(p)
        elif cmd == 0x1A1A:
            self._busy_polls = self.validation_polls
            self.validation_status = self._validate()
            self.validated = self.validation_status & 0x13 == 0
        else:
            return b"", False
        return b"", True

    def _read(self, cmd: int) -> tuple[bytes, bool]:
        if cmd == 0x0205:
            return struct.pack("<IIII", 0x02070100, 0x00000000, 0x03000200, 0), True
        if cmd == 0x1A0C:
            status = (int(not self.running)) | (int(self.running) << 1)
            return bytes([status]), True
        if cmd == 0x1A0A:
            return bytes([0x01]), True  # initialisation done, no errors
        if cmd == 0x1A0B:
            return bytes([0x01]), True
        if cmd == 0x1A1A:
            if self._busy_polls > 0:
                self._busy_polls -= 1
                return bytes([0x80]), True
            return bytes([self.validation_status]), True
        if cmd == 0x0B01:
            return bytes(self.led_currents), True
        if cmd == 0x1A29:
            return struct.pack("<II", self.exposure_us, self.period_us), True
        if cmd == 0x1A1B:
            return bytes([self.display_mode]), True
        if cmd == 0x1A24:
            return bytes([2 if self.running else 0]), True
        if cmd == 0x1A31:
            return bytes(self.pattern_config), True
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
        return b"", True

    def _mailbox_data(self, p: bytes) -> tuple[bytes, bool]:
        if self.mailbox == 2 and self.mailbox_address < 128:
            self.pattern_lut[self.mailbox_address] = bytes(p)
            self.mailbox_address += 1
        elif self.mailbox == 1 and self.mailbox_address < 64:
            self.image_lut[self.mailbox_address] = p[0]
            self.mailbox_address += 1
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
        return bits

    def lut_entries(self) -> list[dict[str, int]]:
        """The pattern LUT as loaded: ``[{"pattern", "bit_depth", "leds", "invert",
        "swap"}]`` for the configured number of entries (a test helper)."""
        n = self.pattern_config[0] + 1
        return [{"pattern": e[0] >> 2, "trigger": e[0] & 3, "bit_depth": e[1] & 0x0F,
                 "leds": e[1] >> 4, "invert": e[2] & 1, "swap": (e[2] >> 2) & 1}
                for e in self.pattern_lut[:n]]


class FakeHid:
    """A stand-in for the ``hid`` module (cython-hidapi) serving one :class:`Dlpc350Emulator`."""

    def __init__(self, emulator: Dlpc350Emulator | None = None) -> None:
        self.emulator = emulator or Dlpc350Emulator()

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
        return _FakeDevice(self.emulator)


class _FakeDevice:
    def __init__(self, emu: Dlpc350Emulator) -> None:
        self.emu = emu
        self.opened = False

    def open_path(self, path: bytes) -> None:
        if not self.emu.plugged:
            raise OSError("open failed")
        self.opened = True

    def write(self, data) -> int:
        data = bytes(data)
        with self.emu.lock:
            if not (self.opened and self.emu.plugged):
                raise OSError("write error")
            if len(data) == 65:
                data = data[1:]  # the report id
            if len(data) != 64:
                return -1
            self.emu.feed(data)
        return 65

    def read(self, size: int, timeout_ms: int = 0) -> list[int]:
        deadline = time.monotonic() + timeout_ms / 1000
        with self.emu.cond:
            if not self.opened:
                raise OSError("read error")
            try:
                report = self.emu.next_reply(deadline)
            except OSError:
                raise OSError("read error") from None
            return [] if report is None else list(report[:size])

    def close(self) -> None:
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

    def write(self, endpoint: int, data, timeout: int) -> int:
        with self.emu.lock:
            if not (self.claimed and self.emu.plugged) or endpoint != 0x01:
                raise _UsbError("No such device (it may have been disconnected)", errno=19)
            self.emu.feed(bytes(data)[:64])
        return len(data)

    def read(self, endpoint: int, size: int, timeout: int) -> bytes:
        deadline = time.monotonic() + timeout / 1000
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
            return report[:size]

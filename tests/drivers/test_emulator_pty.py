"""The protocol emulators' pty base: what a driver reads is already in the record of what
the emulator sent (byte-exact tests clear ``sent`` and then look at it)."""

from __future__ import annotations

import os
import time

import serial

from drivers.emulators import _pty
from drivers.emulators._pty import PtyEmulator


class _Echo(PtyEmulator):
    """Replies ``OK`` to every line."""

    def on_bytes(self, data: bytes) -> None:
        if data.endswith(b"\n"):
            self.reply(b"OK\r\n")


def test_a_reply_is_recorded_before_the_driver_can_read_it(monkeypatch):
    real_write = os.write

    def slow_write(fd, data):  # the emulator thread loses the CPU right after writing
        n = real_write(fd, data)
        time.sleep(0.05)
        return n

    monkeypatch.setattr(_pty.os, "write", slow_write)
    with _Echo() as emulator, serial.Serial(emulator.tty, timeout=5.0) as port:
        for _ in range(3):
            emulator.sent.clear()
            port.write(b"PING\n")
            got = b""
            while not got.endswith(b"OK\r\n"):
                byte = port.read(1)
                assert byte, "no reply within 5 s"
                got += byte
                assert bytes(emulator.sent).startswith(got)  # recorded already
            assert got == b"OK\r\n"

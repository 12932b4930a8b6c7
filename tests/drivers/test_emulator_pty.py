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


def test_bytes_with_no_reply_are_waited_for_not_slept_for(monkeypatch):
    """A write with no reply reaches ``received`` when the emulator's thread reads it:
    ``wait_received`` waits for that (a fixed sleep failed in a loaded full run)."""
    import threading

    real_select = _pty.select.select
    release = threading.Event()

    def late_select(*args):  # the emulator's thread gets no core until released
        if threading.current_thread().name == "_Echo":
            release.wait(10.0)
        return real_select(*args)

    monkeypatch.setattr(_pty.select, "select", late_select)
    with _Echo() as emulator, serial.Serial(emulator.tty, timeout=5.0) as port:
        port.write(b"STOP")  # no newline: no reply
        assert b"STOP" not in emulator.received  # not read yet
        assert not emulator.wait_received(b"STOP", timeout_s=0.05)
        release.set()
        assert emulator.wait_received(b"STOP")

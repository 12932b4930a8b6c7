"""Transports: serial port resolution by serial number, deadlines, unplug, modem lines."""

from __future__ import annotations

import errno
import os
import sys
import time
import types

import pytest
import serial
from serial.tools import list_ports

from drivers.errors import (
    DeviceDisconnectedError,
    LedArrayTimeoutError,
    MissingDependencyError,
)
from drivers.transports import (
    SerialLink,
    find_serial_port,
    import_optional,
    set_modem_line,
)
from drivers.usb_transports import HidLink
from tests.mocks import IlluminateEmulator


def test_serial_number_from_list_ports_first(monkeypatch, tmp_path):
    info = types.SimpleNamespace(device="/dev/ttyUSB7", serial_number="27500101")
    monkeypatch.setattr(list_ports, "comports", lambda: [info])
    (tmp_path / "usb-Thorlabs_27500101-if00-port0").symlink_to("/dev/null")
    assert find_serial_port("27500101", [tmp_path]) == "/dev/ttyUSB7"


def test_serial_number_in_link_directory_as_a_whole_word(monkeypatch, tmp_path):
    monkeypatch.setattr(list_ports, "comports", lambda: [])
    (tmp_path / "usb-Thorlabs_275001012-if00-port0").symlink_to("/dev/null")
    assert find_serial_port("27500101", [tmp_path]) is None  # not a prefix match
    (tmp_path / "usb-Thorlabs_27500101-if00-port0").symlink_to("/dev/null")
    assert find_serial_port("27500101", [tmp_path, "/no/such/dir"]).endswith(
        "27500101-if00-port0")
    (tmp_path / "usb-Dead_999-if00").symlink_to(tmp_path / "gone")  # a dangling link
    assert find_serial_port("999", [tmp_path]) is None


def test_modem_lines_are_guarded_on_a_pty():
    master, slave = os.openpty()
    try:
        port = serial.Serial(os.ttyname(slave), timeout=0.1)
        assert set_modem_line(port, "rts", True) is False  # ENOTTY on a pty: ignored
        port.close()
    finally:
        os.close(master)
        os.close(slave)

    class Broken:
        @property
        def rts(self):
            return True

        @rts.setter
        def rts(self, value):
            raise OSError(errno.EIO, "Input/output error")

    with pytest.raises(OSError):
        set_modem_line(Broken(), "rts", True)


def test_read_deadline_and_unplug():
    with IlluminateEmulator((2, 2)) as emu:
        link = SerialLink("leds", port=emu.port, timeout_error=LedArrayTimeoutError)
        link.open()
        link.write(b"machine\n")
        assert link.read_until(b"-==-\n", 1.0) == b"-==-\n"
        emu.drop_replies(1)
        link.write(b"ver\n")
        t0 = time.monotonic()
        with pytest.raises(LedArrayTimeoutError, match="within 0.2 s"):
            link.read_until(b"-==-\n", 0.2)
        assert 0.2 <= time.monotonic() - t0 < 30.0  # waited its 0.2 s; 30 s: a hang guard
        emu.unplug()
        with pytest.raises(DeviceDisconnectedError, match="reconnect"):
            link.read_until(b"-==-\n", 5.0)
        assert not link.is_open
        link.close()  # idempotent on a vanished port


def test_absent_serial_number_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setattr(list_ports, "comports", lambda: [])
    link = SerialLink("stage", serial_number="27999999", search_dirs=[str(tmp_path)])
    with pytest.raises(DeviceDisconnectedError, match="27999999.*plug it in"):
        link.open()


def test_missing_library_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "usb", None)
    with pytest.raises(MissingDependencyError, match=r"pyusb.*diffuserlab\[hardware\]"):
        import_optional("usb", "dmd")


def test_hid_module_of_the_other_package_is_named():
    other_hid = types.SimpleNamespace(Device=object)  # PyPI "hid" (ctypes) has Device
    link = HidLink("dmd", vendor_id=0x0451, product_id=0x6401, hid_module=other_hid)
    with pytest.raises(MissingDependencyError, match="pip install hidapi"):
        link.open()


def _pty_link():
    master, slave = os.openpty()
    link = SerialLink("stage", port=os.ttyname(slave), timeout_error=LedArrayTimeoutError)
    link.open()
    return master, slave, link


def _until_readable(fd: int, n: int, hang_guard_s: float = 10.0) -> None:
    """Wait until ``n`` bytes can be read at ``fd``: a pty hands a write to its other
    side a moment later (a kernel worker), later still on a loaded machine."""
    import fcntl
    import struct
    import termios

    deadline = time.monotonic() + hang_guard_s
    while struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0" * 4))[0] < n:
        assert time.monotonic() < deadline, f"{n} bytes never reached the pty's other side"
        time.sleep(0.002)


def test_a_reader_late_past_its_deadline_takes_what_came_meanwhile():
    # a thread descheduled past its deadline (a loaded machine) must not call a device
    # silent whose reply is waiting in the port: it looks once more before the timeout
    master, slave, link = _pty_link()
    try:
        os.write(master, b"ok\nabcd")
        _until_readable(slave, 7)  # both replies arrived; the deadline (0 s) has passed
        assert link.read_until(b"\n", 0.0) == b"ok\n"
        assert link.read_exactly(4, 0.0) == b"abcd"
        with pytest.raises(LedArrayTimeoutError, match="within 0 s"):
            link.read_until(b"\n", 0.0)  # nothing came: still a timeout
    finally:
        link.close()
        os.close(master)
        os.close(slave)


def test_a_writer_descheduled_after_its_bytes_went_out_is_not_a_lost_port(monkeypatch):
    # pyserial checks its write timeout after the bytes went out: a writing thread that
    # waited 2.5 s for a core (measured: over 5 s beside two busy loops) used to turn a
    # working stage into "unplugged: Write timeout"
    master, slave, link = _pty_link()
    real_write, port_fd = os.write, link._serial.fileno()

    def stalled(fd, data):
        n = real_write(fd, data)
        if fd == port_fd:
            time.sleep(2.5)
        return n

    try:
        monkeypatch.setattr(os, "write", stalled)
        link.write(b"hello\n")
        monkeypatch.setattr(os, "write", real_write)
        assert link.is_open and os.read(master, 64) == b"hello\n"
    finally:
        link.close()
        os.close(master)
        os.close(slave)

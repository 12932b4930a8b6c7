"""The USB report links (drivers/usb_transports.py): hidapi and pyusb share one
``write`` and ``read``, each giving only its transfers and the errors of a lost device."""

from __future__ import annotations

import threading

import pytest

from drivers.device_access import LOCK_DIR_ENV
from drivers.emulators import Dlpc350Emulator, FakeHid, FakeUsb
from drivers.errors import DeviceDisconnectedError, DmdTimeoutError
from drivers.usb_transports import HidLink, UsbLink

IDS = dict(vendor_id=0x0451, product_id=0x6401, timeout_error=DmdTimeoutError)


def _hid(emu):
    return HidLink("dmd", hid_module=FakeHid(emu), **IDS)


def _usb(emu):
    return UsbLink("dmd", usb_module=FakeUsb(emu), **IDS)


@pytest.fixture(autouse=True)
def _locks(tmp_path, monkeypatch):
    monkeypatch.setenv(LOCK_DIR_ENV, str(tmp_path / "locks"))


@pytest.mark.parametrize("cls", [HidLink, UsbLink])
def test_write_and_read_are_written_once(cls):
    assert "write" not in vars(cls) and "read" not in vars(cls)


@pytest.mark.parametrize("make", [_hid, _usb])
def test_an_unplugged_device_is_lost_on_write_and_the_link_closed(make):
    emu = Dlpc350Emulator()
    link = make(emu)
    link.open()
    emu.unplug()
    with pytest.raises(DeviceDisconnectedError, match="I/O failed"):
        link.write(b"\x01\x02")
    assert not link.is_open
    with pytest.raises(DeviceDisconnectedError, match="not open"):
        link.read(0.05)


def _guarded(emu, call, *, hang_s: float = 20.0):
    """Run ``call()`` in a thread; a hang guard only: if it is still running after
    ``hang_s`` the emulator is unplugged (releasing a blocked read) and the test fails."""
    out: dict = {}

    def run():
        try:
            out["value"] = call()
        except BaseException as exc:  # handed to the test
            out["error"] = exc

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(hang_s)
    if worker.is_alive():
        emu.unplug()
        worker.join(hang_s)
        pytest.fail(f"the read still blocked after {hang_s} s (no timeout handed to it)")
    if "error" in out:
        raise out["error"]
    return out["value"]


VERSION_READ = bytes([0xC0, 1, 2, 0, 0x05, 0x02])  # read 0x0205, sequence 1


@pytest.mark.parametrize("make", [_hid, _usb])
def test_a_reply_later_than_a_few_ms_is_read_within_a_timeout_in_seconds(make):
    """hidapi's and libusb's timeouts are milliseconds: a 1 s read handed on as "1"
    (seconds taken for ms) would give up after 1 ms, before a reply 20 ms late."""
    emu = Dlpc350Emulator(reply_latency_s=0.02)
    link = make(emu)
    link.open()
    try:
        link.write(VERSION_READ)
        report = _guarded(emu, lambda: link.read(5.0))
        assert report[:2] == bytes([0xC0, 1]) and len(report) == 64
    finally:
        link.close()


@pytest.mark.parametrize(("make", "hint"), [
    (_hid, "not in a firmware-update mode"), (_usb, "check that the device is powered")])
def test_a_silent_device_times_out_with_the_links_hint(make, hint):
    """FakeHid blocks as hid_read does when no timeout is given: a read without its
    timeout would hang here (the guard unplugs the emulator and fails the test)."""
    emu = Dlpc350Emulator()
    link = make(emu)
    link.open()
    try:
        emu.drop_replies(1)
        link.write(VERSION_READ)
        with pytest.raises(DmdTimeoutError, match=hint):
            _guarded(emu, lambda: link.read(0.05))
        assert link.is_open
    finally:
        link.close()


class _UnplugsBeforeReplying(Dlpc350Emulator):
    """A controller unplugged after it took a request, before its reply."""

    def _message(self, msg: bytes) -> None:
        self.plugged = False
        self.cond.notify_all()


@pytest.mark.parametrize("make", [_hid, _usb])
def test_a_read_failing_mid_reply_is_a_disconnection_and_closes_the_link(make):
    emu = _UnplugsBeforeReplying()
    link = make(emu)
    link.open()
    link.write(VERSION_READ)
    with pytest.raises(DeviceDisconnectedError, match="I/O failed") as caught:
        _guarded(emu, lambda: link.read(5.0))
    assert "powered" not in str(caught.value)  # not the silent device's hint
    assert not link.is_open


def test_a_hid_write_returning_minus_one_is_a_transport_error():
    """cython-hidapi's write returns -1 on failure, it does not raise."""
    emu = Dlpc350Emulator()
    link = _hid(emu)
    link.open()
    emu.unplug()
    assert link._dev.write(b"\0" + VERSION_READ) == -1  # the fake is as hidapi
    with pytest.raises(DeviceDisconnectedError, match=r"returned -1"):
        link.write(VERSION_READ)
    assert not link.is_open


def test_fake_usb_overflows_as_libusb_on_a_short_buffer():
    """libusb: a packet larger than the read buffer is LIBUSB_ERROR_OVERFLOW, the
    packet lost; a float timeout is refused (ctypes' unsigned int)."""
    fake = FakeUsb(Dlpc350Emulator())
    dev = fake.core.find(idVendor=0x0451, idProduct=0x6401)
    dev.detach_kernel_driver(0)  # the first transfer claims the interface, as pyusb
    dev.write(0x01, VERSION_READ.ljust(64, b"\0"), 1000)
    with pytest.raises(fake.core.USBError, match="Overflow") as caught:
        dev.read(0x81, 63, 1000)
    assert caught.value.errno == 75
    with pytest.raises(fake.core.USBTimeoutError):  # the packet was lost
        dev.read(0x81, 64, 10)
    with pytest.raises(TypeError, match="whole milliseconds"):
        dev.read(0x81, 64, 1.0)


def test_fake_hid_takes_whole_milliseconds_and_blocks_without_a_timeout():
    # the reply comes 3 s late: a 1 ms read right after the write cannot see it even on a
    # loaded machine (with 20 ms, a stall between write and read at load 30 let it through)
    emu = Dlpc350Emulator(reply_latency_s=3.0)
    fake = FakeHid(emu)
    dev = fake.device()
    dev.open_path(fake.enumerate()[0]["path"])
    dev.write(b"\0" + VERSION_READ)
    assert dev.read(64, 1.0) == []  # 1.0 is 1 ms: the reply is 3 s late
    assert len(_guarded(emu, lambda: dev.read(64))) == 64  # no timeout: waits for it
    emu.drop_replies(1)
    dev.write(b"\0" + VERSION_READ)
    errors = []
    reader = threading.Thread(target=lambda: errors.append(_raised(lambda: dev.read(64))))
    reader.start()
    reader.join(0.2)
    assert reader.is_alive()  # no reply, no timeout: hid_read blocks
    emu.unplug()
    reader.join(20)
    assert isinstance(errors[0], OSError) and "read error" in str(errors[0])


def _raised(call):
    try:
        call()
    except Exception as exc:
        return exc
    return None

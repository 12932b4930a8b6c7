"""The USB report links (drivers/usb_transports.py): hidapi and pyusb share one
``write`` and ``read``, each giving only its transfers and the errors of a lost device."""

from __future__ import annotations

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


@pytest.mark.parametrize(("make", "hint"), [
    (_hid, "not in a firmware-update mode"), (_usb, "check that the device is powered")])
def test_a_silent_device_times_out_with_the_links_hint(make, hint):
    link = make(Dlpc350Emulator())
    link.open()
    try:
        with pytest.raises(DmdTimeoutError, match=hint):
            link.read(0.05)
        assert link.is_open
    finally:
        link.close()


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

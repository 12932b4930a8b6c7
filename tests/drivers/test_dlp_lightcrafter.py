"""LightCrafter 4500 (DLPC350) DMD driver against the fake HID transport."""

from __future__ import annotations

import struct
import sys

import pytest

from drivers.dlp_lightcrafter import LightCrafter4500, pattern_lut_entry
from drivers.dmd import PatternEntry
from drivers.errors import (
    DeviceDisconnectedError,
    DeviceProtocolError,
    DeviceValueError,
    MissingDependencyError,
)
from tests.drivers.conformance import DmdConformance
from tests.mocks import Dlpc350Emulator, FakeHid, FakeUsb


@pytest.fixture
def hid():
    return FakeHid(Dlpc350Emulator(validation_polls=2))


def make(hid, **kw):
    kw.setdefault("reply_timeout_s", 30.0)  # a hang guard: a loaded host answers late
    return LightCrafter4500("dmd", hid_backend=hid, **kw)


class TestLightCrafterConformance(DmdConformance):
    @pytest.fixture
    def device(self, hid):
        self.emu = hid.emulator
        with make(hid) as dmd:
            yield dmd

    def provoke_timeout(self, device):
        self.emu.drop_replies(1)
        self.wait_lost_reply(device)


def test_byte_exact_reports(hid):
    emu = hid.emulator
    with make(hid) as dmd:
        emu.reports.clear()
        # PWM bytes 100, 120, 140 (the notes' worked example): the EVM inverts the PWM, so
        # they are currents (255 - b) / 255 (slstudio and QDSpy write 255 - current)
        dmd.led_currents = {"red": 155 / 255, "green": 135 / 255, "blue": 115 / 255}
        seq = emu.reports[0][1]
        assert emu.reports[0] == bytes([0x40, seq, 0x05, 0x00, 0x01, 0x0B, 0x64, 0x78, 0x8C])\
            .ljust(64, b"\0")
        assert emu.pwm_invert == 0  # set at open: the mapping above holds
        assert emu.led_fractions() == pytest.approx([155 / 255, 135 / 255, 115 / 255])
        assert emu.reports[1][:6] == bytes([0xC0, seq + 1, 0x02, 0x00, 0x01, 0x0B])  # read back
        emu.reports.clear()
        dmd.apply_settings({"exposure_s": 4500e-6, "period_s": 4500e-6})
        assert bytes.fromhex("29 1A 94 11 00 00 94 11 00 00") in emu.reports[-1]
        assert emu.exposure_us == emu.period_us == 4500
        dmd.load_sequence([PatternEntry(0, 0, colour="blue")])
        emu.reports.clear()
        dmd.start()
        assert emu.reports[0][2:7] == bytes([0x03, 0x00, 0x24, 0x1A, 0x02])
        assert emu.reports[1][:6] == bytes([0xC0, emu.reports[1][1], 0x02, 0x00, 0x0C, 0x1A])
        emu.reports.clear()
        dmd.validate()
        assert emu.reports[0][:7] == bytes([0x40, emu.reports[0][1], 0x03, 0x00, 0x1A, 0x1A, 0])


def test_pattern_mode_bring_up_sequence(hid):
    emu = hid.emulator
    with make(hid) as dmd:
        emu.log.clear()
        entries = [PatternEntry(2, b, colour="green") for b in range(3)] + [
            PatternEntry(5, 1, bit_depth=8, colour="red", invert=True)]
        dmd.load_sequence(entries, repeat=True)
        order = [cmd for cmd, _ in emu.log]
        first = {c: order.index(c) for c in (0x1A24, 0x1A1B, 0x1A22, 0x1A31, 0x1A29, 0x1A1A)}
        assert first[0x1A24] < first[0x1A1B] < first[0x1A22] < first[0x1A31] < first[0x1A1A]
        # 0-based counts: 4 entries, repeat, 4 patterns, 2 images (TI SetPatternConfig)
        assert (0x1A31, bytes([3, 1, 3, 1])) in emu.log
        writes = [(c, p) for c, p in emu.log if c in (0x1A32, 0x1A33, 0x1A34)]
        lut = b"".join(pattern_lut_entry(e, first_of_image=i in (0, 3))
                       for i, e in enumerate(entries))
        assert writes == [(0x1A33, b"\x02"), (0x1A32, b"\x00"), (0x1A34, lut),
                          (0x1A33, b"\x00"), (0x1A33, b"\x01"), (0x1A32, b"\x00"),
                          (0x1A34, bytes([5, 2])),  # 2 images: sent swapped, as TI does
                          (0x1A33, b"\x00")]
        assert emu.lut_entries() == [
            {"pattern": 0, "trigger": 0, "bit_depth": 1, "leds": 2, "invert": 0, "swap": 1},
            {"pattern": 1, "trigger": 3, "bit_depth": 1, "leds": 2, "invert": 0, "swap": 0},
            {"pattern": 2, "trigger": 3, "bit_depth": 1, "leds": 2, "invert": 0, "swap": 0},
            {"pattern": 1, "trigger": 0, "bit_depth": 8, "leds": 1, "invert": 1, "swap": 1},
        ]
        assert emu.image_lut[:2] == [2, 5] and emu.pattern_source == 3
        assert sum(1 for c, _ in emu.log if c == 0x1A1A) >= 3  # validate + polls while busy
        dmd.start()
        assert emu.running and dmd.running and emu.display_mode == 1
        assert pattern_lut_entry(entries[3], first_of_image=True) == bytes([4, 0x18, 0x05])


def test_long_pattern_lut_and_five_images(hid):
    """A 25-entry LUT is one 75-byte message (two reports); 5 images, one byte each."""
    emu = hid.emulator
    with make(hid) as dmd:
        entries = [PatternEntry(i % 5, i // 5) for i in range(25)]
        emu.reports.clear()
        dmd.load_sequence(entries)
        assert emu.pattern_config == (24, 1, 24, 4)  # repeat is the default
        assert emu.written == {1: 5, 2: 25}
        assert emu.image_lut[:5] == [0, 1, 2, 3, 4]
        assert [e["pattern"] for e in emu.lut_entries()] == [i // 5 for i in range(25)]
        dmd.start()
        assert emu.running


def test_old_wrong_bytes_are_refused(hid):
    """What this driver used to send fails on the emulator as on a controller: no data
    byte in validate (NACK), the image count not 0-based and 3 bytes per image (the
    controller reads images 2,0,0,5,0,0: the validation flags the LUT)."""
    emu = hid.emulator
    with make(hid) as dmd:
        with pytest.raises(DeviceProtocolError, match="0x1A1A.*NACK"):
            dmd.command(0x1A1A)
        dmd.load_sequence([PatternEntry(2, 0), PatternEntry(5, 0)])
        dmd.command(0x1A31, bytes([1, 0, 1, 2]))  # len(images) instead of len - 1
        with pytest.raises(DeviceProtocolError, match="pattern numbers"):
            dmd.validate()
        dmd.command(0x1A31, bytes([1, 0, 1, 1]))
        dmd.command(0x1A33, b"\x01")
        dmd.command(0x1A32, b"\x00")
        for image in (2, 5):
            dmd.command(0x1A34, bytes([image, 0, 0]))
        dmd.command(0x1A33, b"\x00")
        assert emu.image_lut[:6] == [2, 0, 0, 5, 0, 0]
        with pytest.raises(DeviceProtocolError, match="pattern numbers"):
            dmd.validate()


def test_state_changes_are_polled_until_reported():
    """A controller that shows a new mode or sequencer state a few reads late: the
    driver polls with retries instead of assuming (slstudio polls too)."""
    hid = FakeHid(Dlpc350Emulator(settle_polls=4))
    with make(hid) as dmd:
        dmd.load_sequence([PatternEntry(0, b) for b in range(3)])
        dmd.start()
        assert dmd.running
        dmd.stop()
        assert not dmd.running


def test_nack_and_validation_failures(hid):
    emu = hid.emulator
    with make(hid) as dmd:
        with pytest.raises(DeviceProtocolError, match="0x1A99.*NACK"):
            dmd.command(0x1A99, b"\x01")
        with pytest.raises(DeviceProtocolError, match="0x1A24.*NACK"):
            dmd.command(0x1A24, b"\x02")  # start before any validated sequence
        with pytest.raises(DeviceValueError, match="230 us"):
            dmd.apply_settings({"exposure_s": 0.0099, "period_s": 0.01})
        dmd.load_sequence([PatternEntry(0, 0)])
        dmd.command(0x1A29, struct.pack("<II", 9900, 10000))  # behind the driver's back
        with pytest.raises(DeviceProtocolError, match="under 230 us"):
            dmd.validate()
        with pytest.raises(DeviceProtocolError, match="NACK"):
            dmd.start()  # the controller refuses an invalid sequence
        dmd.apply_settings({"exposure_s": 0.005, "period_s": 0.01})
        dmd.load_sequence([PatternEntry(0, 0)])
        dmd.start()
        with pytest.raises(DeviceProtocolError, match="NACK"):
            dmd.command(0x1A31, bytes(4))  # configuration while running: refused
        dmd.exposure_s = 0.004  # the driver stops, changes, re-validates, restarts
        assert emu.running and emu.exposure_us == 4000


def test_long_message_is_continued_in_a_second_report(hid):
    emu = hid.emulator
    with make(hid) as dmd:
        emu.reports.clear()
        with pytest.raises(DeviceProtocolError):  # an unknown command, 70 bytes of payload
            dmd.command(0x1A98, bytes(range(70)))
        assert len(emu.reports) == 2 and emu.log[-1] == (0x1A98, bytes(range(70)))


def test_fake_hid_writes_as_hidapi_does(hid):
    """FakeHid's write is hidapi's hid_write (hidapi.h: "the first byte of data[] must
    contain the Report ID; for devices which only support a single report, this must be
    set to 0x0"; libusb/hid.c skips a 0 report id and sends the rest on the interrupt
    OUT endpoint): a leading 0 is not sent, a non-zero first byte is, and what is sent
    reaches the controller in reports of at most 64 bytes."""
    emu = hid.emulator
    dev = hid.device()
    dev.open_path(hid.enumerate()[0]["path"])
    report = bytes([0x40, 1, 2, 0, 0x99, 0x1A]).ljust(64, b"\xAA")
    emu.reports.clear()
    assert dev.write(b"\0" + report) == 65
    assert emu.reports == [report]  # the report id 0 stripped, 64 bytes sent
    emu.reports.clear()
    dev.write(bytes(1) + report[:63])  # 64 bytes without a report id: the first is taken
    assert emu.reports == [report[:63]]  # as the id 0 and not sent: 63 bytes arrive
    emu.reports.clear()
    dev.write(report)  # a non-zero first byte is sent as data
    assert emu.reports == [report]
    emu.reports.clear()
    dev.write(b"\0" + report + report[:10])  # longer than a report: two packets
    assert emu.reports == [report, report[:10]]
    assert dev.write(b"") == -1
    dev.close()


def test_pattern_lut_of_60_entries_arrives_whole(hid):
    """A 60-entry LUT is one 186-byte message, continued in a second and a third
    report. The third starts with entry 40's last byte, 0 (no invert, no buffer swap):
    a write without the report id would lose it (hidapi takes it for the id), shifting
    every entry after it; with the id, the controller holds all 60 as sent."""
    emu = hid.emulator
    entries = [PatternEntry(i // 24, i % 24, colour=("red", "green", "blue")[i % 3])
               for i in range(60)]
    lut = b"".join(pattern_lut_entry(e, first_of_image=e.bit == 0) for e in entries)
    assert lut[128 - 6] == 0  # the third report's first byte (after the 6-byte header)
    with make(hid) as dmd:
        dmd.load_sequence(entries)
        assert (0x1A34, lut) in emu.log
        assert emu.pattern_config == (59, 1, 59, 2) and emu.written[2] == 60
        assert emu.lut_entries() == [
            {"pattern": e.bit, "trigger": 0 if e.bit == 0 else 3, "bit_depth": 1,
             "leds": {"red": 1, "green": 2, "blue": 4}[e.colour], "invert": 0,
             "swap": int(e.bit == 0)} for e in entries]
        dmd.start()
        assert emu.running


def test_unplug_then_reconnect(hid):
    emu = hid.emulator
    with make(hid) as dmd:
        dmd.led_currents = {"blue": 0.5}
        seq = dmd.load_sequence([PatternEntry(1, b) for b in range(4)])
        dmd.start()
        emu.unplug()
        status = dmd.status()  # Device.status: reported, not raised
        assert status["disconnected"] and "I/O failed" in status["error"]
        assert not dmd._link.is_open
        with pytest.raises(DeviceDisconnectedError, match="stopped answering"):
            dmd.led_currents = {"blue": 0.25}
        with pytest.raises(DeviceDisconnectedError, match="0451:6401"):
            dmd.reconnect()
        emu.replug()
        with emu.lock:  # the controller was power-cycled: defaults, stopped
            emu.led_currents, emu.running = [104, 135, 130], False
        dmd.reconnect()
        assert emu.led_fractions()[2] == pytest.approx(0.5, abs=0.5 / 255)
        assert dmd.sequence == seq
        assert emu.running  # the sequence was loaded again and restarted


def test_missing_hidapi_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "hid", None)
    dmd = LightCrafter4500("dmd")
    with pytest.raises(MissingDependencyError, match=r"diffuserlab\[hardware\]"):
        dmd.open()


def test_exposure_rounds_to_microseconds(hid):
    with make(hid) as dmd:
        dmd.apply_settings({"exposure_s": 0.0012345, "period_s": 0.0012345})
        assert dmd.exposure_s == 0.001234 or dmd.exposure_s == 0.001235
        assert struct.unpack("<II", dmd.command(0x1A29, read=True)[:8])[0] == round(
            dmd.exposure_s * 1e6)


class TestLightCrafterOverPyusb(DmdConformance):
    @pytest.fixture
    def device(self):
        usb = FakeUsb(Dlpc350Emulator(validation_polls=1))
        self.emu = usb.emulator
        self.usb = usb
        with LightCrafter4500("dmd", transport="pyusb", usb_backend=usb,
                              reply_timeout_s=1.0) as dmd:
            assert not usb.kernel_driver  # detached to claim the interface
            yield dmd
        assert usb.kernel_driver  # re-attached on close

    def provoke_timeout(self, device):
        self.emu.drop_replies(1)
        self.wait_lost_reply(device)


def test_pyusb_unplug_and_serial_selection():
    usb = FakeUsb(Dlpc350Emulator(serial_number="LC-7"))
    with pytest.raises(DeviceDisconnectedError, match="with serial LC-8"):
        LightCrafter4500("dmd", transport="pyusb", usb_backend=usb, serial_number="LC-8").open()
    with LightCrafter4500("dmd", transport="pyusb", usb_backend=usb, serial_number="LC-7",
                          reply_timeout_s=1.0) as dmd:
        dmd.led_currents = {"green": 1.0}
        usb.emulator.unplug()
        status = dmd.status()
        assert status["disconnected"] and "USB I/O failed" in status["error"]
        usb.emulator.replug()
        dmd.reconnect()
        assert usb.emulator.led_currents[1] == 0  # full current: PWM byte 0 on the EVM
        assert usb.emulator.led_fractions()[1] == 1.0


@pytest.mark.parametrize("transport", ["hidapi", "pyusb"])
def test_opens_with_replies_a_few_ms_late(transport):
    """A controller answering 20 ms after each request (hidapi and libusb take ms: a
    timeout handed on in seconds gave up after 1-2 ms and the open blamed the power)."""
    emu = Dlpc350Emulator(reply_latency_s=0.02)
    backend = {"hid_backend": FakeHid(emu)} if transport == "hidapi" else {
        "usb_backend": FakeUsb(emu)}
    with LightCrafter4500("dmd", transport=transport, reply_timeout_s=2.0, **backend) as dmd:
        assert dmd.version and dmd.status()["main_status"] == emu.running * 2

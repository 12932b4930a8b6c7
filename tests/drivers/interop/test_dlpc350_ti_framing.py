"""Our LightCrafter 4500 driver's bytes against a transcription of TI's host code
(tests/drivers/interop/ti_dlpc350.py): the same request, the same write messages and
the same 64-byte reports. Reads (status polls) are left out of the comparison; the
sequence byte is masked (TI counts it per write, we per message)."""

from __future__ import annotations

import pytest

from drivers.dlp_lightcrafter import LightCrafter4500
from drivers.dmd import PatternEntry
from tests.drivers.interop import ti_dlpc350 as ti
from tests.mocks import Dlpc350Emulator, FakeHid

LEDS = {"red": 1, "green": 2, "blue": 4}


def host_messages(reports: list[bytes]) -> list[bytes]:
    """Whole messages from the reports a host wrote (continuations joined by length)."""
    out, i = [], 0
    while i < len(reports):
        need = 4 + int.from_bytes(reports[i][2:4], "little")
        buf = bytearray(reports[i])
        i += 1
        while len(buf) < need:
            buf += reports[i]
            i += 1
        out.append(bytes(buf[:need]))
    return out


def writes(reports: list[bytes]) -> list[bytes]:
    """The write messages, sequence byte set to 0."""
    return [m[:1] + b"\0" + m[2:] for m in host_messages(reports) if not m[0] & 0x80]


def ti_load(entries: list[PatternEntry], repeat: bool, exposure_us: int,
            period_us: int) -> list[bytes]:
    """What TI's API sends to load ``entries`` from flash, in our driver's order."""
    images = list(dict.fromkeys(e.image for e in entries))
    words, previous = [], None
    for e in entries:
        first = e.image != previous
        words.append(ti.lut_word(0 if first else 3, e.bit, e.bit_depth, LEDS[e.colour],
                                 invert=e.invert, swap=first))
        previous = e.image
    n = len(entries)
    return (ti.pattern_display(0) + ti.set_mode(True) + ti.set_pattern_display_mode(False)
            + ti.set_pattern_config(n, repeat, n, len(images)) + ti.set_pattern_trigger_mode(1)
            + ti.set_exposure_frame_period(exposure_us, period_us)
            + ti.set_led_enables(True, True, True, True) + ti.send_pat_lut(words)
            + ti.send_image_lut(images) + ti.validate())


@pytest.mark.parametrize("entries", [
    [PatternEntry(2, b, colour="green") for b in range(3)]
    + [PatternEntry(5, 1, bit_depth=8, colour="red", invert=True)],          # 2 images
    [PatternEntry(i % 5, i // 5, colour="blue") for i in range(25)],          # 5 images, 2 reports
])
def test_load_sequence_bytes_equal_tis(entries):
    hid = FakeHid(Dlpc350Emulator())
    with LightCrafter4500("dmd", hid_backend=hid, reply_timeout_s=1.0) as dmd:
        dmd.apply_settings({"exposure_s": 0.004, "period_s": 0.005})
        emu = hid.emulator
        emu.reports.clear()
        dmd.load_sequence(entries, repeat=True)
        ours = writes(emu.reports)
        theirs = ti_load(entries, True, 4000, 5000)
        assert ours == theirs
        ours_reports = [r for r in emu.reports if r[0] == 0x40 and r[4:6] == b"\x34\x1A"]
        lut = next(m for m in theirs if m[4:6] == b"\x34\x1A")
        first = emu.reports.index(ours_reports[0])
        split = ti.reports(lut)
        assert [r[:1] + b"\0" + r[2:] if k == 0 else r
                for k, r in enumerate(emu.reports[first:first + len(split)])] == split
        dmd.start()
        assert emu.running


def test_led_currents_bytes_equal_slstudios():
    hid = FakeHid(Dlpc350Emulator())
    emu = hid.emulator
    with LightCrafter4500("dmd", hid_backend=hid, reply_timeout_s=1.0) as dmd:
        opened = writes(emu.reports)
        emu.reports.clear()
        dmd.led_currents = {"red": 50 / 255, "green": 120 / 255, "blue": 1.0}
        polarity, currents = ti.set_led_currents_slstudio(50, 120, 255)
        assert polarity in opened  # 0x1A05 = 0 at open, as slstudio sets it
        assert writes(emu.reports) == [currents]
        assert emu.led_fractions() == pytest.approx([50 / 255, 120 / 255, 1.0])

"""pycrafter4500 (a LightCrafter 4500 client labs use, over pyusb) drives the DLPC350
emulator through a small pyusb-device stand-in (:class:`~tests.mocks.FakeUsb`: find,
set_configuration, write to endpoint 1, read from 0x81, reset). Its framing (fixed
sequence 0, its own multi-report continuation, its payload bit packing) meets the
emulator; the emulator's state after each session is asserted.
"""

from __future__ import annotations

import pytest

from tests.drivers.interop.clients import client
from tests.mocks import Dlpc350Emulator, FakeUsb

pycrafter = client("pycrafter4500", "pycrafter4500")
import usb.core  # noqa: E402  (pyusb, a dependency of pycrafter4500)


@pytest.fixture
def emu(monkeypatch):
    """The emulator behind ``usb.core.find``, with no kernel driver bound (as under
    Windows' libusb driver, which pycrafter4500 is written for)."""
    fake = FakeUsb(Dlpc350Emulator(validation_polls=2))
    fake.kernel_driver = False
    monkeypatch.setattr(usb.core, "find", fake.core.find)
    monkeypatch.setattr(pycrafter.pycrafter4500.time, "sleep", lambda s: None)
    return fake.emulator


def test_pattern_mode_helper_video_source(emu):
    """pycrafter4500's own bring-up helper, unchanged: video source, 3 patterns."""
    pycrafter.pattern_mode(num_pats=3, fps=120, bit_depth=8, led_color=0b001)
    assert emu.display_mode == 1 and emu.pattern_source == 0 and emu.running
    assert emu.pattern_config == (2, 1, 2, 0)
    assert emu.exposure_us == emu.period_us == 8333
    assert [e["pattern"] for e in emu.lut_entries()] == [0, 1, 2]
    assert {e["bit_depth"] for e in emu.lut_entries()} == {8}
    assert {e["leds"] for e in emu.lut_entries()} == {1}


def load_flash(lcr, entries, images, n_images_field):
    """Stop, pattern mode, flash source, configuration, both LUTs and validation
    through pycrafter4500's calls: one LUT entry per mailbox message with its address
    (as its helper does), the image LUT as one message in TI's order. Returns the
    validation status."""
    n = len(entries)
    lcr.pattern_display("stop")
    lcr.set_display_mode("pattern")
    lcr.set_pattern_input_source("flash")
    lcr.set_pattern_config(num_lut_entries=n, do_repeat=True, num_pats_for_trig_out2=n,
                           num_images=n_images_field)
    lcr.set_pattern_trigger_mode(1)  # internal trigger
    lcr.set_exposure_frame_period(9000, 10000)
    lcr.open_mailbox(2)
    for i, (trig, pattern, depth, leds, swap) in enumerate(entries):
        lcr.mailbox_set_address(i)
        lcr.send_pattern_lut(trig, pattern, depth, leds, do_buf_swap=swap)
    lcr.open_mailbox(0)
    lcr.open_mailbox(1)
    lcr.mailbox_set_address(0)
    lcr.command("w", 0x00, 0x1A, 0x34, images[::-1] if len(images) == 2 else images)
    lcr.open_mailbox(0)
    lcr.start_pattern_lut_validate()
    lcr.command("r", 0x00, 0x1A, 0x1A, [])
    while lcr.ans[4] & 0x80:  # busy: poll until validated
        lcr.command("r", 0x00, 0x1A, 0x1A, [])
    return lcr.ans[4]


def flash_session(lcr, entries, images, currents):
    """A flash-source bring-up, then LED currents as slstudio writes them and start."""
    # pycrafter4500 passes num_images through unchanged (its helper only uses the video
    # source); the firmware takes it 0-based (TI DLPC350_SetPatternConfig)
    status = load_flash(lcr, entries, images, len(images) - 1)
    lcr.command("w", 0x00, 0x1A, 0x05, [0])  # PWM polarity normal
    lcr.command("w", 0x00, 0x0B, 0x01, [255 - c for c in currents])
    lcr.pattern_display("start")
    return status


@pytest.mark.parametrize("images", [[4, 9], [0, 3, 1, 7, 2], list(range(60))])  # 60: 2 reports
def test_flash_sequence_and_led_currents(emu, images):
    # two 1-bit patterns per image, green then blue
    entries = [(0, 0, 1, 0b010, True), (3, 1, 1, 0b100, False)] * len(images)
    with pycrafter.connect_usb() as lcr:
        status = flash_session(lcr, entries, images, [30, 200, 255])
    assert status == 0  # validated without a flag
    assert emu.running and emu.display_mode == 1 and emu.pattern_source == 3
    assert emu.trigger_mode == 1 and (emu.exposure_us, emu.period_us) == (9000, 10000)
    assert emu.pattern_config == (len(entries) - 1, 1, len(entries) - 1, len(images) - 1)
    assert emu.image_lut[:len(images)] == images  # the 2-entry LUT stored in order
    assert [(e["trigger"], e["pattern"], e["leds"], e["swap"]) for e in emu.lut_entries()] \
        == [(t, p, led, int(s)) for t, p, _, led, s in entries]
    assert emu.led_fractions() == pytest.approx([30 / 255, 200 / 255, 1.0])


def test_wrong_image_count_is_flagged(emu):
    """The count pycrafter4500 would send for 5 images if given the count itself (not
    0-based): the emulator's validation flags it, as the LUT would be read wrongly."""
    entries = [(0, 0, 1, 0b111, True)] * 5
    with pycrafter.connect_usb() as lcr:
        load_flash(lcr, entries, [0, 1, 2, 3, 4], n_images_field=5)
        assert lcr.ans[4] & 0x02  # pattern numbers / LUT invalid
        lcr.pattern_display("start")
        assert lcr.ans[0] & 0x20  # NACK: an invalid sequence does not start
    assert not emu.running

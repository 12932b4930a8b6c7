"""A transcription of the message framing of TI's DLPC350 host code.

Source: ``dlpc350_api.cpp`` of TI's LightCrafter 4500 host software (as copied in
github.com/jakobwilm/slstudio, src/projector/LC4500API), and slstudio's
``ProjectorLC4500.cpp`` for how an application calls it. Written out here as data,
not ported: what each API call puts on the wire, so that a test can compare our
driver's bytes with TI's for the same request. Each function returns the messages
(``bytes``, header + command + payload, before the split into 64-byte reports) that
the TI call sends, with the sequence byte set to 0 (TI counts it per write; tests
compare with the sequence masked).

- ``DLPC350_PrepWriteCmd``: flags 0x40 (bit 6 "reply wanted", R/W 0, destination 0),
  sequence, length = payload length + 2 (u16 LE), command CMD3 then CMD2, payload.
- ``DLPC350_SendMsg``: the message in 64-byte reports, the first holding the 4-byte
  header and 60 bytes of command + payload, the next ones 64 bytes each
  (:func:`reports`).
- ``DLPC350_SetPatternConfig``: ``numLutEntries - 1, repeat, numPatsForTrigOut2 - 1,
  numImages - 1`` ("-1 because the firmware command takes 0-based indices").
- ``DLPC350_AddToPatLut``: a 24-bit word, trigger type bits 1:0, pattern number
  7:2, bit depth 11:8, LED select 14:12, invert 16, insert black 17, buffer swap 18,
  trigger-out-previous 19; ``DLPC350_SendPatLut``: open mailbox 2, address 0, one
  MBOX_DATA message of 3 bytes (LE) per word, close mailbox.
- ``DLPC350_SendImageLut``: open mailbox 1, address 0, one MBOX_DATA message of one
  byte per image, the two entries of a 2-entry LUT swapped, close mailbox.
- ``DLPC350_ValidatePatLutData``: LUT_VALID (0x1A1A) write of 1 data byte (TI leaves
  it unset; pycrafter4500 and QDSpy send 0), then reads until bit 7 clears.
- ``DLPC350_SetLedCurrents(r, g, b)``: 3 bytes; slstudio calls
  ``DLPC350_SetLEDPWMInvert(false)`` (0x1A05, 1 byte) and passes ``255 - current``.
"""

from __future__ import annotations

import struct

__all__ = [
    "lut_word",
    "pattern_display",
    "reports",
    "send_image_lut",
    "send_pat_lut",
    "set_exposure_frame_period",
    "set_led_currents_slstudio",
    "set_led_enables",
    "set_mode",
    "set_pattern_config",
    "set_pattern_display_mode",
    "set_pattern_trigger_mode",
    "validate",
    "write",
]

# CmdList entries used (CMD2, CMD3)
PAT_START_STOP, DISP_MODE, PAT_DISP_MODE, PAT_TRIG_MODE = 0x1A24, 0x1A1B, 0x1A22, 0x1A23
PAT_EXPO_PRD, PAT_CONFIG, MBOX_ADDRESS, MBOX_CONTROL = 0x1A29, 0x1A31, 0x1A32, 0x1A33
MBOX_DATA, LUT_VALID, LED_ENABLE, LED_CURRENT, PWM_INVERT = 0x1A34, 0x1A1A, 0x1A07, 0x0B01, 0x1A05


def write(cmd: int, payload: bytes | list[int], seq: int = 0) -> bytes:
    """``DLPC350_PrepWriteCmd`` + payload: one write message asking for a reply."""
    payload = bytes(payload)
    return bytes([0x40, seq & 0xFF]) + struct.pack("<HH", len(payload) + 2, cmd) + payload


def reports(message: bytes) -> list[bytes]:
    """``DLPC350_SendMsg``: the 64-byte reports of one message (zero padded)."""
    return [message[k:k + 64].ljust(64, b"\0") for k in range(0, len(message), 64)]


def pattern_display(action: int) -> list[bytes]:
    return [write(PAT_START_STOP, [action & 0x03])]


def set_mode(pattern: bool) -> list[bytes]:
    return [write(DISP_MODE, [int(pattern)])]


def set_pattern_display_mode(external: bool) -> list[bytes]:
    return [write(PAT_DISP_MODE, [0 if external else 3])]


def set_pattern_trigger_mode(mode: int) -> list[bytes]:
    return [write(PAT_TRIG_MODE, [mode])]


def set_pattern_config(n_entries: int, repeat: bool, n_trig_out2: int,
                       n_images: int) -> list[bytes]:
    return [write(PAT_CONFIG, [n_entries - 1, int(repeat), n_trig_out2 - 1, n_images - 1])]


def set_exposure_frame_period(exposure_us: int, period_us: int) -> list[bytes]:
    return [write(PAT_EXPO_PRD, struct.pack("<II", exposure_us, period_us))]


def set_led_enables(seq_ctrl: bool, red: bool, green: bool, blue: bool) -> list[bytes]:
    return [write(LED_ENABLE, [int(red) | int(green) << 1 | int(blue) << 2
                               | int(seq_ctrl) << 3])]


def lut_word(trig: int, pattern: int, depth: int, leds: int, invert: bool = False,
             black: bool = False, swap: bool = False, prev: bool = False) -> int:
    """``DLPC350_AddToPatLut``'s 24-bit entry."""
    return ((trig & 3) | (pattern & 0x3F) << 2 | (depth & 0xF) << 8 | (leds & 7) << 12
            | int(invert) << 16 | int(black) << 17 | int(swap) << 18 | int(prev) << 19)


def send_pat_lut(words: list[int]) -> list[bytes]:
    data = b"".join(struct.pack("<I", w)[:3] for w in words)
    return [write(MBOX_CONTROL, [2]), write(MBOX_ADDRESS, [0]), write(MBOX_DATA, data),
            write(MBOX_CONTROL, [0])]


def send_image_lut(images: list[int]) -> list[bytes]:
    entries = [images[1], images[0]] if len(images) == 2 else list(images)
    return [write(MBOX_CONTROL, [1]), write(MBOX_ADDRESS, [0]), write(MBOX_DATA, entries),
            write(MBOX_CONTROL, [0])]


def validate() -> list[bytes]:
    return [write(LUT_VALID, [0])]


def set_led_currents_slstudio(red: int, green: int, blue: int) -> list[bytes]:
    """slstudio: PWM polarity normal, then ``255 - current`` per colour (0..255)."""
    return [write(PWM_INVERT, [0]), write(LED_CURRENT, [255 - red, 255 - green, 255 - blue])]

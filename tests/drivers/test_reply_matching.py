"""Which reply belongs to which request: the paths a mutation review found unguarded.

Each test feeds the driver a reply it must refuse next to the one it must take, at the
byte level, through a scripted link in place of the serial port: an APT reply from
another bay of a rack, a late Zaber reply to an earlier (timed-out) command, a Zaber
reply from another device or axis with the same message id, a Zaber reply whose
checksum fails; and, through the DLPC350 emulator's HID reports, a LightCrafter reply
that comes after its read timed out. The limit bits of the APT emulator are read by a client
written independently of ours (thorlabs-apt-device) in
``tests/drivers/interop/test_apt_thorlabs_apt_device.py``.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable

import pytest

from drivers.dlp_lightcrafter import LightCrafter4500
from drivers.errors import DeviceProtocolError, DmdTimeoutError, StageTimeoutError
from drivers.thorlabs_apt_protocol import HOST, MSG, AptController, pack_message
from drivers.zaber_ascii import ZaberAsciiStage, lrc
from tests.mocks import Dlpc350Emulator, FakeHid


class ScriptedLink:
    """The surface of :class:`drivers.transports.SerialLink` the drivers use; every
    write is answered by ``respond(data)``, whose bytes are then read back."""

    path = "/dev/scripted"

    def __init__(self, respond: Callable[[bytes], bytes]) -> None:
        self.respond = respond
        self.written: list[bytes] = []
        self._rx = bytearray()
        self._cond = threading.Condition()
        self.is_open = False

    def open(self) -> None:
        self.is_open = True

    def close(self) -> None:
        self.is_open = False

    def hung_up(self) -> bool:  # a scripted link never loses its other end
        return False

    def write(self, data: bytes) -> None:
        self.written.append(bytes(data))
        with self._cond:
            self._rx += self.respond(bytes(data))
            self._cond.notify_all()

    def read_some(self, timeout_s: float | None = None) -> bytes:
        with self._cond:
            self._cond.wait_for(lambda: self._rx or not self.is_open, 0.02)
            out, self._rx[:] = bytes(self._rx), b""
            return out

    def discard_input(self) -> bytes:
        with self._cond:
            out, self._rx[:] = bytes(self._rx), b""
            return out

    def read_until(self, terminator: bytes, timeout_s: float, what: str = "") -> bytes:
        with self._cond:
            if not self._cond.wait_for(lambda: terminator in self._rx, timeout_s):
                raise StageTimeoutError("stage", f"no {what} within {timeout_s:g} s", "-")
            end = self._rx.index(terminator) + len(terminator)
            out = bytes(self._rx[:end])
            del self._rx[:end]
            return out


# ------------------------------------------------------------------ APT: the bay
def test_apt_reply_from_another_bay_is_not_taken():
    """A BSC20x rack: a position request to bay 2 (0x22) is answered first by bay 1
    (0x21, e.g. a late answer to an earlier request) and then by bay 2; the request
    returns bay 2's position and bay 1's reply goes to the event handler."""
    req, get = MSG["MOT_REQ_POSCOUNTER"], MSG["MOT_GET_POSCOUNTER"]

    def respond(data: bytes) -> bytes:
        msg_id, _, _, dest, _ = struct.unpack_from("<HBBBB", data)
        if msg_id != req:
            return b""
        return b"".join(pack_message(get, HOST, source, data=struct.pack("<Hi", 1, pos))
                        for source, pos in ((0x21, 111), (dest, 222)))

    events = []
    ctrl = AptController("rack", ScriptedLink(respond), on_event=events.append,
                         timeout_error=StageTimeoutError)
    ctrl.open()
    try:
        reply = ctrl.request(req, get, 0x22, param1=1, timeout_s=2.0)
        assert reply.source == 0x22
        assert struct.unpack("<Hi", reply.data)[1] == 222
        assert [(m.source, struct.unpack("<Hi", m.data)[1]) for m in events] == [(0x21, 111)]
    finally:
        ctrl.close()


# ------------------------------------------------------------------ Zaber: id, checksum
def zaber_reply(device: int, axis: int, msg_id: int, data: str, *, checksum=None) -> bytes:
    body = f"{device:02d} {axis} {msg_id} OK IDLE -- {data}"
    return f"@{body}:{checksum or lrc(body)}\r\n".encode("ascii")


def zaber_stage(respond: Callable[[bytes], bytes]) -> tuple[ZaberAsciiStage, ScriptedLink]:
    stage = ZaberAsciiStage("mask", port="/dev/scripted", reply_timeout_s=0.5)
    link = ScriptedLink(respond)
    stage._link = link  # the driver's only path to the port
    return stage, link


def sent_id(data: bytes) -> int:
    return int(data.decode("ascii").lstrip("/").split()[2].split(":")[0])


def test_zaber_late_reply_with_an_earlier_id_is_skipped():
    """The reply to an earlier command that timed out arrives after the next command
    went out, from the same device and axis: only its message id tells it apart."""
    def respond(data: bytes) -> bytes:
        mid = sent_id(data)
        return zaber_reply(1, 1, (mid - 2) % 99 + 1, "999") + zaber_reply(1, 1, mid, "5")

    stage, link = zaber_stage(respond)
    assert stage.command(1, 1, "get pos") == ("IDLE", "--", "5")
    assert stage.command(1, 1, "get pos") == ("IDLE", "--", "5")
    assert [sent_id(w) for w in link.written] == [1, 2]


@pytest.mark.parametrize("device, axis", [(2, 1), (1, 2)])
def test_zaber_reply_from_another_address_with_the_same_id_is_skipped(device, axis):
    """Daisy-chained devices number their message ids alike: a reply from device 2 (or
    from axis 2 of device 1) carrying the id just sent is not the reply to device 1
    axis 1; the driver reads on to the addressed one."""
    def respond(data: bytes) -> bytes:
        mid = sent_id(data)
        return zaber_reply(device, axis, mid, "999") + zaber_reply(1, 1, mid, "5")

    stage, _ = zaber_stage(respond)
    assert stage.command(1, 1, "get pos") == ("IDLE", "--", "5")


def test_zaber_reply_without_its_message_id_is_skipped():
    def respond(data: bytes) -> bytes:
        return (f"@01 1 OK IDLE -- 999:{lrc('01 1 OK IDLE -- 999')}\r\n".encode()
                + zaber_reply(1, 1, sent_id(data), "7"))

    stage, _ = zaber_stage(respond)
    assert stage.command(1, 1, "get pos")[2] == "7"


def test_zaber_reply_failing_its_checksum_is_refused():
    """A reply corrupted on the line (its LRC does not match) is an error naming the
    reply, never a value."""
    def respond(data: bytes) -> bytes:
        good = zaber_reply(1, 1, sent_id(data), "1234")
        bad_cc = "00" if not good.decode().rstrip().endswith(":00") else "01"
        return zaber_reply(1, 1, sent_id(data), "1234", checksum=bad_cc)

    stage, _ = zaber_stage(respond)
    with pytest.raises(DeviceProtocolError, match="fails its checksum"):
        stage.command(1, 1, "get pos")


# ------------------------------------------------------------------ DLPC350: the sequence
@pytest.fixture
def late_led_reply():
    """A LightCrafter whose LED currents read (0x0B01) timed out; the emulator then
    releases the reply it held back, which now waits ahead of the next command's."""
    emu = Dlpc350Emulator()
    with LightCrafter4500("dmd", hid_backend=FakeHid(emu), reply_timeout_s=60.0) as dmd:
        emu.hold_replies(1)
        with pytest.raises(DmdTimeoutError):
            dmd.command(0x0B01, read=True, timeout_s=0.05)
        emu.release_replies()
        yield dmd, emu


def test_lightcrafter_late_reply_to_a_timed_out_read_is_skipped(late_led_reply):
    """The driver takes the reply whose sequence byte is its request's: the main
    status, not the late LED bytes (104, 135, 130)."""
    dmd, emu = late_led_reply
    assert dmd.main_status() == 0x00  # parked, running, frozen, gamma: all off
    assert struct.unpack("<II", dmd.command(0x1A29, read=True)[:8]) == (8333, 8333)
    assert not emu.replies  # the late reply was read and dropped


def test_lightcrafter_only_a_late_reply_is_a_timeout(late_led_reply):
    """A late reply followed by none to the request: the read times out rather than
    returning the late reply's bytes."""
    dmd, emu = late_led_reply
    emu.drop_replies(1)
    with pytest.raises(DmdTimeoutError):
        dmd.command(0x1A0C, read=True, timeout_s=0.3)

"""Zaber's own libraries drive the Zaber chain emulator: zaber.serial (ASCII commands
without message ids, strict about the reply's form) and zaber-motion (message ids and
checksums, through its raw ``generic_command`` path). zaber-motion's unit-aware API
(``detect_devices``, ``Axis.move_absolute`` with units) needs Zaber's online device
database, which a lab or CI without internet does not have: it is not used here.
"""

from __future__ import annotations

import time

import pytest

from tests.drivers.interop.clients import client
from tests.mocks import ZaberEmulator

zs = client("zaber.serial", "zaber.serial")


@pytest.fixture
def emu():
    with ZaberEmulator({1: 1, 2: {"axes": 2, "peripheral_id": 43211}}, time_scale=100.0) as e:
        yield e


def test_zaber_serial_session(emu):
    port = zs.AsciiSerial(emu.port, timeout=2)
    try:
        d1, d2 = zs.AsciiDevice(port, 1), zs.AsciiDevice(port, 2)
        reply = d1.send("get deviceid")
        assert (reply.reply_flag, reply.data, reply.message_id) == ("OK", "50081", None)
        assert d2.send("get system.axiscount").data == "2"
        assert d2.axis(1).send("get peripheralid").data == "43211"
        assert d1.send("tools echo hello").data == "hello"
        assert d1.send("get pos").warning_flag == "WR"  # not homed yet

        d1.home()  # sends home, then polls until idle
        assert d1.send("").device_status == "IDLE" and "WR" not in emu.axis(1).flags
        d1.move_abs(10_000)
        assert d1.get_position() == 10_000
        d1.move_rel(-2_500)
        assert d1.get_position() == 7_500 == round(emu.axis(1).position)
        assert d1.send("warnings").data == "00"

        ax = d2.axis(2)
        ax.home()
        ax.move_abs(50_000)
        assert ax.get_position() == 50_000 and emu.axis(2, 2).position == 50_000
        assert d2.axis(1).send("").warning_flag == "WR"  # the other axis is still unhomed
        ax.move_vel(2_000)  # move at velocity until stopped
        time.sleep(0.05)
        assert ax.get_status() == "BUSY" and emu.axis(2, 2).motion is not None
        ax.stop()
        ax.poll_until_idle()
        assert emu.axis(2, 2).motion is None and ax.get_position() > 50_000

        d1.send("set maxspeed 50000")
        assert d1.send("get maxspeed").data == "50000" and emu.axis(1).maxspeed == 50_000
        # rejections: the reply says why
        assert d1.send("move abs 99999999").data == "BADDATA"
        assert d1.send("fly away").data == "BADCOMMAND"
        assert zs.AsciiDevice(port, 1).axis(3).send("get pos").data == "BADAXIS"
        # a warning: an unexpected limit on the way
        emu.set_limit_switch(5_000)
        d1.move_abs(0)
        assert "WL" in d1.send("warnings").data.split()
        assert d1.get_position() == 5_000
        d1.send("warnings clear")
        d1.send("system reset")
        assert d1.send("").warning_flag == "WR"  # reset: the reference is lost
    finally:
        port.close()
    # no message ids were sent, and none came back (zaber.serial checks the reply's id)
    assert all(len(c.split()) < 3 or not c.split()[2].isdigit() for c in emu.commands)
    replies = [r.split() for r in bytes(emu.sent).decode().split("\r\n") if r]
    assert all(r[2] in ("OK", "RJ") for r in replies if r[0].startswith("@"))


def test_zaber_motion_generic_commands(emu):
    zaber_motion = client("zaber_motion", "zaber-motion")
    zm = client("zaber_motion.ascii", "zaber-motion")
    conn = zm.Connection.open_serial_port(emu.port)
    try:
        r = conn.generic_command("get pos", device=1, axis=1)
        assert (r.reply_flag, r.data, r.warning_flag) == ("OK", "0", "WR")
        conn.generic_command("home", device=1, axis=1)
        deadline = time.monotonic() + 60  # a hang guard
        while conn.generic_command("", device=1, axis=1).status == "BUSY":
            assert time.monotonic() < deadline
            time.sleep(0.01)
        conn.generic_command("move abs 12345", device=1, axis=1)
        while conn.generic_command("", device=1, axis=1).status == "BUSY":
            time.sleep(0.01)
        assert conn.generic_command("get pos", device=1, axis=1).data == "12345"
        with pytest.raises(zaber_motion.BadCommandException):
            conn.generic_command("fly away", device=1, axis=1)
        serials = conn.generic_command_multi_response("get system.serial")
        assert sorted(r.data for r in serials) == ["33001", "33002"]
    finally:
        conn.close()
    # zaber-motion sends message ids and checksums; each was answered with its id
    assert all(":" in c for c in emu.commands)

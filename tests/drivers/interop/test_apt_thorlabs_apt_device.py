"""thorlabs-apt-device (yaq's APT client, its own framer and unpacker) drives the APT
emulator: home, absolute and relative moves, velocity and jog parameters set and read
back, status bits, jog, move at velocity, stop. The emulator's state is asserted, so a
misreading shared by our driver and our emulator would show here.
"""

from __future__ import annotations

import io
import time

import pytest

from tests.drivers.interop.clients import client
from tests.mocks import AptEmulator

tad = client("thorlabs_apt_device", "thorlabs-apt-device")


def until(predicate, timeout_s: float = 120.0, what: str = "condition") -> None:
    """Wait for the client's asynchronous state (its reader runs on its own loop). The
    limit is a hang guard, not a deadline: the wait ends as soon as the state holds (it
    was 5 s, and beside busy processes, load 12-20, "moving at velocity" took longer)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not reached within {timeout_s} s")
        time.sleep(0.01)


@pytest.fixture
def kdc():
    emu = AptEmulator("kdc101", time_scale=20.0, update_period_s=0.01,
                      travel_counts=(0, 863874))
    with emu:
        dev = tad.KDC101(serial_port=emu.port, home=False)
        try:
            yield emu, dev
        finally:
            dev.close()
            time.sleep(0.2)  # the client stops its loop and closes the port asynchronously


def test_kdc101_session(kdc):
    emu, dev = kdc
    ch = emu.channels[0x50]
    until(lambda: dev.status["msg"] == "mot_get_dcstatusupdate", what="first status update")
    until(lambda: dev.velparams["max_velocity"] == ch.velocity[2], what="velocity read")
    assert dev.status["channel_enabled"] and not dev.status["homed"]

    dev.home()
    until(lambda: dev.status["homed"], what="homed")
    assert ch.homed and emu.position() == 0

    dev.move_absolute(200_000)
    until(lambda: dev.status["position"] == 200_000 and not dev.status["moving_forward"],
          what="absolute move")
    assert emu.position() == 200_000 and ch.motion is None

    dev.move_relative(-50_000)
    until(lambda: dev.status["position"] == 150_000, what="relative move")
    assert emu.position() == 150_000

    dev.set_velocity_params(acceleration=800, max_velocity=500_000)
    until(lambda: dev.velparams["max_velocity"] == 500_000, what="velocity read-back")
    assert ch.velocity == (0, 800, 500_000) and dev.velparams["acceleration"] == 800

    dev.set_jog_params(size=7_000, acceleration=800, max_velocity=300_000)
    until(lambda: dev.jogparams["step_size"] == 7_000, what="jog read-back")
    assert ch.jog == (2, 7_000, 0, 800, 300_000, 2)  # single-step jog, profiled stop

    # KDC101 in this client: "forward" sends direction 2 (invert_direction_logic)
    dev.move_jog("forward")
    until(lambda: emu.position() == 143_000 and ch.motion is None, what="jog step")
    dev.move_jog("reverse")
    until(lambda: emu.position() == 150_000 and ch.motion is None, what="jog back")

    dev.move_velocity("reverse")  # direction 1: towards the forward end of the travel
    # the emulator's motion first: a status sent before the move arrived may still show
    # the jog's moving bit (a loaded machine got there before the move, CI run)
    until(lambda: ch.motion is not None, what="velocity move received")
    assert ch.motion.direction > 0
    until(lambda: dev.status["moving_forward"] or dev.status["moving_reverse"],
          what="moving at velocity")
    dev.stop()
    until(lambda: ch.motion is None, what="stopped")
    stopped_at = emu.position()
    assert 150_000 < stopped_at < 863_874
    until(lambda: dev.status["position"] == stopped_at, what="status after stop")
    assert not emu.unknown  # every message the client sent is one the emulator knows
    decoded = parse_all(emu)
    assert {"mot_get_dcstatusupdate", "mot_get_velparams", "mot_get_jogparams",
            "mot_move_homed", "mot_move_completed", "mot_move_stopped"} <= {
                m.msg for m in decoded}


def parse_all(emu) -> list:
    """Everything the emulator sent, framed by the client's own unpacker, which raises
    on any byte it cannot frame (unknown id, destination, source or length)."""
    unpacker = tad.protocol.Unpacker(io.BytesIO(bytes(emu.sent)), on_error="raise")
    return list(unpacker)


def test_kdc101_limit_and_error_report(kdc):
    emu, dev = kdc
    errors: list = []
    dev.register_error_callback(lambda **kw: errors.append(kw))
    dev.home()
    until(lambda: dev.status["homed"], what="homed")
    emu.set_limit_switch(100_000)
    dev.move_absolute(300_000)
    until(lambda: emu.channels[0x50].motion is None and emu.position() == 100_000,
          what="stopped at the limit switch")
    until(lambda: dev.status["forward_limit_switch"] or dev.status["reverse_limit_switch"],
          what="limit bit seen by the client")
    emu.rich_response(0x2A, "Motor overtemp")
    # the client's handler looks for "hw_rich_response" but its parser names the message
    # "hw_richresponse", so its callbacks never fire (thorlabs-apt-device 0.3.8): check
    # the report with its parser instead
    until(lambda: any(m.msg == "hw_richresponse" for m in parse_all(emu)),
          what="rich response framed")
    rich = [m for m in parse_all(emu) if m.msg == "hw_richresponse"][-1]
    assert rich.code == 0x2A and rich.notes.rstrip(b"\0") == b"Motor overtemp"
    assert not errors


def test_limit_bits_name_the_side():
    """thorlabs-apt-device reads the status bits with its own parser: the reverse limit
    at the home end of the travel, the forward limit after a move forward into a
    switch, the reverse limit after a move back into one (a swap of the two bits in
    the emulator, in any place it sets them, fails here). The client is told to take
    the bits and directions as the protocol document defines them (its KDC101 class
    swaps both names by default, for units wired the other way round)."""
    emu = AptEmulator("kdc101", time_scale=20.0, update_period_s=0.01,
                      travel_counts=(0, 863874))
    with emu:
        dev = tad.KDC101(serial_port=emu.port, home=False, invert_direction_logic=False,
                         swap_limit_switches=False)
        try:
            limit_bits_session(emu, dev)
        finally:
            dev.close()
            time.sleep(0.2)


def limit_bits_session(emu, dev) -> None:
    dev.home()
    until(lambda: dev.status["homed"] and not dev.status["moving_reverse"], what="homed")
    until(lambda: dev.status["reverse_limit_switch"], what="reverse limit at the home end")
    assert not dev.status["forward_limit_switch"]
    emu.set_limit_switch(100_000)
    dev.move_absolute(300_000)
    until(lambda: emu.channels[0x50].motion is None and emu.position() == 100_000,
          what="stopped at the switch moving forward")
    until(lambda: dev.status["position"] == 100_000 and dev.status["forward_limit_switch"],
          what="forward limit seen by the client")
    assert not dev.status["reverse_limit_switch"]
    emu.set_limit_switch(50_000)
    dev.move_absolute(0)
    until(lambda: emu.channels[0x50].motion is None and emu.position() == 50_000,
          what="stopped at the switch moving back")
    until(lambda: dev.status["position"] == 50_000 and dev.status["reverse_limit_switch"],
          what="reverse limit seen by the client")
    assert not dev.status["forward_limit_switch"]
    emu.set_limit_switch(None)
    dev.move_absolute(900_000)  # past the end of the travel: stops at the end switch
    until(lambda: emu.channels[0x50].motion is None and emu.position() == 863874,
          what="stopped at the end of the travel")
    until(lambda: dev.status["position"] == 863874 and dev.status["forward_limit_switch"],
          what="forward limit at the end of the travel")
    assert not dev.status["reverse_limit_switch"]

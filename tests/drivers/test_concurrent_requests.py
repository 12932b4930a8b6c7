"""Concurrent requests of the same message, in every driver with a request table.

A GUI's 1 Hz status poll and a running plan ask the same controller the same thing
(APT MOT_REQ_STATUSBITS to 0x50, Zaber ``get pos``, DLPC350 main status) from two
threads. Each test runs many threads doing that at once against the emulator: every
request must get its own reply (no KeyError, no timeout, no reply taken by the
other thread).
"""

from __future__ import annotations

import struct
import threading

import pytest

from drivers.dlp_lightcrafter import LightCrafter4500
from drivers.template import TemplateStage
from drivers.thorlabs_apt import ThorlabsAptStage
from drivers.thorlabs_apt_protocol import MSG
from drivers.zaber_ascii import ZaberAsciiStage
from tests.mocks import (
    AptEmulator,
    Dlpc350Emulator,
    FakeHid,
    TemplateStageEmulator,
    ZaberEmulator,
)

THREADS, ROUNDS = 8, 25


def hammer(call, threads: int = THREADS, rounds: int = ROUNDS) -> list:
    """Run ``call()`` ``rounds`` times in each of ``threads`` threads started together;
    return the exceptions raised (empty when every call succeeded)."""
    errors: list[BaseException] = []
    start = threading.Barrier(threads)

    def work():
        start.wait()
        try:
            for _ in range(rounds):
                call()
        except BaseException as exc:  # collected and reported by the test
            errors.append(exc)

    pool = [threading.Thread(target=work) for _ in range(threads)]
    for t in pool:
        t.start()
    for t in pool:
        t.join(60.0)
    assert not any(t.is_alive() for t in pool), "a request thread hung"
    return errors


def test_apt_same_message_from_many_threads(tmp_path):
    emu = AptEmulator("kdc101", time_scale=200.0, update_period_s=0.01,
                      link=tmp_path / "usb-Thorlabs_Brushed_Motor_Controller_27000001-if00-port0")
    with emu:
        stage = ThorlabsAptStage("stage", axes=["z"], serial_numbers={"z": "27000001"},
                                 limits_mm={"z": [0.0, 25.0]}, speed_mm_s=2.0,
                                 search_dirs=[str(tmp_path)], reply_timeout_s=30.0)
        with stage:
            ctrl = next(iter(stage._ctrl.values()))

            def status_bits():
                reply = ctrl.request(MSG["MOT_REQ_STATUSBITS"], MSG["MOT_GET_STATUSBITS"], 0x50,
                                     param1=1, timeout_s=2.0)
                assert reply.msg_id == MSG["MOT_GET_STATUSBITS"] and len(reply.data) == 6

            errors = hammer(status_bits)
            assert not errors, errors[:3]
            assert not ctrl._waiting  # every request removed its own entry
            # the stage's own calls from two threads at once (a poll and a run)
            errors = hammer(lambda: (stage.is_moving(), stage.status()), threads=4, rounds=10)
            assert not errors, errors[:3]


def test_apt_late_reply_after_a_timeout_is_not_lost_to_the_next_request(tmp_path):
    """A request that timed out leaves nothing behind: the next request of the same
    message gets a reply (the dropped one's place is not taken by a stale waiter)."""
    with AptEmulator("kdc101", time_scale=200.0, update_period_s=0.01) as emu:
        stage = ThorlabsAptStage("stage", axes=["z"], port=emu.port, limits_mm={"z": [0, 25]},
                                 speed_mm_s=2.0, reply_timeout_s=30.0)  # a hang guard
        with stage:
            ctrl = next(iter(stage._ctrl.values()))
            emu.drop_replies(1)
            with pytest.raises(stage.timeout_error):
                ctrl.request(MSG["MOT_REQ_STATUSBITS"], MSG["MOT_GET_STATUSBITS"], 0x50,
                             param1=1, timeout_s=0.3)
            assert not ctrl._waiting
            ctrl.request(MSG["MOT_REQ_STATUSBITS"], MSG["MOT_GET_STATUSBITS"], 0x50,
                         param1=1, timeout_s=30.0)  # answered: 30 s is a hang guard


def test_zaber_same_command_from_many_threads(tmp_path):
    with ZaberEmulator({1: 1}, time_scale=100.0) as emu:
        stage = ZaberAsciiStage("stage", axes=["x"], port=emu.port, speed_mm_s=5.0,
                                reply_timeout_s=30.0, require_homed=False)
        with stage:
            def get_pos():
                status, flag, data = stage.command(1, 1, "get pos")
                assert status in ("IDLE", "BUSY") and data.lstrip("-").isdigit()

            errors = hammer(get_pos)
            assert not errors, errors[:3]
            errors = hammer(lambda: (stage.is_moving(), stage.positions()), threads=4, rounds=10)
            assert not errors, errors[:3]


def test_template_queries_from_many_threads():
    """The template's protocol has no message ids: only its lock pairs replies."""
    with TemplateStageEmulator(2, time_scale=100.0) as emu:
        with TemplateStage("stage", axes=["x", "y"], port=emu.port, reply_timeout_s=30.0) as stage:
            def queries():
                assert stage.query("AXES?") == "2"
                assert stage.query("TRAVEL? 2") == "0 50"

            errors = hammer(queries)
            assert not errors, errors[:3]
            errors = hammer(lambda: (stage.is_moving(), stage.positions()), threads=4, rounds=10)
            assert not errors, errors[:3]


def test_dlpc350_same_read_from_many_threads():
    hid = FakeHid(Dlpc350Emulator(reply_latency_s=0.001))
    with LightCrafter4500("dmd", hid_backend=hid, reply_timeout_s=30.0) as dmd:
        def reads():
            assert dmd.main_status() in (0x00, 0x01, 0x02)
            exposure, period = struct.unpack("<II", dmd.command(0x1A29, read=True)[:8])
            assert exposure <= period

        errors = hammer(reads)
        assert not errors, errors[:3]


def test_apt_reply_read_late_by_a_starved_reader_is_not_a_timeout(tmp_path):
    """The reader thread kept from a core past the request's deadline (a loaded machine)
    while the reply waits in the port: the request gets it; a reply that never comes
    is still a timeout, a few reads after the deadline."""
    import time

    with AptEmulator("kdc101", time_scale=200.0, update_period_s=0.01) as emu:
        stage = ThorlabsAptStage("stage", axes=["z"], port=emu.port, limits_mm={"z": [0, 25]},
                                 speed_mm_s=2.0, reply_timeout_s=30.0)  # a hang guard
        with stage:
            ctrl = next(iter(stage._ctrl.values()))
            read_some, stall, stalled = ctrl.link.read_some, threading.Event(), threading.Event()

            def starved(*args, **kwargs):
                if stall.is_set():
                    stall.clear()
                    stalled.set()
                    time.sleep(1.0)  # the reply arrives meanwhile
                return read_some(*args, **kwargs)

            ctrl.link.read_some = starved
            stall.set()
            assert stalled.wait(30.0)  # the reader is in its stalled read
            reply = ctrl.request(MSG["MOT_REQ_STATUSBITS"], MSG["MOT_GET_STATUSBITS"], 0x50,
                                 param1=1, timeout_s=0.3)
            assert reply.msg_id == MSG["MOT_GET_STATUSBITS"]
            emu.drop_replies(1)
            t0 = time.monotonic()
            with pytest.raises(stage.timeout_error):
                ctrl.request(MSG["MOT_REQ_STATUSBITS"], MSG["MOT_GET_STATUSBITS"], 0x50,
                             param1=1, timeout_s=0.3)
            assert 0.3 <= time.monotonic() - t0 < 30.0  # waited its 0.3 s; a hang guard
            assert ctrl._late == 0

"""The emulated bench: ``diffuserlab emulators start``, ``devices`` and a PSF sweep through
the real drivers (thorlabs-apt, zaber-ascii, illuminate, aravis on its fake camera)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from instrument.cli import main
from instrument.devices.emulated_bench import BENCH_TEMPLATE, DEFAULT_DIR, EmulatedBench
from instrument.runs.runstore import RunStore

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "bench-emulated.toml"


def test_example_file_is_the_template_for_the_default_directory():
    assert EXAMPLE.read_text() == BENCH_TEMPLATE.substitute(dir=str(DEFAULT_DIR))


def test_devices_and_psf_sweep_on_the_emulated_bench(tmp_path, capsys):
    with EmulatedBench(tmp_path / "links", time_scale=50.0) as emulated:
        bench = tmp_path / "bench.toml"
        bench.write_text(emulated.bench_text())
        assert main(["validate", str(bench)]) == 0
        capsys.readouterr()
        assert main(["devices", str(bench)]) == 0
        rows = [line.split()[:4] for line in capsys.readouterr().out.splitlines()[1:]]
        assert rows == [
            ["camera", "camera", "aravis", "open"],
            ["source_stage", "stage", "thorlabs-apt", "open"],
            ["led_array", "led_array", "illuminate", "open"],
            ["slm", "slm", "simulated-slm", "open"],
            ["mask_stage", "stage", "zaber-ascii", "open"],
        ]
        run = tmp_path / "sweep.zarr"
        code = main(["calibrate", "psf-sweep", str(bench), "--n-depths", "3", "--z-min", "20",
                     "--z-max", "60", "--spacing", "uniform", "--out", str(run)])
        assert code == 0
        store = RunStore.open(run)
        assert store.summary()["status"] == "complete"
        assert store.product("psf_stack")[0].shape == (3, 512, 512)
        z = emulated.emulators["apt-z"]
        assert z.position() == round(60.0 * 34554.96)  # the last depth, through the driver
        assert z.acks >= 1  # the driver acknowledged the status updates (keepalive)


def _start(tmp_path: Path, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "instrument.cli", "emulators", "start", "--dir",
           str(tmp_path / "links"), *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_ready(proc: subprocess.Popen, timeout_s: float = 30.0) -> list[str]:
    lines, deadline = [], time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line.rstrip("\n"))
        if line.strip() == "ready":
            return lines
    proc.kill()
    pytest.fail(f"emulators did not start: {lines} {proc.stderr.read()}")


def test_emulators_start_serves_until_sigterm(tmp_path):
    out = tmp_path / "bench.toml"
    proc = _start(tmp_path, "--bench-out", str(out), "--ledmx", "--duration-s", "60")
    try:
        lines = _wait_ready(proc)
        links = sorted(p.name for p in (tmp_path / "links").iterdir())
        assert len(links) == 6 and any("27000003" in n for n in links)
        assert all(os.path.exists(tmp_path / "links" / n) for n in links)
        assert f"bench file: {out}" in lines
        assert str(tmp_path / "links") in out.read_text()
        second = _start(tmp_path)  # the same directory: refused, the first keeps serving
        assert second.wait(30) == 2
        assert "already run" in second.stderr.read()
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
    assert "emulators stopped" in proc.stdout.read()
    assert list((tmp_path / "links").iterdir()) == []  # the links went with the ptys


def test_psf_sweep_survives_an_unplugged_stage_controller(tmp_path, capsys):
    """The z controller is unplugged during the sweep's first move and plugged back
    0.5 s later: the runner reconnects it (found again by serial number on its new pty,
    settings re-applied) and the run completes."""
    with EmulatedBench(tmp_path / "links", time_scale=20.0) as emulated:
        bench = tmp_path / "bench.toml"
        bench.write_text(emulated.bench_text())
        z = emulated.emulators["apt-z"]
        started = threading.Event()
        start = z._start

        def start_and_tell(ch, now, target, kind):  # the sweep's first move, as it starts
            start(ch, now, target, kind)
            if kind == "move" and abs(target - 20.0 * 34554.96) < 2:  # to z-min, 20 mm
                started.set()

        z._start = start_and_tell

        def yank():
            # waits on the move's start (60 s hang guard): polling for a motion under
            # way could miss a short one on a loaded host
            assert started.wait(60), "the sweep's move to z-min did not start"
            z.unplug()
            time.sleep(0.5)  # a lower bound: unplugged at least this long
            z.replug()

        thread = threading.Thread(target=yank, daemon=True)
        thread.start()
        run = tmp_path / "sweep.zarr"
        code = main(["calibrate", "psf-sweep", str(bench), "--n-depths", "2", "--z-min", "20",
                     "--z-max", "40", "--spacing", "uniform", "--out", str(run),
                     "--reconnect-timeout", "20"])
        thread.join(60)
        assert code == 0
        assert z.plug_count == 2  # it really was unplugged and plugged back
        assert RunStore.open(run).summary()["status"] == "complete"
        assert z.position() == round(40.0 * 34554.96)


def _wait_for_late_replies(emulators, guard_s: float = 60.0) -> None:
    """Wait until the late replies of ``emulators`` were sent: none is still due (each
    is a timer thread calling the emulator's ``emit``), up to a hang guard."""
    deadline = time.monotonic() + guard_s
    while time.monotonic() < deadline:
        if not any(isinstance(t, threading.Timer) and t.is_alive()
                   and getattr(t.function, "__self__", None) in emulators
                   for t in threading.enumerate()):
            return
        time.sleep(0.01)
    raise AssertionError(f"late replies still due after {guard_s:g} s")


def test_the_emulated_bench_opens_though_its_emulators_answer_late(tmp_path):
    """On a loaded computer the emulators' process can answer a second or more late
    (a bench open failed so, at load 5, on the Zaber's 1 s reply timeout). The bench file
    waits up to 5 s for a reply from each serial device: the bench opens with the first
    reply of every serial controller 2 s late, where the drivers' defaults time out."""
    from instrument.devices.bench_setup import BenchOpenError, load_bench, open_bench

    late = ("apt-z", "zaber", "illuminate")
    with EmulatedBench(tmp_path / "links", time_scale=50.0) as emulated:
        text = emulated.bench_text()
        assert text.count("reply_timeout_s = 5.0") == 3
        bench = tmp_path / "bench.toml"
        bench.write_text(text)
        for name in late:
            emulated.emulators[name].delay_replies(2.0)
        with open_bench(load_bench(bench)) as opened:
            assert len(opened) == 5 and all(dev.is_open for dev in opened.values())

        strict = tmp_path / "strict.toml"
        strict.write_text(text.replace("reply_timeout_s = 5.0\n", ""))
        _wait_for_late_replies([emulated.emulators[name] for name in late])
        emulated.emulators["zaber"].delay_replies(2.0)
        with pytest.raises(BenchOpenError, match="mask_stage.*no reply to"):
            open_bench(load_bench(strict))

"""The bench process's typed service: commands by device id, events pushed to every
client, a second client (a notebook) on the bench a window holds open."""

from __future__ import annotations

import json
import queue
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from instrument.bench.bench_process import BenchClient
from instrument.bench.bench_service import BenchServiceError, DeviceInfo

from .test_bench_process import OPEN, opened_bench

#: Hang guard, s: the longest any step may take on a loaded machine.
HANG_S = 90.0


def nudge(ctx, *, stage: str, x_mm: float) -> None:
    """A job that moves a stage itself (as a calibration run does), not through the
    service's commands."""
    ctx.bench.devices[stage].move_to({"x": x_mm})


class Events:
    """The events a client was pushed, waited on by what they say."""

    def __init__(self) -> None:
        self.queue: queue.SimpleQueue = queue.SimpleQueue()
        self.seen: list = []

    def __call__(self, event) -> None:
        self.queue.put(event)

    def wait(self, test, what: str):
        deadline = time.monotonic() + HANG_S
        while True:
            for event in self.seen:
                if test(event):
                    self.seen.remove(event)
                    return event
            try:
                self.seen.append(self.queue.get(timeout=max(0.0, deadline - time.monotonic())))
            except queue.Empty:
                pytest.fail(f"no event {what} within {HANG_S:.0f} s")


@pytest.fixture(params=[False, True], ids=["child-process", "in-process"])
def client(request):
    events = Events()
    with opened_bench(in_process=request.param, jobs={"nudge": nudge}, on_event=events) as c:
        c.events = events
        yield c


def test_the_devices_are_plain_data_with_their_declarations(client):
    devices = {d.name: d for d in client.devices()}
    assert list(devices) == ["camera", "source_stage", "led_array", "slm", "mask_stage"]
    stage = devices["source_stage"]
    assert isinstance(stage, DeviceInfo) and stage.kind == "stage"
    assert stage.driver_name == "SimulatedStage"
    assert "velocity" in [s.name for s in stage.settings_declared]  # imported here
    assert "x" in stage.axes and stage.units["x"] == "mm"
    low, high = stage.travel["x"]
    assert low < 0.5 < high
    leds = devices["led_array"].led_positions_mm
    assert leds.ndim == 2 and leds.shape[1] == 2 and len(leds) > 1
    assert devices["slm"].resolution == tuple(devices["slm"].info["resolution"])
    assert 0 < devices["camera"].info["exposure_range_s"][0]
    assert client.is_virtual()


def test_commands_move_apply_show_and_read(client):
    from drivers.errors import DeviceError, StageLimitError

    assert client.move("source_stage", {"x": 0.5})["x"] == pytest.approx(0.5)
    assert client.positions("source_stage")["x"] == pytest.approx(0.5)
    assert client.move("source_stage", {"x": 0.25}, relative=True)["x"] == pytest.approx(0.75)
    with pytest.raises(StageLimitError):
        client.move("source_stage", {"x": 1e6})
    assert client.positions("source_stage")["x"] == pytest.approx(0.75)

    before = client.setting_values("camera")["exposure_s"]
    applied = client.apply_settings("camera", {"exposure_s": before * 2})
    assert applied["exposure_s"] == pytest.approx(before * 2)
    with pytest.raises(DeviceError):  # refused: nothing applied
        client.apply_settings("camera", {"exposure_s": -1.0})
    assert client.settings("camera")["exposure_s"] == pytest.approx(before * 2)

    assert sorted(client.show("led_array", [3])) == [3]
    assert client.show("led_array", "off") == {}
    rows, cols = next(d for d in client.devices() if d.name == "slm").resolution
    client.show("slm", np.zeros((rows, cols)))

    fmt = client.camera_format()
    assert fmt.image_shape == (256, 320) and fmt.bit_depth == 12
    assert fmt.dark_offset_dn is not None  # the simulated camera's
    frame = client.snap()
    assert frame.image.shape == fmt.image_shape
    assert client.settings_snapshot()["camera"]["settings"]["exposure_s"] == pytest.approx(
        before * 2)


def test_a_command_names_an_unknown_device_or_the_wrong_kind(client):
    with pytest.raises(BenchServiceError, match="no device 'stagey'.*source_stage"):
        client.move("stagey", {"x": 0.0})
    with pytest.raises(BenchServiceError, match="camera is a camera, not a stage"):
        client.positions("camera")


def test_changes_are_pushed_to_the_client(client):
    events = client.events
    events.wait(lambda e: e.kind == "bench" and e.data["open"], "of the bench opening")
    # the watcher's first reading of every device
    first = events.wait(lambda e: e.kind == "status" and e.device == "camera",
                        "of the camera's status")
    assert first.data["status"]["is_open"] and "exposure_s" in first.data["values"]

    client.apply_settings("camera", {"exposure_s": 0.004})
    got = events.wait(lambda e: e.kind == "settings" and e.device == "camera",
                      "of the camera's settings")
    assert got.data["exposure_s"] == pytest.approx(0.004)
    client.move("source_stage", {"x": 1.0})
    got = events.wait(lambda e: e.kind == "positions" and e.device == "source_stage",
                      "of the stage's move")
    assert got.data["x"] == pytest.approx(1.0)
    # a job moves the stage itself: the bench process's watcher notices and pushes it
    client.run_job("nudge", {"stage": "source_stage", "x_mm": 2.0})
    events.wait(lambda e: e.kind == "positions" and e.device == "source_stage"
                and abs(e.data["x"] - 2.0) < 1e-6, "of the job's move")
    client.run_job("close_bench")
    events.wait(lambda e: e.kind == "bench" and not e.data["open"], "of the bench closing")
    assert client.devices() == []


def _notebook(tmp_path) -> str:
    """A notebook's cell: connect to the open bench by address and key, move the stage,
    apply a camera setting, and try to close the bench (it stays open)."""
    script = textwrap.dedent(f"""
        import json, sys
        sys.path[:0] = {sys.path!r}
        from instrument.bench.bench_process import BenchClient
        from instrument.bench.bench_service import BenchServiceError
        if __name__ == "__main__":
            address, key = json.loads(sys.stdin.readline())
            nb = BenchClient(address=address, authkey=bytes.fromhex(key))
            out = {{"devices": [d.name for d in nb.devices()],
                   "moved": nb.move("source_stage", {{"x": 3.0}}),
                   "applied": nb.apply_settings("camera", {{"exposure_s": 0.006}})}}
            try:
                nb.run_job("close_bench")
            except BenchServiceError as exc:
                out["run_job"] = str(exc)
            nb.close()
            print(json.dumps(out), flush=True)
        """)
    path = tmp_path / "notebook.py"
    path.write_text(script)
    return str(path)


def test_a_second_client_drives_the_bench_the_window_holds_open(tmp_path):
    events = Events()
    window = BenchClient(on_event=events)
    try:
        window.run_job("open_bench", OPEN)
        notebook = subprocess.run(
            [sys.executable, _notebook(tmp_path)], capture_output=True, text=True,
            input=json.dumps([window.address, window.authkey.hex()]) + "\n", timeout=HANG_S)
        assert notebook.returncode == 0, notebook.stderr
        out = json.loads(notebook.stdout)
        assert out["devices"] == [d.name for d in window.devices()]
        assert out["moved"]["x"] == pytest.approx(3.0)
        assert "client that started the bench process" in out["run_job"]
        # the window was pushed what the notebook did, and its bench is still open
        got = events.wait(lambda e: e.kind == "positions" and e.device == "source_stage"
                          and abs(e.data["x"] - 3.0) < 1e-6, "of the notebook's move")
        assert got.data["x"] == pytest.approx(3.0)
        events.wait(lambda e: e.kind == "settings" and e.device == "camera"
                    and e.data["exposure_s"] == pytest.approx(0.006),
                    "of the notebook's setting")
        assert window.positions("source_stage")["x"] == pytest.approx(3.0)
        assert window.settings("camera")["exposure_s"] == pytest.approx(0.006)
    finally:
        window.close()


def test_a_second_client_needs_the_bench_process_key():
    from multiprocessing import AuthenticationError

    window = BenchClient()
    try:
        with pytest.raises(AuthenticationError):
            BenchClient(address=window.address, authkey=b"not the key")
    finally:
        window.close()

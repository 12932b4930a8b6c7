"""The Devices panel's Connect button cancels a bench that is still opening (a stage
homing at open): the button reads Cancel while the bench opens, and pressing it stops
the open within the devices' 0.1 s checks, and nothing is left open."""

from __future__ import annotations

import time

from drivers.base import Device
from instrument.config import default_bench
from instrument.config.writer import to_toml
from instrument.devices import registry

OPENED: list[Device] = []


class HomingStage(Device):
    """A stage whose open waits (as homing at open does) until cancelled."""

    kind = "stage"

    def __init__(self, device_id, **params):
        super().__init__(device_id, **params)
        OPENED.append(self)

    def _do_open(self, timeout_s):
        while True:  # the open's own bounds end it: its cancel event here
            self._check_cancel("while homing")
            time.sleep(0.01)

    def _do_close(self):
        pass

    def _do_get_info(self):
        return {}

    def _do_get_settings(self):
        return {}

    def _do_apply(self, name, value):
        return None


def test_connect_button_cancels_an_open_in_progress(qapp, tmp_path, monkeypatch, wait):
    from gui.panels.devices import DevicePanel
    from gui.session import Session

    monkeypatch.setattr(registry, "_local", {})
    monkeypatch.setattr("gui.session.BENCH_IN_PROCESS", True)  # the driver is registered here
    registry.register("homing-stage", HomingStage)
    bench = default_bench()  # the simulated bench, its source stage homing at open
    bench = bench.model_copy(update={"devices": [
        d.model_copy(update={"driver": "homing-stage"}) if d.id == "source_stage" else d
        for d in bench.devices]})
    path = tmp_path / "bench.toml"
    path.write_text(to_toml(bench))
    session = Session(str(path), simulate=False)
    panel = DevicePanel(session)
    panel.toggle_connection()
    wait(lambda: OPENED or panel.error.text(), 30, "the open to start")
    assert not panel.error.text()
    assert panel.connect_button.text() == "Cancel" and panel.connect_button.isEnabled()
    panel.toggle_connection()
    wait(lambda: panel.connect_button.text() == "Connect", 30, "the open to stop")
    assert "cancelled while homing" in panel.error.text()
    assert panel.state.text() == "not connected" and not session.connected
    assert not any(d.is_open for d in OPENED)
    panel.deleteLater()

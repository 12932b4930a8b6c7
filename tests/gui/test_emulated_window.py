"""A window on the emulated bench (the real drivers on their protocol emulators).

A completed mask alignment leaves the mask stage where it aligned it: the bench
restore after the job puts back what the job changed to take its readings (the
camera's exposure, the LEDs), never the pose the job exists to produce, and the pose
is still there after the window is closed and a new one opens the bench again (the
emulated bench: the real Zaber driver on its protocol emulator, which keeps its
position between the two windows as a stage does).

Every device's state is watched the same way: an idle LED array whose port hangs up
turns red as soon as a polled stage does."""

from __future__ import annotations

import pytest

ALIGNED = {"x": 0.08, "y": 0.05, "z": 0.3, "tip": 0.02, "tilt": 0.01, "rotation": 0.13}


class _FakeAligner:
    """Moves the mask stage to :data:`ALIGNED` and changes the exposure, as the
    alignment does (its readings take their own exposure), then reports a pass."""

    def __init__(self, bench, model, cfg, *, record, control, on_event):
        self.bench = bench

    def run(self) -> dict:
        self.bench.camera.apply_settings({"exposure_s": 0.004})
        self.bench.mask_stage.move_to(ALIGNED, timeout_s=30.0)
        return {"steps": {"verify": {"passed": True, "eta_ratio": [1.0] * 15}},
                "summary": {"translation_px": (0.0, 0.0), "theta_rad": 0.0, "captures": 3,
                            "stage_pose": self.bench.mask_stage.positions()}}


@pytest.fixture
def emulators(tmp_path):
    """The running emulators (:class:`instrument.devices.emulated_bench.EmulatedBench`)."""
    from instrument.devices.emulated_bench import EmulatedBench

    with EmulatedBench(tmp_path / "ports", time_scale=50.0) as bench:
        yield bench


@pytest.fixture
def emulated(emulators, tmp_path):
    """The bench file naming the emulators' ports."""
    path = tmp_path / "bench-emulated.toml"
    path.write_text(emulators.bench_text())
    return str(path)


def _open_window(qapp, bench_file: str):
    from gui.app import MainWindow
    from gui.session import Session
    from tests.gui.conftest import wait_for

    w = MainWindow(Session(bench_file))
    w.show()
    w.session.connect_bench()
    wait_for(qapp, lambda: w.session.connected, 120.0, "the emulated bench to open")
    return w


def _close(qapp, w) -> None:
    from tests.gui.conftest import wait_for

    w.confirm = lambda title, text: True
    w.close()
    wait_for(qapp, lambda: not w.isVisible(), 60.0, "the window to close")
    w.deleteLater()
    qapp.processEvents()


def test_a_completed_alignment_keeps_the_mask_at_the_aligned_pose(qapp, wait, emulated,
                                                                   tmp_path, monkeypatch):
    import calibration_routines.mask_alignment as mask_alignment

    monkeypatch.setenv("DIFFUSERLAB_GUI_SETTINGS", str(tmp_path / "gui.ini"))
    monkeypatch.setattr(mask_alignment, "MaskAligner", _FakeAligner)
    monkeypatch.setattr("gui.session.BENCH_IN_PROCESS", True)  # the fake runs here
    w = _open_window(qapp, emulated)
    try:
        service = w.session.service
        exposure = service.settings("camera")["exposure_s"]
        start = service.positions("mask_stage")
        assert start != pytest.approx(ALIGNED, abs=1e-3)
        al = w.alignment
        al.out.setText(str(tmp_path / "mask.align"))
        al.seed.setText("7")
        job = al.start()
        wait(lambda: job.done, 60, "the alignment")
        assert "completed (passed)" in al.message.text(), al.message.text()
        assert service.positions("mask_stage") == pytest.approx(ALIGNED, abs=2e-3)
        # what the job changed only to take its readings is put back
        assert service.settings("camera")["exposure_s"] == pytest.approx(exposure)
    finally:
        _close(qapp, w)
    again = _open_window(qapp, emulated)
    try:
        assert again.session.service.positions("mask_stage") == pytest.approx(ALIGNED,
                                                                              abs=2e-3)
    finally:
        _close(qapp, again)


def test_an_aborted_alignment_puts_the_mask_back(qapp, wait, emulated, tmp_path, monkeypatch):
    """A half-done alignment is no pose to keep: the stage goes back where it was."""
    import calibration_routines.mask_alignment as mask_alignment
    from instrument.acquisition.runner import RunAborted

    class _Aborted(_FakeAligner):
        def run(self) -> dict:
            super().run()
            raise RunAborted("aborted by the operator")

    monkeypatch.setenv("DIFFUSERLAB_GUI_SETTINGS", str(tmp_path / "gui.ini"))
    monkeypatch.setattr(mask_alignment, "MaskAligner", _Aborted)
    monkeypatch.setattr("gui.session.BENCH_IN_PROCESS", True)  # the fake runs here
    w = _open_window(qapp, emulated)
    try:
        start = w.session.service.positions("mask_stage")
        al = w.alignment
        al.out.setText(str(tmp_path / "mask.align"))
        al.seed.setText("7")
        job = al.start()
        wait(lambda: job.done, 60, "the alignment")
        assert "stopped" in al.message.text(), al.message.text()
        assert w.session.service.positions("mask_stage") == pytest.approx(start, abs=2e-3)
    finally:
        _close(qapp, w)


def test_an_unplugged_idle_led_array_turns_red_as_a_stage_does(qapp, wait, emulators, emulated,
                                                               tmp_path, monkeypatch):
    """Nothing is sent to the array after the unplug: its box and the status area say
    DISCONNECTED within the status poll's seconds (it said "open" for over a minute),
    and the device count names it."""
    monkeypatch.setenv("DIFFUSERLAB_GUI_SETTINGS", str(tmp_path / "gui.ini"))
    w = _open_window(qapp, emulated)
    try:
        box = w.devices.boxes["led_array"]
        wait(lambda: "open" in box.state.text(), 20, "the array's first status")
        # the operator's words: no driver dicts (APT setups) or JSON in the boxes, and
        # no "auto" dark level that this bench refuses with a PSF sweep
        for dev_id, b in w.devices.boxes.items():
            texts = [lab.text() for lab in b.status_labels.values()]
            texts += [f.text() for n, f in b.fields.items() if n != "lut_rad"]
            assert not [t for t in texts if "{" in t or "[]" in t or "'" in t], (dev_id, texts)
        assert "auto" not in w.live.dark.placeholderText()
        assert "dark run" in w.record.batch_fields["--dark"].placeholderText()
        emulators.emulators["illuminate"].unplug()
        wait(lambda: "DISCONNECTED" in box.state.text(), 20, "the array shown disconnected")
        assert "DISCONNECTED" in w.device_labels["led_array"].text()
        assert "led_array" in w.devices.state.text()
        emulators.emulators["illuminate"].replug()
        box.reconnect()
        wait(lambda: "DISCONNECTED" not in box.state.text() and "open" in box.state.text(),
             30, "the array reconnected")
    finally:
        _close(qapp, w)

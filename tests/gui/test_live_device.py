"""The Live panel's device choice (offscreen): remembered between sessions, handed to
the live reconstructor built on the worker, and an unusable choice refused with the
operator's message while the raw stream goes on."""

from __future__ import annotations

import pytest

import recon.live
from recon.backend import resolve_device, torch_cpu
from tests.recon.test_device import no_gpu


def test_the_device_choice_is_remembered_across_sessions(qapp, tmp_path, monkeypatch):
    monkeypatch.setenv("DIFFUSERLAB_GUI_SETTINGS", str(tmp_path / "gui.ini"))
    from gui.app import MainWindow
    from gui.session import Session

    first = MainWindow(Session(None, simulate=True, scene="none"))
    assert [first.live.device.itemText(i) for i in range(first.live.device.count())] == [
        "cpu", "cuda", "auto"]
    assert first.live.device.currentText() == "cpu"  # the default, as on the command line
    first.live.device.setCurrentText("auto")
    first.shutdown()
    first.deleteLater()
    second = MainWindow(Session(None, simulate=True, scene="none"))
    try:
        assert second.live.device.currentText() == "auto"
    finally:
        second.shutdown()
        second.deleteLater()


def _raw_frames_advance(window, wait) -> None:
    first = window.session.latest_frame().index
    wait(lambda: window.session.latest_frame().index > first + 2, 20, "more raw frames")


@no_gpu
def test_an_unusable_device_is_a_message_and_the_raw_view_goes_on(window, wait, psf_file):
    live, session = window.live, window.session
    live.psf.setText(psf_file)
    live.depth.setEditText("")
    live.dark.setText("")
    live.device.setCurrentText("cuda")
    job = session.stream_job(True)
    wait(lambda: job.done and session.latest_frame() is not None, 30, "the stream")
    try:
        job = live.start_reconstruction()
        wait(lambda: job.done, 60, "the refusal")
        text = live.error.text()
        assert "cuda requested but" in text and "diffuserlab[gpu]" in text, text
        assert "Traceback" not in text and "bug" not in text
        assert live.live is None and live.recon_button.text() == "Start reconstruction"
        assert live.recon_button.isEnabled() and live.device_used.text() == ""
        assert session.streaming
        _raw_frames_advance(window, wait)
    finally:
        live.device.setCurrentText("cpu")
        job = session.stream_job(False)
        wait(lambda: job.done and not session.streaming, 15, "the stream to stop")


def test_the_chosen_device_runs_the_live_reconstruction(window, wait, psf_file, monkeypatch):
    standin = torch_cpu()
    if standin is None:
        pytest.skip("PyTorch is not installed")
    asked = []

    def resolve(name):
        asked.append(name)
        return standin if name == "cuda" else resolve_device(name)

    monkeypatch.setattr(recon.live, "resolve_device", resolve)  # the GPU's stand-in
    monkeypatch.setattr("gui.jobs.LIVE_IN_PROCESS", False)  # the stand-in is in this process
    live = window.live
    live.psf.setText(psf_file)
    live.depth.setEditText("")
    live.dark.setText("")
    live.method.setCurrentText("admm")
    live.iterations.setValue(2)
    live.device.setCurrentText("cuda")
    job = live.start_reconstruction()
    try:
        wait(lambda: job.done, 60, "the live reconstruction to build")
        assert live.live is not None, live.error.text()
        assert asked == ["cuda"]
        reconstructor = live.live.reconstructor
        assert reconstructor.backend is standin
        assert live.device_used.text() == f"running on {standin.label}"
        wait(lambda: live._shown_recon >= 0, 120, "a reconstruction")
        first = live._shown_recon
        wait(lambda: live._shown_recon > first, 60, "the next reconstruction")
        assert type(reconstructor.state.x).__module__ == "torch"  # the warm state's device
        assert "errors 0" in live.recon_stats.text()
        assert live.recon_view.image.shape == window.session.service.camera_format().image_shape
        meta = live.recon_view.snapshot_metadata()["reconstruction"]
        assert meta["device"] == standin.label and meta["device_requested"] == "cuda"
    finally:
        live.stop_reconstruction()
        live.device.setCurrentText("cpu")
        live.method.setCurrentText("wiener")
        window.session.stop_stream()
    wait(lambda: not window.session.streaming and live.job.done, 15, "the stream to stop")
    assert live.device_used.text() == ""

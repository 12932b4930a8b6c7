"""The window beside a notebook in a process of its own, on one bench: the window shows
where the notebook attaches, lists the notebook's job with its owner and stops it after
asking, asks before Ctrl+Q would end it, and its live view yields the camera to the
notebook's recording and takes it back."""

from __future__ import annotations

import os

import pytest

from tests.instrument import bench_clients as other
from tests.instrument.bench_clients import OtherClient


@pytest.fixture
def notebook(window):
    service = window.session.service
    client = OtherClient(service.address, service.authkey)
    yield client
    client.close()
    for info in service.jobs():  # a failed test's job does not outlive it
        if info.state == "running":
            service.job(info.id).stop()
            service.job(info.id).result(60.0)


def _recording(out, frames: int = 5000) -> dict:
    return {"out": str(out), "frames": frames, "options": {}}


def test_the_window_shows_where_a_notebook_attaches(window):
    service = window.session.service
    text = window.devices.bench_jobs.where.text()
    assert str(service.address) in text and service.connection_file in text
    assert os.path.exists(service.connection_file)


def test_a_notebook_s_job_is_listed_stopped_after_asking_and_asked_about_at_quit(
        window, notebook, wait, tmp_path):
    panel = window.devices.bench_jobs
    job_id = notebook.value(other.start, "record", _recording(tmp_path / "nb.zarr"))
    notebook.value(other.wait_recorded, job_id, 0)
    wait(lambda: [i.id for i in panel.infos] == [job_id], 60.0, "the notebook's job listed")
    listed = panel.list.item(0).text()
    assert f"job {job_id} record of {notebook.name}" in listed and "holds camera" in listed
    # Ctrl+Q asks first, naming the notebook's job; No keeps the window and the job
    asked: list = []
    window.confirm = lambda title, text: asked.append(text) or False
    try:
        window.close()
        assert window.isVisible() and not window._closing
    finally:
        del window.confirm
    assert len(asked) == 1 and f"job {job_id} (record) of {notebook.name}" in asked[0].lower()
    assert notebook.value(other.wait_recorded, job_id, 1) > 1  # still recording
    # Stop job asks, naming the owner, then stops it
    questions: list = []
    panel.confirm = lambda title, text: questions.append(text) or True
    try:
        assert panel.stop_selected()
    finally:
        del panel.confirm
    assert questions and notebook.name in questions[0]
    assert notebook.value(other.result, job_id)["status"] == "stopped"
    wait(lambda: panel.infos == [], 60.0, "the stopped job to leave the list")


def test_the_live_view_yields_the_camera_to_a_notebook_s_recording(
        window, notebook, wait, tmp_path):
    session = window.session
    session.stream_job(True)
    wait(lambda: session.streaming and session.frames_seen > 2, 60.0, "the live view")
    job_id = notebook.value(other.start, "record", _recording(tmp_path / "nb.zarr", 10))
    log = window.log_pane.text
    wait(lambda: f"taken by job {job_id} (record) of {notebook.name}" in log.toPlainText(),
         60.0, "the log to say who took the camera")
    assert notebook.value(other.result, job_id)["recorded"] == 10
    wait(lambda: f"camera is back from job {job_id}" in log.toPlainText(), 60.0,
         "the live view to come back")
    seen = session.frames_seen
    wait(lambda: session.frames_seen > seen + 2, 60.0, "frames of the live view again")
    assert session.streaming
    session.stream_job(False)
    wait(lambda: not session.streaming, 60.0, "the stream to stop")

"""The window's texts in an operator's words, and not clipped: a timed snapshot note,
driver messages without API calls or errno numbers, a lookup table as a summary, the
device count and the progress counts sized to their text."""

from __future__ import annotations

import numpy as np


def test_snapshot_saved_is_a_timed_note(qapp, wait, tmp_path, monkeypatch):
    import gui.imageview
    from gui.imageview import FrameView

    monkeypatch.setattr(gui.imageview, "NOTE_MS", 200)
    v = FrameView("test image", name="test")
    v.show()
    v.setImage(np.arange(60 * 80, dtype=np.float32).reshape(60, 80))
    shown: list[str] = []
    set_text = v.stats.setText
    v.stats.setText = lambda text: (shown.append(text), set_text(text))
    try:
        job = v.save_snapshot(tmp_path / "snap.tif")
        wait(lambda: any(t.startswith("snapshot saved: ") for t in shown), 10,
             "the snapshot's note")
        wait(lambda: v.stats.text() == "", 10, "the note to go")
        assert job.done and (tmp_path / "snap.tif").exists()
    finally:
        v.deleteLater()


def test_driver_messages_read_in_the_gui_words():
    from gui.device_status import status_fields

    fields = dict(status_fields("led_array", {
        "is_open": True, "disconnected": True,
        "error": "[Errno 111] Connection refused; check cable and power, then call "
                 "reconnect()"}))
    text = fields["error"]
    assert "Errno" not in text and "reconnect()" not in text, text
    assert "Connection refused" in text and "press Reconnect" in text


def test_a_lookup_table_is_a_summary_not_a_python_list(window):
    from gui.device_settings import value_text

    lut = list(np.linspace(0.0, 2 * np.pi, 256, endpoint=False))
    assert value_text(lut, "lut_rad") == "256 values, 0 to 6.26"
    edit = window.devices.boxes["slm"].fields["lut_rad"]
    assert "[" not in edit.text() and edit.text().startswith("256 values, 0 to ")
    assert edit.text().endswith(" rad") and "calibration" in edit.toolTip()
    assert value_text([1, 2], "pair") == "[1, 2]"  # a short list is typed as it is


def test_the_device_count_is_not_clipped(window, qapp):

    label = window.devices.state
    before = label.text()
    try:
        label.setText("5 devices: 2 open, <b>3 disconnected (camera, source_stage, "
                      "mask_stage)</b>")
        qapp.processEvents()
        assert label.wordWrap()
        assert label.heightForWidth(label.width()) <= label.height()
    finally:
        label.setText(before)


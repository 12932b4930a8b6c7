"""What operators from Micro-Manager, PyMoDAQ and napari expect (offscreen): image tools
on every view, nothing typed twice, device state always visible with Reconnect,
presets and stored positions, shortcuts and arrow-key jog, the log pane, the layout."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np
import pytest
from PySide6.QtCore import Qt
from PySide6.QtTest import QTest


@pytest.fixture
def view(qapp):
    from gui.imageview import FrameView

    v = FrameView("test image", name="test")
    v.resize(500, 400)
    v.show()
    image = np.arange(60 * 80, dtype=np.float32).reshape(60, 80)
    image[10, 20] = -5.0
    v.setImage(image)
    yield v, image
    v.deleteLater()


def test_pixel_readout_names_the_pixel_under_the_cursor(view):
    v, image = view
    assert v.pixel_text(20.4, 10.9) == "x 20, y 10: -5"
    assert v.pixel_text(79.0, 59.0) == f"x 79, y 59: {image[59, 79]:.5g}"
    assert v.pixel_text(80.0, 0.0) == "" and v.pixel_text(-1.0, 3.0) == ""


def test_roi_statistics_are_the_pixels_inside_it(view):
    v, image = view
    v.show_roi(True)
    v.roi.setPos((10, 5))
    v.roi.setSize((30, 20))
    s = v.roi_statistics()
    block = image[5:25, 10:40]
    assert s["pixels"] == block.size
    assert s["mean"] == pytest.approx(block.mean()) and s["max"] == block.max()
    assert s["min"] == block.min() == -5.0 and s["std"] == pytest.approx(block.std())
    assert "mean" in v.stats.text() and "30 x 20 px" in v.stats.text()
    v.show_roi(False)
    assert v.roi_statistics() is None and v.stats.text() == ""


def test_line_profile_follows_the_line(view):
    v, image = view
    v.show_profile(True)
    assert v.profile_plot.isVisibleTo(v)
    v.set_line((0.0, 30.0), (79.0, 30.0))  # along row 30 (pyqtgraph samples at indices)
    dist, values = v.profile()
    assert dist[-1] == pytest.approx(78.0)  # samples 1 px apart from the start
    assert values == pytest.approx(np.interp(dist, np.arange(80), image[30]), abs=1e-3)
    v.set_line((40.0, 0.0), (40.0, 59.0))  # down column 40
    dist, values = v.profile()
    assert values == pytest.approx(np.interp(dist, np.arange(60), image[:, 40]), abs=1e-3)
    v.show_profile(False)
    assert v.profile() is None and not v.profile_plot.isVisibleTo(v)


def test_auto_levels_min_max_percentile_and_lock(view):
    v, image = view
    v.level_mode.setCurrentText("min/max")
    v.auto_levels()
    assert v.levels() == (pytest.approx(-5.0), pytest.approx(image.max()))
    v.level_mode.setCurrentText("5-95 %")
    v.auto_levels()
    lo, hi = v.levels()
    sample = image[::1, ::1]
    assert lo == pytest.approx(np.percentile(sample, 5), rel=0.05)
    assert hi == pytest.approx(np.percentile(sample, 95), rel=0.05)
    v.lock_levels(True)
    v.setImage(image * 10)  # new images keep the locked levels
    assert v.levels() == (pytest.approx(lo), pytest.approx(hi))
    v.lock_levels(False)
    v.setImage(image * 10)
    assert v.levels()[1] == pytest.approx(10 * hi, rel=0.05)
    # dragging the histogram's region locks the levels (manual levels stay)
    v.histogram.region.setRegion((100.0, 200.0))
    assert v.levels_locked


def test_video_mode_levels_follow_the_newest_image_at_the_end_of_the_period(qapp, wait):
    """In video mode a burst of images is shown with the first one's levels, and the
    newest gets its own levels, histogram and ROI statistics when the period ends (a
    slider scrubbed through a run must not rest on a stale image's levels)."""
    from gui.imageview import FrameView

    v = FrameView("video", histogram_hz=4.0)
    v.resize(500, 400)
    v.show()
    v.level_mode.setCurrentText("min/max")
    v.show_roi(True)
    ramp = np.arange(40 * 50, dtype=np.float32).reshape(40, 50)
    v.setImage(ramp)
    first = v.levels()
    assert first == (pytest.approx(0.0), pytest.approx(ramp.max()))
    for k in (2, 3, 4):  # within the period: swapped alone
        v.setImage(ramp * k)
    assert v.levels() == first
    assert np.array_equal(v.item.image, ramp * 4)
    wait(lambda: v.levels()[1] == pytest.approx(4 * ramp.max()), 2.0,
         "the newest image's levels at the end of the period")
    hist_x, _ = v.histogram.plot.getData()
    assert hist_x.max() > 3 * ramp.max()  # the histogram is the newest image's
    assert f"max {4 * ramp[:20, :20].max():.5g}," in v.stats.text()  # the 20 px ROI
    v.lock_levels(True)  # locked: a burst's end keeps them
    v.setImage(ramp)
    v.setImage(ramp * 9)
    qapp.processEvents()
    wait(lambda: not v._catch_up.isActive(), 2.0, "the period's end")
    assert v.levels()[1] == pytest.approx(4 * ramp.max())
    v.deleteLater()


def test_colormap_choice_changes_the_lookup_table(view):
    v, _ = view
    grey = v.histogram.gradient.getLookupTable(256)
    v.set_colormap("viridis")
    lut = v.histogram.gradient.getLookupTable(256)
    assert not np.array_equal(lut, grey)
    assert lut[-1].tolist()[:3] != [255, 255, 255]
    with pytest.raises(ValueError, match="viridis"):
        v.set_colormap("rainbow-unicorn")


def test_save_snapshot_writes_the_image_and_its_metadata(view, wait, tmp_path):
    import tifffile

    v, image = view
    v.metadata = lambda: {"device_settings": {"camera": {"exposure_s": 0.01}},
                          "reconstruction": {"method": "admm", "iterations": 5}}
    v.show_roi(True)
    job = v.save_snapshot(tmp_path / "snap.tif")
    wait(lambda: job.done, 10, "the snapshot")
    with tifffile.TiffFile(tmp_path / "snap.tif") as tif:
        data = tif.asarray()
        meta = tif.shaped_metadata[0]
    assert np.array_equal(data, image) and data.dtype == image.dtype
    assert meta["title"] == "test image" and "time_utc" in meta and "levels" in meta
    assert meta["device_settings"]["camera"]["exposure_s"] == 0.01
    assert meta["reconstruction"]["method"] == "admm" and meta["roi"]["pixels"] > 0
    job = v.save_snapshot(tmp_path / "snap.tif")  # never replaces a file
    wait(lambda: job.done, 10, "the refusal")
    assert "not saved" in v.stats.text() and "never replaces" in v.stats.text()


def test_every_image_view_of_the_window_has_the_tools(window):
    from gui.imageview import FrameView

    views = window.findChildren(FrameView)
    assert len(views) >= 6  # raw, live reconstruction, calibration, result, 3 projections
    for v in views:
        texts = [a.text() for a in v.toolbar.actions()]
        for tool in ("ROI", "Profile", "Auto", "Lock", "Snapshot..."):
            assert tool in texts, (v.title(), texts)
    assert window.live.raw_view.metadata is not None
    meta = window.live.raw_view.snapshot_metadata()
    assert "camera" in meta["device_settings"]


# -- nothing typed twice ----------------------------------------------------------------------


def test_a_remembered_field_is_written_off_the_gui_thread(qapp, tmp_path, monkeypatch, wait):
    """Typing into a remembered field stores each change at once (read sees it) and the
    file is written by the settings writer's thread, never by the GUI thread: a sync
    calls fdatasync twice, which held key presses' repaints up to 276 ms."""
    import configparser
    import threading

    from PySide6.QtWidgets import QLineEdit

    import gui.fields as fields

    path = tmp_path / "gui.ini"
    monkeypatch.setenv("DIFFUSERLAB_GUI_SETTINGS", str(path))
    synced_on: list[str] = []
    real_sync = fields.QSettings.sync

    def sync(self):
        synced_on.append(threading.current_thread().name)
        real_sync(self)

    monkeypatch.setattr(fields.QSettings, "sync", sync)
    field = fields.remember(QLineEdit(), "test/dark")
    for text in ("6", "64", "64x", "64"):
        field.setText(text)
        assert fields.read("fields/test/dark") == text  # at once, written or not
    qapp.processEvents()
    wait(lambda: "settings-writer" in synced_on, 10, "the settings writer")
    assert threading.main_thread().name not in synced_on
    wait(lambda: path.exists(), 10, "the file")
    ini = configparser.ConfigParser()
    ini.read(path)
    assert ini["fields"]["test\\dark"] == "64"
    fields.store("fields/test/dark", "65")
    fields.flush()  # the window's close: written on the caller's thread, now
    ini.read(path)
    assert ini["fields"]["test\\dark"] == "65"
    assert fields.read("fields/test/dark") == "65"


def test_the_settings_file_is_synced_by_python_not_by_qsettings(qapp, tmp_path, monkeypatch):
    """PySide6 keeps the interpreter's lock through ``QSettings.sync()``: a sync of the
    settings file that waited for a busy disk froze every Python thread (run H4's 4.4 s
    operator-day freeze). The writer syncs ``QSettings`` only on a staging copy in
    memory, and puts the file in place with Python's I/O (``os.fsync`` releases the
    lock); the file holds the values, a second flush keeps the first one's, and what
    another QSettings of the file set before survives."""
    import configparser
    import threading

    import gui.fields as fields

    path = tmp_path / "gui.ini"
    monkeypatch.setenv("DIFFUSERLAB_GUI_SETTINGS", str(path))
    other = fields.QSettings(str(path), fields.QSettings.Format.IniFormat)
    other.setValue("window/kept", "yes")  # e.g. the window's geometry, saved before
    other.sync()
    del other
    synced, fsynced, ran = [], [], []
    real_sync, real_fsync = fields.QSettings.sync, os.fsync

    def sync(self):
        synced.append(self.fileName())
        real_sync(self)

    def fsync(fd):
        ticked = []
        ticker = threading.Thread(target=lambda: ticked.append(True))  # another thread runs
        ticker.start()
        real_fsync(fd)
        ticker.join(60)
        name = os.readlink(f"/proc/self/fd/{fd}")
        if name.startswith(str(tmp_path)):  # the settings file's, not another test's
            fsynced.append(name)
            ran.extend(ticked)

    monkeypatch.setattr(fields.QSettings, "sync", sync)
    monkeypatch.setattr(os, "fsync", fsync)
    fields.store("fields/test/a", "1")
    fields.flush()
    fields.store("fields/test/b", "2")
    fields.flush()
    assert synced and all(not name.startswith(str(tmp_path)) for name in synced), synced
    assert len(fsynced) == 2 and all(p.startswith(str(tmp_path)) for p in fsynced), fsynced
    assert ran == [True, True]
    ini = configparser.ConfigParser()
    ini.read(path)
    assert (ini["fields"]["test\\a"], ini["fields"]["test\\b"]) == ("1", "2")
    assert ini["window"]["kept"] == "yes"
    assert fields.read("fields/test/a") == "1"
    assert not list(tmp_path.glob(".gui.ini.*")), list(tmp_path.iterdir())  # no leftovers


def test_fields_are_remembered_across_sessions(qapp, tmp_path, monkeypatch):
    monkeypatch.setenv("DIFFUSERLAB_GUI_SETTINGS", str(tmp_path / "gui.ini"))
    from gui.app import MainWindow
    from gui.session import Session

    first = MainWindow(Session(None, simulate=True, scene="none"))
    first.live.psf.setText("/data/sweep.zarr")
    first.live.depth.setEditText("45")
    first.live.method.setCurrentText("admm")
    first.live.iterations.setValue(7)
    first.record.frames.setText("200")
    first.record.exposure.setText("15 ms")
    first.record.batch_fields["--iterations"].setValue(150)
    first.record.batch_fields["--method"].setCurrentText("fista")
    first.calibration.fields["psf-sweep"]["--n-depths"].setText("9")
    first.alignment.frames.setValue(2)
    first.shutdown()
    first.deleteLater()
    second = MainWindow(Session(None, simulate=True, scene="none"))
    try:
        assert second.live.psf.text() == "/data/sweep.zarr"
        assert second.live.depth.currentText() == "45"
        assert second.live.method.currentText() == "admm" and second.live.iterations.value() == 7
        assert second.record.frames.text() == "200" and second.record.exposure.text() == "15 ms"
        assert second.record.batch_fields["--iterations"].value() == 150
        assert second.record.batch_fields["--method"].currentText() == "fista"
        assert second.calibration.fields["psf-sweep"]["--n-depths"].text() == "9"
        assert second.alignment.frames.value() == 2
    finally:
        second.shutdown()
        second.deleteLater()


def test_live_psf_and_depth_are_carried_to_batch_unless_typed_there(window):
    rec = window.record
    rec.batch_fields["--psf"].setText("")
    rec.batch_fields["--depth"].setEditText("")
    rec._carried = ("", "")
    window.live.psf_chosen.emit("/runs/sweep.zarr", "45")
    assert rec.batch_fields["--psf"].text() == "/runs/sweep.zarr"
    assert rec.batch_fields["--depth"].currentText() == "45"
    window.live.psf_chosen.emit("/runs/other.zarr", "60")  # carried again: follows
    assert rec.batch_fields["--psf"].text() == "/runs/other.zarr"
    rec.batch_fields["--psf"].setText("/mine.npy")  # typed by the operator: kept
    window.live.psf_chosen.emit("/runs/third.zarr", "70")
    assert rec.batch_fields["--psf"].text() == "/mine.npy"


def test_depth_offers_the_stacks_depths(window, wait, tmp_path):
    from instrument.runs.stacks import import_psf_stack

    stack = np.random.default_rng(0).random((3, 16, 20)).astype(np.float32)
    np.save(tmp_path / "stack.npy", stack)
    import_psf_stack(tmp_path / "stack.npy", tmp_path / "stack.zarr", depths_mm=[30, 45, 60])
    live = window.live
    live.psf.setText(str(tmp_path / "stack.zarr"))
    live.depth.setEditText("")
    job = live.offer_depths()
    wait(lambda: job.done, 10, "the depths")
    assert [live.depth.itemText(i) for i in range(live.depth.count())] == ["30", "45", "60"]
    assert live.depth.currentText() == "30"


# -- device state, Reconnect, presets, stored positions ---------------------------------------


def test_a_disconnected_device_shows_red_everywhere_and_reconnects(window, wait):
    from drivers.errors import DeviceDisconnectedError

    panel = window.devices
    service = window.session.service
    wait(lambda: "5 open" in panel.state.text(), 10, "the first status")
    service.run_job("device_fault", {"device": "led_array", "action": "disconnect"})
    with pytest.raises(DeviceDisconnectedError):
        service.show("led_array", "off")
    wait(lambda: "disconnected" in panel.state.text(), 10, "the poll to see it")
    box = panel.boxes["led_array"]
    assert "DISCONNECTED" in box.state.text() and "#c00020" in box.state.text()
    assert "DISCONNECTED" in window.device_labels["led_array"].text()
    assert "4 open" in panel.state.text() and "led_array" in panel.state.text()
    service.run_job("device_fault", {"device": "led_array", "action": "allow_reconnect"})
    job = box.reconnect()
    wait(lambda: job.done, 10, "the reconnect")
    assert box.error.text() == ""
    wait(lambda: "5 open" in panel.state.text(), 10, "the poll after the reconnect")
    assert "open" in window.device_labels["led_array"].text()


def test_status_is_named_fields_not_a_dict(window, wait):
    box = window.devices.boxes["source_stage"]
    wait(lambda: "position" in box.status_labels, 10, "a poll")
    text = box.status_labels["position"].text()
    assert "x " in text and "mm" in text and "{" not in text
    cam = window.devices.boxes["camera"]
    assert cam.status_labels["exposure"].text().endswith("ms")


def test_presets_save_and_apply_device_settings(window, wait):
    box = window.devices.boxes["camera"]
    service = window.session.service
    service.apply_settings("camera", {"exposure_s": 0.005, "gain": 2.0})
    box.save_preset("bright sample")
    service.apply_settings("camera", {"exposure_s": 0.05, "gain": 0.0})
    assert box.preset.currentText() == "bright sample"
    job = box.apply_preset("bright sample")
    wait(lambda: job.done, 10, "the preset")
    held = service.settings("camera")
    assert held["exposure_s"] == pytest.approx(0.005) and held["gain"] == pytest.approx(2.0)
    assert box.fields["exposure_s"].text() == "5 ms"
    box.delete_preset("bright sample")
    assert box.preset.count() == 0
    service.apply_settings("camera", {"exposure_s": 0.01, "gain": 0.0})


def test_stored_positions_recall_with_one_click_and_persist(window, wait):
    box = window.devices.boxes["source_stage"]
    service = window.session.service
    service.move("source_stage", {"x": 2.0, "y": -1.0, "z": 35.0})
    job = box.stage.store_position("focus bead")
    wait(lambda: job.done and "focus bead" in box.stage.stored_buttons, 10, "the store")
    service.move("source_stage", {"x": 0.0, "y": 0.0, "z": 60.0})
    QTest.mouseClick(box.stage.stored_buttons["focus bead"], Qt.MouseButton.LeftButton)
    wait(lambda: not box.queue.busy, 10, "the recall")
    assert service.positions("source_stage") == pytest.approx({"x": 2.0, "y": -1.0, "z": 35.0})
    from gui.fields import load_json

    assert "focus bead" in load_json(box.stage.key, {})
    box.stage.forget("focus bead")
    assert "focus bead" not in box.stage.stored_buttons


# -- keyboard -----------------------------------------------------------------------------------


def test_shortcuts_start_live_snap_and_stop_motion(window, wait):
    window.activateWindow()
    window.setFocus()
    QTest.keyClick(window, Qt.Key.Key_F5)
    wait(lambda: window.session.streaming, 10, "F5 to start the stream")
    QTest.keyClick(window, Qt.Key.Key_F5)
    wait(lambda: not window.session.streaming, 10, "F5 to stop it")
    before = window.session.frames_seen
    QTest.keyClick(window, Qt.Key.Key_F6)
    wait(lambda: window.session.frames_seen > before, 10, "F6 to snap a frame")
    service = window.session.service
    service.apply_settings("source_stage", {"velocity": dict.fromkeys("xyz", 1.0)})
    try:
        service.run_job("start_move", {"stage": "source_stage", "targets": {"z": 80.0}})
        QTest.keyClick(window, Qt.Key.Key_Escape)
        wait(lambda: not service.run_job("is_moving", {"stage": "source_stage"}), 5,
             "Esc to stop the stage")
        assert service.positions("source_stage")["z"] < 79.0
    finally:
        service.apply_settings("source_stage", {"velocity": dict.fromkeys("xyz", 50.0)})


def test_arrow_keys_jog_the_chosen_stage_unless_a_field_has_the_focus(window, wait):
    panel = window.devices
    panel.arrow_stage.setCurrentText("source_stage")
    box = panel.boxes["source_stage"]
    service = window.session.service
    service.move("source_stage", {"x": 0.0, "y": 0.0})
    box.stage.jog_steps["x"].setValue(0.5)
    box.stage.jog_steps["y"].setValue(0.25)
    window.activateWindow()
    window.live.raw_view.glw.setFocus()
    QTest.keyClick(window.live.raw_view.glw, Qt.Key.Key_Right)
    QTest.keyClick(window.live.raw_view.glw, Qt.Key.Key_Up)
    wait(lambda: not box.queue.busy, 10, "the jogs")
    positions = service.positions("source_stage")
    assert positions["x"] == pytest.approx(0.5) and positions["y"] == pytest.approx(0.25)
    field = window.live.psf
    field.setFocus()
    QTest.keyClick(field, Qt.Key.Key_Right)  # moves the text cursor, not the stage
    QTest.qWait(300)
    assert service.positions("source_stage")["x"] == pytest.approx(0.5)


# -- log pane and layout ------------------------------------------------------------------------


def test_log_pane_shows_warnings_once_per_job_and_prompts(window):
    pane = window.log_pane
    n = len(pane.lines)
    noisy = logging.getLogger("recon.auto.weight")
    for k in range(50):
        noisy.warning("automatic TV weight %.3g: too coarse for a reliable choice", 1e-3 * k)
    assert len(pane.lines) == n + 1 and "too coarse" in pane.lines[-1]
    from gui.logpane import announce_job

    announce_job("batch reconstruction")
    noisy.warning("automatic TV weight %.3g: too coarse for a reliable choice", 0.5)
    assert sum("too coarse" in ln for ln in pane.lines[n:]) == 2
    answers = []
    window.ask("cap", "Put the cap on the camera", answers.append)
    assert any("Put the cap on the camera" in ln for ln in pane.lines)
    from PySide6.QtWidgets import QMessageBox

    dialog = [w for w in window.findChildren(QMessageBox) if w.isVisible()][-1]
    dialog.button(QMessageBox.StandardButton.Ok).click()
    assert answers == [True] and "operator answered Done" in pane.lines[-1]

    def gone(ok):  # the bench process ended while the box was open (its socket removed)
        raise FileNotFoundError(2, "No such file or directory")

    window.ask("cap", "Put the cap on again", gone)  # answered: no traceback, a log line
    dialog = [w for w in window.findChildren(QMessageBox) if w.isVisible()][-1]
    dialog.button(QMessageBox.StandardButton.Abort).click()
    assert "was not delivered: the bench process is gone" in pane.lines[-1]
    window.devices.error.setText("a refusal the operator saw")
    assert "a refusal the operator saw" in pane.lines[-1]


def test_log_pane_keeps_the_last_lines_only(qapp):
    """A day-long session's log pane does not grow: the lines kept are the last
    MAX_LINES (with some slack between trims), as the text view's."""
    from gui.logpane import MAX_LINES, LogPane, gui_log

    pane = LogPane()
    pane.install()
    try:
        for k in range(MAX_LINES + MAX_LINES // 10 + 5):
            gui_log.info(f"operator line {k}")  # distinct lines (a repeat shows once)
    finally:
        pane.uninstall()
    assert MAX_LINES <= len(pane.lines) <= MAX_LINES + MAX_LINES // 10
    assert pane.lines[-1].endswith(f"operator line {MAX_LINES + MAX_LINES // 10 + 4}")
    assert pane.text.document().blockCount() <= MAX_LINES
    pane.deleteLater()


def test_the_live_view_is_beside_the_task_panels_by_default(window):
    docks = window.docks
    live = docks["Live view"]
    assert window.tabifiedDockWidgets(live) == []
    for title in ("Calibration", "Alignment", "Record", "Results"):
        assert live not in window.tabifiedDockWidgets(docks[title]), title
    assert window.dockWidgetArea(live) == window.dockWidgetArea(docks["Calibration"])


def test_snapshot_metadata_of_a_live_reconstruction_names_its_parameters(window):
    live = window.live
    live._live_settings = {"psf": "/runs/sweep.zarr", "depth_requested_mm": 44.0,
                           "depth_used_mm": 45.0, "dark": ""}
    meta = live.recon_view.snapshot_metadata()
    assert meta["reconstruction"]["psf"] == "/runs/sweep.zarr"
    assert meta["reconstruction"]["depth_used_mm"] == 45.0
    assert "method" in meta["reconstruction"] and "device_settings" in meta
    json.dumps(meta)


def test_led_clicks_do_not_pile_up_references(window, wait):
    """Each LED click recoloured the map with fresh brushes: ~6000 references to None
    kept per click by pyqtgraph (the operator's day grew by 23000 a loop)."""
    import gc
    import sys

    box = window.devices.boxes["led_array"]
    for i in range(3):
        job = box.light_led(i)
        wait(lambda j=job: j.done, 10, "the LED")
    QTest.qWait(200)
    gc.collect()
    before = sys.getrefcount(None)
    for i in range(10):
        job = box.light_led(i % 4)
        wait(lambda j=job: j.done, 10, "the LED")
        QTest.qWait(50)
    gc.collect()
    assert (sys.getrefcount(None) - before) / 10 < 200


def test_snapshot_saves_the_frame_on_screen_at_the_click(view, wait, tmp_path, monkeypatch):
    """The live view keeps streaming while the Save dialog is open: the file holds the
    image shown at the click, not the one shown when the dialog closes; the dialog
    opens in out/snapshots, made if it did not exist."""
    import tifffile
    from PySide6.QtWidgets import QFileDialog

    monkeypatch.setenv("DIFFUSERLAB_GUI_SETTINGS", str(tmp_path / "gui.ini"))
    monkeypatch.chdir(tmp_path)
    v, image = view
    offered = []

    def dialog(parent, title, start, filters):
        offered.append(start)
        for k in range(2, 6):  # frames arrive while the operator types a name
            v.setImage(image * k)
        return str(tmp_path / "clicked.tif"), filters

    monkeypatch.setattr(QFileDialog, "getSaveFileName", staticmethod(dialog))
    job = v.choose_snapshot()
    wait(lambda: job.done, 10, "the snapshot")
    assert np.array_equal(tifffile.imread(tmp_path / "clicked.tif"), image)
    folder = tmp_path / "out" / "snapshots"
    assert folder.is_dir() and offered[0].startswith(str(Path("out") / "snapshots"))


def test_two_processes_writing_one_settings_file_keep_every_value(tmp_path):
    """Two windows' settings writers on one file at once (two real processes): each
    write reads the file, sets its keys and puts it in place under the writer's lock
    file, so neither loses the other's values."""
    import configparser
    import subprocess
    import sys

    path = tmp_path / "gui.ini"
    script = ("import os, sys\n"
              "import gui.fields as fields\n"
              "n = sys.argv[1]\n"
              "for i in range(40):\n"
              "    fields.store(f'fields/p{n}/k{i}', str(i))\n"
              "    fields.flush()\n")
    env = {**os.environ, "DIFFUSERLAB_GUI_SETTINGS": str(path), "QT_QPA_PLATFORM": "offscreen"}
    procs = [subprocess.Popen([sys.executable, "-c", script, str(n)], env=env)
             for n in (1, 2)]
    assert [p.wait(600) for p in procs] == [0, 0]
    ini = configparser.ConfigParser()
    ini.read(path)
    missing = [f"p{n}\\k{i}" for n in (1, 2) for i in range(40)
               if ini["fields"].get(f"p{n}\\k{i}") != str(i)]
    assert not missing, missing

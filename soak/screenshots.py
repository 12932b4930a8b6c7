"""Screenshots of every panel, driven on the virtual bench (docs/images/ holds them).

``python -m soak.screenshots OUT_DIR [--alignment-record DIR]`` (under an X display,
e.g. ``xvfb-run -a``; the screenshot test runs it so) opens the window on the
built-in simulated bench, drives each panel into a state worth showing and saves
``gui-<panel>.png`` of each dock:

* devices: the LED behind the pinhole lit, a refused exposure showing the camera
  interface's message;
* calibration: a short PSF sweep, complete, its last frame shown;
* live: the stream with the live reconstruction (the sweep's PSF, warm ADMM);
* tools: the image tools on the live view (ROI statistics, line profile, pixel readout,
  a colormap);
* disconnected: the window with the LED array unplugged (red in its box, the status
  area and the device count; Reconnect);
* record: a short video recorded;
* results: the sweep's PSF stack with its depth slider and projections;
* alignment: a finished record (``--alignment-record``, e.g. from ``diffuserlab
  align mask --simulate``, about 6 minutes), else the panel before a start;
* log: the log pane with the session's history;
* details for the operator's guide: presets (the camera's box with saved presets),
  positions (the source stage's box with stored positions), shortcuts (the Acquire
  menu open, with its keys).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

from gui.workers import wait_until

__all__ = ["take_screenshots"]

log = logging.getLogger(__name__)


def _settle(app, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        app.processEvents()
        time.sleep(0.01)


def take_screenshots(out_dir: str | Path, *, alignment_record: str | None = None,
                     width: int = 1400, height: int = 860) -> list[Path]:
    """Drive the panels and save one PNG per dock (see the module docstring).

    Returns
    -------
    list of Path
        The PNG files written.
    """
    import os
    import tempfile

    os.environ.setdefault("DIFFUSERLAB_GUI_SETTINGS",
                          str(Path(tempfile.mkdtemp(prefix="gui-shots-")) / "gui.ini"))
    from PySide6.QtWidgets import QApplication

    from gui.app import MainWindow, configure
    from gui.session import BENCH_JOBS, Session

    from .device_jobs import JOBS

    BENCH_JOBS.update(JOBS)  # a simulated device's faults

    app = QApplication.instance() or QApplication(sys.argv[:1])
    configure()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="gui-shots-runs-"))
    w = MainWindow(Session(None, simulate=True, scene="none"))
    w.resize(width, height)
    w.show()
    _settle(app, 0.5)
    layout = w.saveState()  # the default layout, put back after a panel was floated
    written: list[Path] = []

    t0 = time.monotonic()

    def detail(name: str, widget) -> None:
        """One widget as it is shown (a box of a panel, a menu)."""
        _settle(app, 0.6)
        path = out / f"gui-{name}.png"
        if not widget.grab().save(str(path)):
            raise RuntimeError(f"could not write {path}")
        written.append(path)

    def shot(name: str, dock: str) -> None:
        log.info("screenshot %s at %.1f s", name, time.monotonic() - t0)
        d = w.docks[dock]
        w.restoreState(layout)  # a dock floated and docked back lands out of place
        d.raise_()
        whole = name in ("window", "disconnected")
        if not whole:  # one panel, floated at a readable size, then docked back
            d.setFloating(True)
            d.resize(1300, 760)
        _settle(app, 0.8)
        path = out / f"gui-{name}.png"
        if whole:  # as the X server shows it: grab() draws docks once floated (native
            # windows) at wrong offsets, over each other
            w.raise_()
            _settle(app, 0.3)
            image = app.primaryScreen().grabWindow(w.winId())
        else:
            image = d.grab()
        ok = image.save(str(path))
        if not whole:
            d.setFloating(False)
            w.restoreState(layout)
            _settle(app, 0.3)
        if not ok:
            raise RuntimeError(f"could not write {path}")
        written.append(path)

    try:
        s = w.session
        s.connect_bench()
        wait_until(app, lambda: s.connected, 120, "the bench to open")
        bench = s.service
        for stage in ("source_stage", "mask_stage"):
            bench.apply_settings(stage, {"velocity": dict.fromkeys(s.devices[stage].axes, 50.0)})
        # calibration: a short PSF sweep
        cal = w.calibration
        cal.routine.setCurrentText("psf-sweep")
        for flag, value in (("--z-min", "30"), ("--z-max", "80"), ("--n-depths", "5"),
                            ("--frames", "1")):
            cal.fields["psf-sweep"][flag].setText(value)
        sweep = str(work / "psf-sweep.zarr")
        cal.out.setText(sweep)
        w.docks["Calibration"].raise_()
        job = cal.start()
        wait_until(app, lambda: job.done, 180, "the PSF sweep")
        # devices: the LED behind the pinhole lit, a refused setting
        box = w.devices.boxes["led_array"]
        import numpy as np

        centre = int(np.argmin(np.hypot(*s.devices["led_array"].led_positions_mm.T)))
        job = box.light_led(centre)
        wait_until(app, lambda: job.done, 10, "the LED")
        from instrument.runs.runstore import RunStore

        depths = RunStore.open(sweep).product("psf_stack")[1]["depths_mm"]
        depth = depths[len(depths) // 2]
        bench.move("source_stage", {"x": 0.0, "y": 0.0, "z": depth})
        # live view: the stream and the live reconstruction with the sweep's PSF
        live = w.live
        live.psf.setText(sweep)
        live.depth.setEditText(f"{depth:g}")
        live.method.setCurrentText("admm")
        live.iterations.setValue(5)
        w.docks["Live view"].raise_()
        job = live.start_reconstruction()
        wait_until(app, lambda: job.done, 120, "the live reconstruction to start")
        if live.live is None:
            raise RuntimeError(f"live reconstruction: {live.error.text()}")
        wait_until(app, lambda: live._shown_recon >= 0, 180, "a live reconstruction")
        _settle(app, 3.0)
        # the whole window first: a dock floated for its own shot and docked back
        # leaves the window's layout overlapping under the window manager
        shot("window", "Live view")
        # a device unplugged: red in its box, the status area and the device count
        bench.run_job("device_fault", {"device": "led_array", "action": "disconnect"})
        job = box.light_led(centre)
        wait_until(app, lambda: job.done, 10, "the refused LED")
        wait_until(app, lambda: "disconnected" in w.devices.state.text(), 10, "the poll")
        w.devices.area.ensureWidgetVisible(box, 0, 0)
        _settle(app, 1.5)
        shot("disconnected", "Devices")
        bench.run_job("device_fault", {"device": "led_array", "action": "allow_reconnect"})
        job = box.reconnect()
        wait_until(app, lambda: job.done, 10, "the reconnect")
        # devices: a refused setting shows the interface's message
        cam_box = w.devices.boxes["camera"]
        w.devices.area.ensureWidgetVisible(cam_box, 0, 0)
        cam_box.fields["exposure_s"].setText("120")
        job = cam_box.apply("exposure_s")
        wait_until(app, lambda: job.done, 10, "the refusal")
        shot("devices", "Devices")
        cam_box.fields["exposure_s"].setText(f"{bench.settings('camera')['exposure_s']:g}")
        job = cam_box.apply("exposure_s")
        wait_until(app, lambda: job.done, 10, "the setting")
        # presets: the camera's settings saved under names, one applied
        exposure = bench.settings("camera")["exposure_s"]
        for name, value in (("dim scene, 40 ms", 0.04), ("bright PSF, 2 ms", 0.002)):
            job = cam_box.run(bench.apply_settings, "camera", {"exposure_s": value})
            wait_until(app, lambda j=job: j.done, 10, "the exposure")
            cam_box.save_preset(name)
        job = cam_box.apply_preset("dim scene, 40 ms")
        wait_until(app, lambda: job.done, 10, "the preset")
        cam_box.refresh_settings()
        cam_box.preset.setCurrentText("dim scene, 40 ms")
        w.devices.area.ensureWidgetVisible(cam_box, 0, 0)
        detail("presets", cam_box)
        job = cam_box.run(bench.apply_settings, "camera", {"exposure_s": exposure})
        wait_until(app, lambda j=job: j.done, 10, "the exposure")
        cam_box.refresh_settings()
        # stored positions: the stage at the pinhole and at the sweep's far end
        stage_box = w.devices.boxes["source_stage"]
        for name, where in (("pinhole on axis", {"x": 0.0, "y": 0.0, "z": depth}),
                            ("far end", {"x": 0.0, "y": 0.0, "z": 80.0})):
            bench.move("source_stage", where)
            job = stage_box.stage.store_position(name)
            wait_until(app, lambda j=job: j.done, 10, "the stored position")
        bench.move("source_stage", {"x": 0.0, "y": 0.0, "z": depth})
        w.devices.area.ensureWidgetVisible(stage_box, 0, 0)
        detail("positions", stage_box)
        # shortcuts: the Acquire menu open
        w.raise_()
        w.activateWindow()
        bar = w.menuBar()
        w.acquire_menu.popup(bar.mapToGlobal(bar.actionGeometry(
            w.acquire_menu.menuAction()).bottomLeft()))
        _settle(app, 0.8)
        corner = w.mapToGlobal(w.rect().topLeft())
        image = app.primaryScreen().grabWindow(0, corner.x(), corner.y(), 640, 260)
        w.acquire_menu.hide()
        path = out / "gui-shortcuts.png"
        if not image.save(str(path)):
            raise RuntimeError(f"could not write {path}")
        written.append(path)
        shot("calibration", "Calibration")
        shot("live", "Live view")
        # the image tools: ROI statistics, line profile, colormap, pixel readout
        raw = live.raw_view
        raw.show_roi(True)
        raw.show_profile(True)
        live.recon_view.set_colormap("viridis")
        live.recon_view.show_roi(True)
        _settle(app, 0.5)
        from PySide6.QtCore import QPoint
        from PySide6.QtTest import QTest

        port = raw.glw.viewport()
        QTest.mouseMove(port, QPoint(port.width() // 3, port.height() // 3))
        QTest.mouseMove(port, QPoint(port.width() // 3 + 5, port.height() // 3 + 3))
        _settle(app, 1.0)
        shot("tools", "Live view")
        raw.show_roi(False)
        raw.show_profile(False)
        live.recon_view.show_roi(False)
        # record: a short video (the live view keeps running beside it)
        rec = w.record
        rec.out.setText(str(work / "video.zarr"))
        rec.frames.setText("20")
        rec.batch_fields["--psf"].setText(sweep)
        rec.batch_fields["--depth"].setEditText(live.depth.currentText())
        w.docks["Record"].raise_()
        job = rec.start_recording()
        wait_until(app, lambda: job.done, 120, "the recording")
        live.stop_reconstruction()
        s.stop_stream()
        rec.batch_fields["--method"].setCurrentText("admm")
        rec.batch_fields["--iterations"].setValue(10)
        rec.batch_fields["--frames"].setText("0:4")
        rec.batch_fields["--workers"].setText("1")
        job = rec.start_batch()
        wait_until(app, lambda: job.done, 300, "the batch reconstruction")
        shot("record", "Record")
        # results: the PSF stack with its projections
        job = w.results.open(sweep, "psf_stack")
        wait_until(app, lambda: job.done and w.results.volume is not None, 60, "the results")
        w.results.depth_slider.setValue(1)
        shot("results", "Results")
        # alignment
        al = w.alignment
        w.docks["Alignment"].raise_()
        if alignment_record:
            al.open_record(alignment_record)
        shot("alignment", "Alignment")
        shot("log", "Log")
    finally:
        w.shutdown()
    return written


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m soak.screenshots",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("out_dir", help="folder for the PNG files (e.g. docs/images)")
    p.add_argument("--alignment-record", default=None,
                   help="a finished alignment record to show in the alignment panel")
    args = p.parse_args(argv)
    from PySide6.QtWidgets import QApplication

    paths = take_screenshots(args.out_dir, alignment_record=args.alignment_record)
    print(f"platform {QApplication.instance().platformName()}")
    for path in paths:
        print(path)
    return 0


if __name__ == "__main__":
    from gui.cli import exit_now

    exit_now(main())

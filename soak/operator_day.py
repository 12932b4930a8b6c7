"""An operator's day, driven through the real ``diffuserlab gui`` in a real X window.

``python -m soak.operator_day --report OUT.json [--bench FILE | --simulate]
[--minutes M]`` runs the ``diffuserlab gui`` command itself (:func:`instrument.cli.main`, the window
and event loop as an operator gets them) with an :class:`Operator` on its event loop.
The operator clicks, types and presses keys through the X server (:mod:`soak.xinput`,
xdotool), finds what to click by the widgets' names, and waits for what the window
shows, never blocking the event loop (:class:`soak.driver.WindowDriver`). The day:

connect; stream (F5); stage jogs, go-to with Enter, a stored position recalled; LEDs;
dark and PSF sweep (paused, continued, aborted, resumed); live Wiener then ADMM with
the sweep's PSF; a short alignment (simulated bench); a 200-frame recording with the
live reconstruction running; a batch reconstruction; Results with slider steps; the
image tools and a snapshot; an LED array unplugged and reconnected; Esc during a
move and Snap (F6); then, when the day's minutes are not used up, the day's middle
again; at the end Ctrl+Q during a recording, answered Yes.

:class:`soak.daymonitor.DayMonitor` measures the GUI thread's lateness per phase, the
reference counts of None and True and the memory; the report (JSON) is written before
the window closes. ``soak.soak`` starts Xvfb, a window manager and the emulators, runs
this, and checks how the process ended.
"""

from __future__ import annotations

import argparse
import gc
import logging
import os
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from PySide6.QtCore import QPoint, QPointF, QTimer
from PySide6.QtWidgets import QApplication, QFileDialog, QMessageBox

from instrument.atomic import write_json

from .daymonitor import DayMonitor, HeapTracker, census
from .driver import StepFailed, WindowDriver, shown_at

__all__ = ["Operator", "StepFailed", "main", "start_when_shown"]

log = logging.getLogger(__name__)

#: Environment variable naming the socket file descriptor to the emulators' process.
CONTROL_ENV = "DIFFUSERLAB_DAY_CONTROL"
#: Looks (0.5 s apart, on the window's event loop) at a prompt box still shown after its
#: Done click was carried out before it is clicked again.
RECLICK_LOOKS = 20


class Operator(WindowDriver):
    """The day's steps as a generator stepped by the event loop (module docstring).

    Parameters
    ----------
    window : gui.app.MainWindow
    options : argparse.Namespace
        ``work`` (folder for runs), ``minutes``, ``report``, ``simulate``,
        ``alignment_s`` (abort the alignment after this; 0: let it finish).
    """

    def __init__(self, window, options) -> None:
        super().__init__(window)
        self.o = options
        self.monitor = DayMonitor()
        self.work = Path(options.work)
        self.work.mkdir(parents=True, exist_ok=True)
        self.completed: list[str] = []
        self.records: list[dict] = []
        self.notes: dict[str, Any] = {}
        self.loops = 0
        self.heap = HeapTracker()
        self.t0 = time.monotonic()
        #: Each prompt box seen: where its button was at the last look, and the looks
        #: since it was clicked (None before), :meth:`_answer_prompts`.
        self._prompted: dict = {}
        self._control = _Control.from_env()

    def start(self) -> None:
        self.monitor.start()
        self._gen = self.day()
        QTimer.singleShot(0, self._step)
        self._prompts = QTimer()
        self._prompts.timeout.connect(self._answer_prompts)
        self._prompts.start(500)

    def _answer_prompts(self) -> None:
        """A run's operator prompt on a real bench (cap the camera, ...): done, as the
        operator would, by clicking Done, once the box shows its button at the same spot
        at two looks 0.5 s apart (as :meth:`aim` does; a box is visible to Qt before the
        window manager has placed it: a click sent at once was lost on 2026-11-28, most
        likely so, and the day's second dark run waited 600 s for its answer). A box
        still shown :data:`RECLICK_LOOKS` looks after its click was carried out (looks on
        this event loop, which has read the click by then) is clicked again, counted in
        ``notes["prompt_reclicks"]``."""
        seen, self._prompted = self._prompted, {}  # the boxes shown now only
        for box in self.w.findChildren(QMessageBox):
            if not box.isVisible() or box.windowTitle() != "operator action":
                continue
            before, looks = seen.get(box, (None, None))
            if looks is None and before is None:
                self.notes.setdefault("prompts", []).append(box.text())
            point, shown = shown_at(box.button(QMessageBox.StandardButton.Ok), before)
            if looks is not None:  # clicked: once X has carried it out, count the looks
                looks += 1 if self.x.idle() else 0
                if looks < RECLICK_LOOKS or not shown:
                    self._prompted[box] = (point, looks)
                    continue
                self.notes["prompt_reclicks"] = self.notes.get("prompt_reclicks", 0) + 1
            if shown:
                self.x.click_at(point)
                self._prompted[box] = (point, 0)
            else:
                self._prompted[box] = (point, looks)

    def phase(self, name: str) -> None:
        if name == "stream" and os.environ.get("DIFFUSERLAB_DAY_CENSUS"):
            self.notes.setdefault("census", []).append(census())
        self.monitor.set_phase(name)
        log.info("operator day: %s (%.0f s)", name, time.monotonic() - self.t0)

    def done(self, name: str) -> None:
        self.completed.append(name)

    def remaining_s(self) -> float:
        return self.o.minutes * 60.0 - (time.monotonic() - self.t0)

    def check_no_bug(self, where: str) -> None:
        bugs = [ln for ln in self.w.log_pane.lines if "this is a bug" in ln]
        if bugs:
            raise StepFailed(f"{where}: the window showed a bug: {bugs[-1]}")

    # -- the day ----------------------------------------------------------------------------
    def day(self) -> Iterator:
        w = self.w
        self.phase("connect")
        yield self.until(lambda: w.session.connected, 300, "the bench to open")
        if self.o.simulate:
            for name in ("source_stage", "mask_stage"):
                axes = w.session.devices[name].axes
                w.session.service.apply_settings(name, {"velocity": dict.fromkeys(axes, 20.0)})
        self.done("connect")
        yield from self.stream_and_stage()
        yield from self.calibrate(pause_and_resume=True)
        yield from self.live_view()
        yield from self.alignment()
        yield from self.record_and_batch()
        yield from self.results()
        yield from self.image_tools()
        yield from self.unplug_and_reconnect()
        yield from self.shortcuts()
        loop_s = 0.8 * (time.monotonic() - self.t0)  # the day's middle, again
        while self.remaining_s() > loop_s:
            t = time.monotonic()
            self.loops += 1
            self.monitor.loop = self.loops
            self.heap.mark()
            yield from self.stream_and_stage()
            yield from self.calibrate(pause_and_resume=False)
            yield from self.live_view()
            yield from self.record_and_batch()
            yield from self.results()
            yield from self.image_tools()
            yield from self.unplug_and_reconnect()
            yield from self.shortcuts()
            loop_s = 1.1 * (time.monotonic() - t)
        yield from self.quit_mid_recording()

    def stream_and_stage(self) -> Iterator:
        w = self.w
        self.phase("stream")
        self.dock("Calibration")
        if not w.session.streaming:
            self.x.click(w.live.raw_view.glw)  # focus in the window, no field
            self.x.key("F5")
            yield self.typed()
        yield self.until(lambda: w.session.streaming, 20, "F5 to start the stream")
        yield self.until(lambda: w.live._shown_raw > 10, 60, "frames in the live view")
        yield 5.0
        self.done("stream")
        self.phase("stage")
        box = w.devices.boxes["source_stage"]
        stage = _Stage(w.session.service, "source_stage")
        if self.o.simulate and self.loops == 0:  # the pinhole in front of the diffuser
            yield from self.fill(box.stage.targets["z"], "60", enter=True)
            yield self.until(lambda: not box.queue.busy and abs(stage.position("z") - 60) < 1e-3,
                             60, "the go-to z 60")
        start = stage.positions()
        jog = self.button("source_stage.jog.x+")
        clicks: list[bool] = []

        def count(checked: bool = False) -> None:
            clicks.append(checked)

        jog.clicked.connect(count)
        yield from self.click(jog, times=3)  # quick clicks
        step = box.stage.jog_steps["x"].value()
        # xdotool has sent them; on a loaded machine the window may read the last one
        # only after the first two moved: wait for the three, then for the stage. Under
        # load 15 a click sometimes never reached the button (the stage moved twice):
        # the missing ones are clicked again, one at a time, and counted in the report
        t_wait = time.monotonic()
        yield self.until(lambda: len(clicks) >= 3 or time.monotonic() - t_wait > 15, 30,
                         "the window to get the three clicks")
        for _ in range(3 - len(clicks)):
            self.notes["jog_clicks_not_received"] = \
                self.notes.get("jog_clicks_not_received", 0) + 1
            n = len(clicks)
            yield from self.click(jog)
            yield self.until(lambda n=n: len(clicks) > n, 30, "a jog click to be received")
        jog.clicked.disconnect(count)
        yield self.until(lambda: not box.queue.busy, 60, "the three jogs")
        moved = stage.position("x") - start["x"]
        if abs(moved - 3 * step) > 1e-3:
            raise StepFailed(f"three jogs of {step} moved x by {moved}")
        yield from self.fill(box.stage.targets["z"], f"{start['z'] + 2.0:g}", enter=True)
        yield self.until(lambda: not box.queue.busy and abs(
            stage.position("z") - start["z"] - 2.0) < 1e-3, 60, "Enter in go-to z to move")
        name = f"day-{self.loops}"
        yield from self.fill(box.stage.position_name, name, enter=True)
        yield self.until(lambda: name in box.stage.stored_buttons, 20, "the stored position")
        yield from self.fill(box.stage.targets["x"], f"{start['x']:g}", enter=True)
        yield self.until(lambda: not box.queue.busy, 60, "the move back")
        yield from self.click(box.stage.stored_buttons[name])
        yield self.until(lambda: not box.queue.busy and abs(
            stage.position("x") - start["x"] - 3 * step) < 1e-3, 60, "the recall")
        box.stage.forget(name)
        yield from self.fill(box.stage.targets["x"], f"{start['x']:g}", enter=True)
        yield from self.fill(box.stage.targets["z"], f"{start['z']:g}", enter=True)
        yield self.until(lambda: not box.queue.busy, 60, "the stage back")
        self.done("stage")
        self.phase("leds")
        leds = w.devices.boxes["led_array"]
        yield from self.click(self.button("led_array.all-off"))
        yield self.until(lambda: not w.session.service.lit("led_array"), 20, "All off")
        if self.o.simulate:  # the LED behind the pinhole, clicked on the array's map
            import numpy as np

            yield from self.aim(leds.led_plot.viewport())  # scrolled into view
            pos = leds.device.led_positions_mm
            i = int(np.argmin(np.hypot(*pos.T)))
            vb = leds.led_plot.getViewBox()
            scene = vb.mapViewToScene(QPointF(float(pos[i, 0]), float(pos[i, 1])))
            local = leds.led_plot.mapFromScene(scene)
            self.x.click_at(leds.led_plot.viewport().mapToGlobal(local))
            yield self.typed()
            yield self.until(lambda: list(w.session.service.lit("led_array")) == [i], 20,
                             "the LED clicked")
        self.done("leds")
        self.check_no_bug("stage and LEDs")

    def calibrate(self, pause_and_resume: bool) -> Iterator:
        w = self.w
        cal = w.calibration
        self.dock("Calibration")
        self.phase("calibration")
        yield from self.choose(cal.routine, "dark")
        yield from self.fill(cal.fields["dark"]["--frames"], "2")
        dark = self.work / f"dark-{self.loops}.zarr"
        yield from self.fill(cal.out, str(dark))
        before = cal.job
        yield from self.click(cal.start_button)
        # the click carried out by xdotool is not yet the window's: under load Qt reads it
        # later, and a run that has not started is also "not running" (run R's day
        # failed here with an empty status: the run began a moment after)
        yield self.until(lambda: cal.job is not before, 60, "the dark run to start")
        yield self.until(lambda: cal.result is not None or not cal.running, 300, "the dark run")
        if not self.o.simulate and cal.result is not None and cal.result.status == "failed" \
                and "no light" in cal.status.text():
            # libaravis's fake camera sees no light (its frames are a pattern that the
            # LEDs do not change: flat == its dark): the run must refuse, saying so
            self.done("dark refused: the flat received no light")
        elif cal.result is None or cal.result.status != "complete":
            raise StepFailed(f"dark run: {cal.status.text()}")
        else:
            self.notes["dark"] = str(dark)
        yield self.until(lambda: w.session.streaming, 30, "the stream to resume after dark")
        yield from self.choose(cal.routine, "psf-sweep")
        fields = cal.fields["psf-sweep"]
        z = (30, 80, 3) if self.o.simulate else (20, 60, 3)
        for flag, value in (("--z-min", z[0]), ("--z-max", z[1]), ("--n-depths", z[2]),
                            ("--frames", 1)):
            yield from self.fill(fields[flag], str(value))
        sweep = self.work / f"sweep-{self.loops}.zarr"
        yield from self.fill(cal.out, str(sweep))
        yield from self.click(cal.start_button)
        yield self.until(lambda: "frame" in cal.events, 300, "the sweep's first frame")
        if pause_and_resume:
            yield from self.click(cal.pause_button)
            yield self.until(lambda: "paused" in cal.events, 120, "the pause")
            yield 2.0
            yield from self.click(cal.pause_button)  # Continue
            yield self.until(lambda: "resumed" in cal.events, 60, "Continue")
            yield from self.click(cal.abort_button)
            yield self.until(lambda: cal.result is not None, 120, "the abort")
            if cal.result.status == "complete":
                self.notes["abort"] = "the sweep ended before the abort"
            else:
                yield self.until(lambda: cal.resume_button.isEnabled(), 10, "Resume enabled")
                yield from self.click(cal.resume_button)
                yield self.until(lambda: cal.result is None, 20, "the resumed run")
        yield self.until(lambda: cal.result is not None, 600, "the sweep to finish")
        if cal.result.status != "complete":
            raise StepFailed(f"PSF sweep: {cal.status.text()}")
        self.notes["sweep"] = str(sweep)
        yield self.until(lambda: w.session.streaming, 30, "the stream to resume after the sweep")
        self.done("calibration" + (" with pause, abort, resume" if pause_and_resume else ""))
        self.check_no_bug("calibration")

    def live_view(self) -> Iterator:
        w = self.w
        live = w.live
        self.phase("live-wiener")
        if live.live is not None:  # still running from before: stopped, then the new PSF
            yield from self.click(live.recon_button)
            yield self.until(lambda: live.live is None, 30, "the reconstruction to stop")
        yield from self.fill(live.psf, self.notes["sweep"], enter=True)
        yield self.until(lambda: live.depth_job is not None and live.depth_job.done, 30,
                         "the stack's depths")
        yield from self.fill(live.depth.lineEdit(), live.depth.itemText(1))
        if not self.o.simulate:  # the dark run, or a level in DN when it was refused
            yield from self.fill(live.dark, self.notes.get("dark", "0"))
        if live.method.currentText() != "wiener":
            yield from self.choose(live.method, "wiener")
        yield from self.click(live.recon_button)
        yield self.until(lambda: live.live is not None or live.error.text(), 180,
                         "the live reconstruction")
        if live.live is None:
            raise StepFailed(f"live reconstruction: {live.error.text()}")
        first = live._shown_recon
        yield self.until(lambda: live._shown_recon > first, 180, "a Wiener reconstruction")
        yield 8.0
        self.done("live Wiener")
        self.phase("live-admm")
        yield from self.choose(live.method, "admm")
        yield self.until(lambda: live.live.stats()["method"] == "admm", 20, "ADMM")
        n = live.live.stats()["reconstructed"]
        yield self.until(lambda: live.live.stats()["reconstructed"] > n + 5, 300,
                         "ADMM reconstructions (numba compiles first)")
        yield 8.0
        self.done("live ADMM")
        self.check_no_bug("live view")

    def alignment(self) -> Iterator:
        w = self.w
        al = w.alignment
        self.dock("Alignment")
        self.phase("alignment")
        yield from self.fill(al.out, str(self.work / f"mask-{self.loops}.align"))
        if not self.o.simulate:  # a real bench needs the mask's seed: refused, clearly
            yield from self.click(al.start_button)
            yield self.until(lambda: "seed" in al.message.text(), 30, "the refusal")
            self.done("alignment refused without a mask seed")
            return
        yield from self.fill(al.frames.lineEdit(), "1")
        if al.focus.isChecked():
            yield from self.click(al.focus)
        yield from self.click(al.start_button)
        yield self.until(lambda: al.running, 20, "the alignment to start")
        if self.o.alignment_s > 0:  # a short alignment: aborted after a while
            yield self.o.alignment_s
            if al.running:
                yield from self.click(al.abort_button)
        yield self.until(lambda: not al.running, 900, "the alignment to end")
        if "bug" in al.message.text():
            raise StepFailed(f"alignment: {al.message.text()}")
        self.notes["alignment"] = al.message.text().splitlines()[0]
        yield self.until(lambda: w.session.streaming, 30, "the stream after the alignment")
        self.done("alignment")

    def record_and_batch(self) -> Iterator:
        w = self.w
        rec = w.record
        self.dock("Record")
        self.phase("recording")
        if w.live.live is None:
            raise StepFailed("the live reconstruction should run during the recording")
        video = self.work / f"video-{self.loops}.zarr"
        yield from self.fill(rec.out, str(video))
        yield from self.fill(rec.frames, "200")
        yield from self.fill(rec.seconds, "")
        before = rec.record_job  # the last loop's, done: the new one must be waited for
        yield from self.click(rec.record_button)
        yield self.until(lambda: rec.record_job is not before and rec.record_job.done, 300,
                         "the 200-frame recording")
        s = rec.summary
        if s is None or s.get("path") != str(video):
            raise StepFailed(f"recording: {rec.record_error.text() or rec.counters.text()}")
        self.records.append({k: s.get(k) for k in ("path", "status", "recorded",
                                                   "lost_by_recorder", "dropped_by_camera",
                                                   "skipped_by_ring", "fps")})
        self.done("recording 200 frames with live reconstruction")
        self.phase("batch")
        fields = rec.batch_fields
        if fields["--psf"].text() != self.notes["sweep"]:
            raise StepFailed(f"the live PSF was not carried to Batch: {fields['--psf'].text()}")
        yield from self.choose(fields["--method"], "wiener")
        yield from self.fill(fields["--frames"], "0:20")
        yield from self.fill(fields["--workers"], "1")
        if not self.o.simulate:
            yield from self.fill(fields["--dark"], self.notes.get("dark", "0"))
        before = rec.batch_job
        yield from self.click(rec.batch_button)
        yield self.until(lambda: rec.batch_job is not before and rec.batch_job.done, 600,
                         "the batch reconstruction")
        if rec.batch_result is None or rec.batch_result.get("reconstructed", 0) < 1:
            raise StepFailed(f"batch: {rec.batch_error.text()}")
        self.notes["video"] = str(video)
        self.done("batch")
        self.check_no_bug("recording and batch")

    def results(self) -> Iterator:
        w = self.w
        res = w.results
        self.dock("Results")
        self.phase("results")
        yield from self.fill(res.path, self.notes["video"], enter=True)
        yield self.until(lambda: res.store is not None and res.frame_shown == 0, 60,
                         "the recorded run")
        yield from self.click(res.frame_slider)
        for _ in range(25):
            self.x.key("Right")
        yield self.typed()
        target = res.frame_slider.value()
        yield self.until(lambda: res.frame_shown == target, 60, "the last slider step")
        yield self.until(lambda: res.problems is not None, 300, "the run's check")
        if res.problems:
            raise StepFailed(f"results: {res.problems[:2]}")
        self.done("results with slider steps")

    def image_tools(self) -> Iterator:
        w = self.w
        raw = w.live.raw_view
        self.phase("image-tools")
        for action in (raw.roi_action, raw.profile_action):
            if not action.isChecked():
                yield from self.click(self.tool(raw, action))
        yield self.until(lambda: raw.roi_statistics() is not None and raw.profile() is not None,
                         10, "ROI and profile")
        inside = raw.glw.mapToGlobal(raw.glw.rect().center())
        for dx in (0, 7, 14):  # a few moves over the image (motion events)
            self.x.move_to(inside + QPoint(dx - 40, dx - 20))
        yield self.typed()
        yield self.until(lambda: raw.readout.text().startswith("x "), 10, "the pixel readout")
        yield from self.choose(raw.colormap, "viridis")
        yield from self.click(self.tool(raw, raw.lock_action))
        yield from self.click(self.tool(raw, raw.snapshot_action))
        yield self.until(lambda: isinstance(QApplication.activeModalWidget(), QFileDialog), 20,
                         "the snapshot dialog")
        shot = self.work / f"snapshot-{self.loops}.tif"
        self.x.key("ctrl+a")
        self.x.type(str(shot))
        self.x.key("Return")
        yield self.typed()
        yield self.until(lambda: shot.exists(), 30, "the snapshot file")
        for action in (raw.roi_action, raw.profile_action, raw.lock_action):
            yield from self.click(self.tool(raw, action))
        yield from self.choose(raw.colormap, "grey")
        self.done("image tools and a snapshot")

    def unplug_and_reconnect(self) -> Iterator:
        w = self.w
        self.phase("disconnect")
        box = w.devices.boxes["led_array"]
        if self._control is not None:
            self._control.ask("unplug illuminate")
            yield self.until(self._control.answered, 30, "the emulator unplugged")
        else:
            w.session.service.run_job("device_fault", {"device": "led_array",
                                                       "action": "disconnect"})
        yield from self.click(self.button("led_array.all-off"))
        yield self.until(lambda: "DISCONNECTED" in w.device_labels["led_array"].text(), 30,
                         "the status area to show the LED array disconnected")
        if "disconnected" not in w.devices.state.text():
            raise StepFailed(f"device count: {w.devices.state.text()}")
        if self._control is not None:
            self._control.ask("replug illuminate")
            yield self.until(self._control.answered, 30, "the emulator plugged back")
        else:
            w.session.service.run_job("device_fault", {"device": "led_array",
                                                       "action": "allow_reconnect"})
        yield from self.click(box.reconnect_button)
        yield self.until(lambda: "DISCONNECTED" not in w.device_labels["led_array"].text()
                         and "disconnected" not in w.devices.state.text(), 60,
                         "the LED array reconnected")
        self.done("unplug and Reconnect")

    def shortcuts(self) -> Iterator:
        w = self.w
        self.phase("shortcuts")
        box = w.devices.boxes["source_stage"]
        far = {a: (lo + hi) / 2 for a, (lo, hi) in box.device.travel.items() if a == "z"}
        service, moving = w.session.service, {"stage": "source_stage"}
        self.x.click(w.live.raw_view.glw)
        yield self.typed()
        service.run_job("start_move", {**moving, "targets": far})  # a long move, then Esc
        yield 0.2
        self.x.key("Escape")
        yield self.typed()
        yield self.until(lambda: not service.run_job("is_moving", moving), 10,
                         "Esc to stop the stage")
        before = w.session.frames_seen
        self.x.key("F6")
        yield self.typed()
        yield self.until(lambda: not w.session.streaming and w.session.frames_seen > before,
                         30, "F6 to snap a frame")
        self.x.key("F5")
        yield self.typed()
        yield self.until(lambda: w.session.streaming, 20, "F5 to start the stream again")
        self.done("shortcuts")

    def quit_mid_recording(self) -> Iterator:
        w = self.w
        rec = w.record
        self.dock("Record")
        self.phase("quit")
        video = self.work / "last-video.zarr"
        yield from self.fill(rec.out, str(video))
        yield from self.fill(rec.frames, "100000")
        before = rec.record_job
        yield from self.click(rec.record_button)
        yield self.until(lambda: rec.record_job is not before
                         and rec.record_progress.value() >= 10, 120, "frames recorded")
        self.notes["quit_recording"] = str(video)
        self.done("quit asked while recording")
        self._finish(quit=True)

    # -- the end ------------------------------------------------------------------------------
    def report(self) -> dict:
        out = self.monitor.report()
        collector = getattr(QApplication.instance(), "_collector", None)  # gui.gcthread
        out.update(completed=self.completed, failure=self.failure, records=self.records,
                   notes=self.notes, loops=self.loops, day_s=time.monotonic() - self.t0,
                   xinput_errors=self.x.errors, xinput_sent=self.x.sent, retyped=self.retyped,
                   log_errors=[ln for ln in self.w.log_pane.lines if " error: " in ln][-20:],
                   # what the window said before a failed step (a message such as "the
                   # live stream could not start again: ..." has no " error: ")
                   log_tail=self.w.log_pane.lines[-40:] if self.failure is not None else [],
                   platform=QApplication.instance().platformName(),
                   simulate=bool(self.o.simulate), heap_growth=self.heap.report(),
                   gc_automatic=gc.isenabled(),  # False: collected on the GUI thread only
                   gc_collections=None if collector is None else list(collector.collections))
        return out

    def _finish(self, quit: bool = False) -> None:
        self.monitor.stop()
        self._prompts.stop()
        if self.failure is not None:  # what the window showed when the step failed
            screen = QApplication.primaryScreen().grabWindow(0)
            screen.save(str(self.work / "failure.png"))
        report = self.report()
        if os.environ.get("DIFFUSERLAB_DAY_FROZEN_GARBAGE"):  # unfreezes: the day's end
            from .daymonitor import frozen_garbage

            report["frozen_garbage"] = frozen_garbage()
        write_json(self.o.report, report, default=str)
        if quit:  # Ctrl+Q, then Yes in the question: the recording is finished first
            self.x.click(self.w.live.raw_view.glw)
            self.x.key("ctrl+q")
            QTimer.singleShot(1500, self._answer_yes)
        else:
            self.w.confirm = lambda title, text: True
            QTimer.singleShot(0, self.w.close)

    def _answer_yes(self) -> None:
        box = QApplication.activeModalWidget()
        if isinstance(box, QMessageBox):
            self.x.key("alt+y")
        else:
            QTimer.singleShot(500, self._answer_yes)


class _Stage:
    """A stage's position as the bench's service reads it."""

    def __init__(self, service, name: str) -> None:
        self.service, self.name = service, name

    def positions(self) -> dict[str, float]:
        return self.service.positions(self.name)

    def position(self, axis: str) -> float:
        return self.positions()[axis]


class _Control:
    """Requests to the process that runs the emulators (unplug / replug a device)."""

    def __init__(self, fd: int) -> None:
        self.sock = socket.socket(fileno=fd)
        self._answer = threading.Event()
        self._answer.set()

    @classmethod
    def from_env(cls) -> _Control | None:
        fd = os.environ.get(CONTROL_ENV)
        return cls(int(fd)) if fd else None

    def ask(self, request: str) -> None:
        self._answer.clear()

        def exchange() -> None:
            self.sock.sendall((request + "\n").encode())
            self.sock.recv(64)
            self._answer.set()

        threading.Thread(target=exchange, daemon=True).start()

    def answered(self) -> bool:
        return self._answer.is_set()


def start_when_shown(make: Callable[[Any], Any]) -> None:
    """Start an operator on the window ``diffuserlab gui`` is about to show.

    Creates the QApplication if there is none, then, on its event loop, waits (every
    100 ms) for the :class:`gui.app.MainWindow` and calls ``make(window).start()``; the
    operator is kept alive with the application (``app._operator``). Call it before
    handing the process to ``diffuserlab gui``.

    Parameters
    ----------
    make : callable
        ``make(window)`` returns the operator (an object with ``start()``).
    """
    app = QApplication.instance() or QApplication(sys.argv[:1])

    def begin() -> None:
        from gui.app import MainWindow

        windows = [w for w in app.topLevelWidgets() if isinstance(w, MainWindow)]
        if not windows:
            QTimer.singleShot(100, begin)
            return
        operator = make(windows[0])
        app._operator = operator  # kept alive with the application
        operator.start()

    QTimer.singleShot(0, begin)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m soak.operator_day",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--bench", default=None, help="bench file (default: --simulate)")
    p.add_argument("--simulate", action="store_true", help="the built-in simulated bench")
    p.add_argument("--minutes", type=float, default=5.0, help="length of the day")
    p.add_argument("--alignment-s", type=float, default=30.0,
                   help="abort the alignment after this many seconds (0: let it finish)")
    p.add_argument("--work", required=True, help="folder for the day's runs")
    p.add_argument("--report", required=True, help="JSON report written before the end")
    args = p.parse_args(argv)
    args.simulate = args.simulate or args.bench is None
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    start_when_shown(lambda window: Operator(window, args))
    from gui.session import BENCH_JOBS
    from instrument.cli import main as diffuserlab

    from .device_jobs import JOBS

    BENCH_JOBS.update(JOBS)  # a simulated device's faults, a move not waited for

    command = ["gui", "--scene", "beads-flow"] + (
        ["--simulate"] if args.bench is None else [args.bench])
    return diffuserlab(command)


if __name__ == "__main__":
    sys.exit(main())

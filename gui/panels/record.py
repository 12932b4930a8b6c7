"""Record panel: start / stop a video recording (frames written, MB/s, dropped, ETA),
and batch reconstruction of a recorded run (progress, ETA, cancel).

Recording is :func:`instrument.acquisition.video.record_video` on a worker (the camera streams
into a ring, every frame goes to the recorder; the live view keeps showing the newest
frame and, if it runs, the live reconstruction); Stop sets its ``stop`` event, and
the run keeps what was recorded. Batch reconstruction is
:func:`instrument.processing.batch.reconstruct_run` on a worker (dask), cancelled through its
``cancel`` event; its results are a product of the run, shown in the Results panel.
Every field is remembered between sessions; the live reconstruction's PSF and depth
are carried into the batch fields (:meth:`RecordPanel.take_psf`).
"""

from __future__ import annotations

import datetime as _dt
import threading
import time
from pathlib import Path

from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QBoxLayout,
    QGridLayout,
    QGroupBox,
    QLabel,
    QLineEdit,
    QPushButton,
    QWidget,
)

from instrument.options import COMMAND_FIELDS, RunOptions
from instrument.processing.reconstruct_files import RECIPE_FIXES
from recon.early_stop import FILE as RECIPE_FILE
from recon.early_stop import OFF, named
from recon.options import ReconOptions

from ..device_settings import parse_duration_s
from ..fields import remember
from ..forms import OptionsForm, lay_out
from ..logpane import announce_job, gui_log, job_ended
from ..session import Session
from ..workers import DEVICE_NICE, InputError, Job
from .common import JobProgress, dark_hint, depth_field, error_label, offer_depths

__all__ = ["RecordPanel"]

#: ``recon-run``'s own fields the batch form shows (its reconstruction fields are the
#: command's, :data:`instrument.options.COMMAND_FIELDS`): PSF and depth first,
#: the frames, workers and ΔF/F last.
BATCH_RUN_FIELDS = ("psf", "depth_mm", "frames", "workers", "dff")


def refusal_text(failed: list[str], total: int) -> str:
    """One operator-level line for the frames a batch refused (its ``failed`` lines,
    ``"frame I (point P): REASON"``): the frames grouped by the reason's first clause,
    each group with its frames and the first frame's whole reason.

    Parameters
    ----------
    failed : list of str
        :func:`instrument.processing.batch.reconstruct_run`'s ``failed``.
    total : int
        The frames the batch was asked for.

    Returns
    -------
    str
        E.g. ``"4 of 4 frames refused, none reconstructed: frames 0-3: the data carry
        no signal: ... (each frame's reason is in the log)"``.
    """
    from instrument.runs.runstore_records import ranges_text

    groups: dict[str, tuple[list[int], str]] = {}
    for line in failed:
        head, _, reason = line.partition(": ")
        try:
            index = int(head.split()[1])
        except (IndexError, ValueError):
            index = -1
        frames, _ = groups.setdefault(reason.split(":")[0], ([], reason))
        frames.append(index)
    none = " none reconstructed:" if len(failed) >= total else ""
    parts = [f"frame{'s' if len(f) > 1 else ''} {ranges_text(sorted(f))}: {reason}"
             for f, reason in groups.values()]
    return (f"{len(failed)} of {total} frames refused,{none or ':'} " + "; ".join(parts)
            + " (each frame's reason is in the log)").replace(",:", ":")


def _number(text: str, what: str, kind=float):
    text = text.strip()
    if not text:
        return None
    try:
        return kind(text)
    except ValueError:
        raise InputError(f"{what} {text!r}: give a number or leave it empty") from None


class RecordPanel(QWidget):
    """See the module docstring.

    Signals
    -------
    result_ready(str, str)
        ``(run, product)`` of a finished batch reconstruction (the Results panel shows
        it).
    """

    result_ready = Signal(str, str)

    def __init__(self, session: Session, live_panel=None, parent=None) -> None:
        super().__init__(parent)
        self.session = session
        self.live_panel = live_panel
        self.record_job: Job | None = None
        self.batch_job: Job | None = None
        self.stop_event = threading.Event()
        self.last_run: str | None = None
        self.summary: dict | None = None
        self.batch_result: dict | None = None
        self._carried: tuple[str, str] = ("", "")
        self._rate_from: tuple[float, int] | None = None  # (time, frames) of the first
        layout = self._columns = QBoxLayout(QBoxLayout.Direction.TopToBottom, self)
        layout.setContentsMargins(4, 4, 4, 4)
        rec = QGroupBox("record a video")
        g = QGridLayout(rec)
        g.addWidget(QLabel("run store:"), 0, 0)
        self.out = QLineEdit()
        self.out.setObjectName("record.out")
        self.out.setPlaceholderText("default out/runs/video-TIME.zarr")
        g.addWidget(self.out, 0, 1, 1, 3)
        g.addWidget(QLabel("frames:"), 1, 0)
        self.frames = remember(QLineEdit("100"), "record/frames")
        self.frames.setObjectName("record.frames")
        self.frames.setToolTip("number of frames (or give seconds instead)")
        g.addWidget(self.frames, 1, 1)
        g.addWidget(QLabel("or seconds (s):"), 1, 2)
        self.seconds = remember(QLineEdit(), "record/seconds")
        g.addWidget(self.seconds, 1, 3)
        g.addWidget(QLabel("frame rate (Hz):"), 2, 0)
        self.fps = remember(QLineEdit(), "record/fps")
        self.fps.setPlaceholderText("camera's setting")
        g.addWidget(self.fps, 2, 1)
        g.addWidget(QLabel("exposure (ms or s):"), 2, 2)
        self.exposure = remember(QLineEdit(), "record/exposure")
        self.exposure.setPlaceholderText("camera's setting (e.g. 20 ms)")
        g.addWidget(self.exposure, 2, 3)
        self.record_button = QPushButton("Start recording")
        self.record_button.setObjectName("record.start")
        self.record_button.clicked.connect(self.toggle_recording)
        g.addWidget(self.record_button, 3, 0)
        self.record_progress = JobProgress("frames written")
        g.addWidget(self.record_progress, 3, 1, 1, 3)
        self.counters = QLabel("not recording")
        self.counters.setWordWrap(True)
        g.addWidget(self.counters, 4, 0, 1, 4)
        self.record_error = error_label()
        g.addWidget(self.record_error, 5, 0, 1, 4)
        layout.addWidget(rec)
        batch = QGroupBox("batch reconstruction of a recorded run (dask)")
        b = QGridLayout(batch)
        b.addWidget(QLabel("run:"), 0, 0)
        self.run_path = remember(QLineEdit(), "batch/run")
        self.run_path.setObjectName("batch.run")
        self.run_path.setPlaceholderText("RUN.zarr (default: the last recording)")
        b.addWidget(self.run_path, 0, 1, 1, 3)
        # the fields are generated from recon-run's declarations (gui.forms)
        depth = depth_field("batch--depth")
        self.run_form = OptionsForm(RunOptions, BATCH_RUN_FIELDS, name="batch",
                                    remember_as="batch", widgets={"depth_mm": depth})
        self.recon_form = OptionsForm(ReconOptions, COMMAND_FIELDS["recon-run"],
                                      name="batch", remember_as="batch")
        psf = self.run_form.widgets["psf"]
        psf.setPlaceholderText("image, PSF stack or calibration run")
        psf.editingFinished.connect(lambda: offer_depths(depth, psf.text()))
        #: ``{flag: widget}`` of the batch form (``"--iterations"``).
        self.batch_fields: dict[str, QWidget] = {
            form.specs[f].flag: w for form in (self.run_form, self.recon_form)
            for f, w in form.widgets.items()}
        rows = (self.run_form.rows(("psf", "depth_mm")) + self.recon_form.rows()
                + self.run_form.rows(BATCH_RUN_FIELDS[2:]))
        end = lay_out(b, rows, row=1, columns=2)
        # a scene-calibrated PSF run's recipe: the fields show it, a line says so
        self.recipe_line = QLabel("")
        self.recipe_line.setObjectName("batch.recipe")
        self.recipe_line.setWordWrap(True)
        self.recipe_line.hide()
        self.recipe_button = QPushButton("Use the PSF run's recipe")
        self.recipe_button.setObjectName("batch.use-recipe")
        self.recipe_button.setToolTip("show and run the reconstruction recipe the PSF's "
                                      "scene calibration fitted")
        self.recipe_button.clicked.connect(self.use_recipe)
        self.recipe_button.hide()
        b.addWidget(self.recipe_line, end, 0, 1, 4)  # the whole width: up to 6 lines
        b.addWidget(self.recipe_button, end + 1, 3)
        end += 2
        self._recipe = None  # the PSF run's recipe (recon.early_stop.EarlyStop) or None
        self._recipe_shown = False  # the fixed fields show it, and it will run
        self._before_recipe: dict[str, str] = {}  # their texts before they showed it
        self._edited: set[str] = set()  # the fields the operator edited since
        for field in RECIPE_FIXES:
            widget = self.recon_form.widgets.get(field)
            if widget is not None:
                signal = (widget.valueChanged if hasattr(widget, "valueChanged")
                          else widget.currentTextChanged)
                signal.connect(lambda _=None, f=field: self._recipe_edited(f))
        self.batch_fields["--early-stop"].textChanged.connect(
            lambda _=None: self._recipe_edited("early_stop"))
        psf.editingFinished.connect(self.show_recipe)
        self.batch_button = QPushButton("Reconstruct run")
        self.batch_button.setObjectName("batch.start")
        self.batch_button.clicked.connect(self.toggle_batch)
        b.addWidget(self.batch_button, end, 0)
        self.batch_progress = JobProgress("frames reconstructed")
        b.addWidget(self.batch_progress, end, 1, 1, 3)
        self.batch_status = QLabel("")
        self.batch_status.setWordWrap(True)
        b.addWidget(self.batch_status, end + 1, 0, 1, 4)
        self.batch_error = error_label()
        b.addWidget(self.batch_error, end + 2, 0, 1, 4)
        layout.addWidget(batch)
        self._groups = (rec, batch)
        session.changed.connect(self._show_dark_hint)
        self._show_dark_hint()
        self.show_recipe()
        layout.setAlignment(Qt.AlignmentFlag.AlignTop)

    def _show_dark_hint(self) -> None:
        """The batch's dark field says what empty means on this bench (:func:`dark_hint`)."""
        field = self.batch_fields.get("--dark")
        if isinstance(field, QLineEdit):
            field.setPlaceholderText(dark_hint(self.session))

    def resizeEvent(self, event) -> None:  # noqa: N802 (Qt's name)
        """The recording and the batch side by side when the dock is wide enough for
        both (a 1600 x 1000 screen: both fit its height then), else one above the
        other (a laptop's narrow dock scrolls)."""
        super().resizeEvent(event)
        margins = self._columns.contentsMargins()
        need = (sum(g.minimumSizeHint().width() for g in self._groups)
                + self._columns.spacing() + margins.left() + margins.right())
        direction = (QBoxLayout.Direction.LeftToRight if event.size().width() >= need
                     else QBoxLayout.Direction.TopToBottom)
        if self._columns.direction() != direction:
            self._columns.setDirection(direction)

    # -- the PSF run's recipe ------------------------------------------------------------
    def _fixed_widgets(self) -> dict:
        """``{field: widget}`` of the recipe's fixed fields the form shows."""
        return {f: self.recon_form.widgets[f] for f in RECIPE_FIXES
                if f in self.recon_form.widgets}

    def _set_quietly(self, widget, text: str) -> None:
        """Show ``text`` in a field without storing it (:func:`gui.fields.remember`) and
        without counting it as the operator's edit."""
        from PySide6.QtWidgets import QComboBox, QSpinBox

        widget.blockSignals(True)
        try:
            if isinstance(widget, QSpinBox):
                widget.setValue(int(text))
            elif isinstance(widget, QComboBox) and not widget.isEditable() and not text:
                widget.setCurrentIndex(-1)
            elif isinstance(widget, QComboBox):
                widget.setCurrentText(text)
            else:
                widget.setText(text)
        finally:
            widget.blockSignals(False)

    def _recipe_texts(self, recipe) -> dict[str, str]:
        """What the fixed fields show for ``recipe``: its solve (FISTA, its count, no TV,
        no l1; the prior left blank: FISTA without TV has none)."""
        return {"method": "fista", "iterations": str(int(recipe.iterations)), "tv": "0",
                "l1": "0", "prior": ""}

    def show_recipe(self) -> None:
        """Show what will run with the PSF field's run.

        A ``calibrate psf-from-scenes`` run holding its recipe (``early_stop.json``)
        is reconstructed with that recipe by default, as ``recon-run --psf RUN``
        (:func:`instrument.processing.reconstruct_files.scene_recipe_default`): the solver,
        iteration, TV and l1 fields then show the recipe's solve, the prior field is
        blank and disabled, and a line says the recipe's PSF threshold and denoising.
        Fields the operator already set (or ``--early-stop``) decline it, and the
        line says so. Another PSF: the fields return to what they held.
        """
        from recon.early_stop import EarlyStop
        from recon.errors import ReconInputError

        path = self.batch_fields["--psf"].text().strip()
        recipe, unreadable = None, ""
        if path and (Path(path) / RECIPE_FILE).is_file():
            try:
                recipe = EarlyStop.load(path)
            except ReconInputError as exc:
                unreadable = str(exc)
        if recipe is None:
            self._restore_fields()
            self._recipe = None
            self.recipe_button.hide()
            self.recipe_line.setText(unreadable)
            self.recipe_line.setVisible(bool(unreadable))
            return
        self._recipe = recipe
        given = self.recon_form.texts()
        if self._recipe_shown or not (set(given) & {*RECIPE_FIXES, "early_stop"}):
            self._apply_recipe()
        else:
            self._say_declined(", ".join(
                self.recon_form.labels[f].text().rstrip(":") for f in given
                if f in (*RECIPE_FIXES, "early_stop")) + " set in the form")

    def use_recipe(self) -> None:
        """Show and run the PSF run's recipe again (the *Use the PSF run's recipe*
        button): the early-stop field emptied, the fixed fields showing the recipe."""
        if self._recipe is None:
            return
        self._set_quietly(self.batch_fields["--early-stop"], "")
        self._apply_recipe()

    def _apply_recipe(self) -> None:
        r = self._recipe
        widgets = self._fixed_widgets()
        if not self._before_recipe:
            self._before_recipe = {f: str(OptionsForm.widget_text(w))
                                   for f, w in widgets.items()}
        self._edited.clear()
        for field, text in self._recipe_texts(r).items():
            if field in widgets:
                self._set_quietly(widgets[field], text)
        if "prior" in widgets:
            widgets["prior"].setEnabled(False)
            widgets["prior"].setToolTip("the recipe's FISTA has no prior")
        self.batch_fields["--early-stop"].setPlaceholderText(
            "the PSF run's recipe (off declines)")
        self._recipe_shown = True
        denoise = (f"isotropic TV denoising at weight {r.denoise_weight:g}"
                   if r.denoise_weight else "no denoising")
        field = ("" if r.field_response is None else
                 ", then its field response (a gain over the field fitted on the "
                 "calibration scenes: dark where they were dark)")
        self.recipe_line.setText(
            f"will run the PSF run's scene-calibration recipe: PSF soft-thresholded at "
            f"{r.psf_threshold:g} of its maximum, FISTA without a prior, {r.iterations} "
            f"iterations, then {denoise}{field}. Editing solver, iterations, TV, l1 or "
            "early-stop declines the recipe.")
        self.recipe_line.setStyleSheet("")
        self.recipe_line.show()
        self.recipe_button.hide()

    def _restore_fields(self) -> None:
        """The fixed fields back to what they held before they showed a recipe (those
        the operator edited since are kept)."""
        widgets = self._fixed_widgets()
        for field, text in self._before_recipe.items():
            if field not in self._edited:
                self._set_quietly(widgets[field], text)
        self._release_prior()
        self.batch_fields["--early-stop"].setPlaceholderText("none")
        self._recipe_shown = False
        self._before_recipe = {}
        self._edited.clear()

    def _release_prior(self) -> None:
        prior = self._fixed_widgets().get("prior")
        if prior is not None and not prior.isEnabled():
            prior.setEnabled(True)
            prior.setToolTip(self.recon_form.specs["prior"].help)
            if prior.currentIndex() < 0:
                self._set_quietly(prior, self._before_recipe.get(
                    "prior", self.recon_form.specs["prior"].default))

    def _recipe_edited(self, field: str) -> None:
        """An operator's edit of a fixed field (or the early-stop field) while the
        recipe is shown declines it; the line says so."""
        self._edited.add(field)
        if not self._recipe_shown:
            return
        if field == "early_stop" and not self.batch_fields["--early-stop"].text().strip():
            return
        self._recipe_shown = False
        self._release_prior()
        self.batch_fields["--early-stop"].setPlaceholderText("none")
        label = self.recon_form.labels[field].text().rstrip(":")
        self._say_declined(f"'{label}' edited")

    def _say_declined(self, why: str) -> None:
        self.recipe_line.setText(
            f"the PSF run's scene-calibration recipe is declined ({why}): the batch runs "
            "the form's values as shown, without the recipe's PSF threshold and "
            "denoising. 'Use the PSF run's recipe' takes it again.")
        self.recipe_line.setStyleSheet("color: #8a5a00;")
        self.recipe_line.show()
        self.recipe_button.show()

    def batch_texts(self) -> dict[str, str]:
        """The batch form's ``{flag: text}`` as :func:`gui.jobs.batch_options` takes
        them: while the fields show the PSF run's recipe, its fixed fields are left out
        (the recipe is the default,
        :func:`~instrument.processing.reconstruct_files.scene_recipe_default`);
        a recipe declined is declined explicitly (``--early-stop off``), whatever
        the fields hold."""
        texts = {**self.run_form.texts(flags=True), **self.recon_form.texts(flags=True)}
        if self._recipe is None:
            return texts
        if self._recipe_shown:
            fixed = {self.recon_form.specs[f].flag for f in RECIPE_FIXES}
            return {f: v for f, v in texts.items() if f not in fixed}
        texts.setdefault("--early-stop", OFF)
        return texts

    # -- state ---------------------------------------------------------------------------
    @property
    def recording(self) -> bool:
        return self.record_job is not None and self.record_job.running

    @property
    def batch_running(self) -> bool:
        return self.batch_job is not None and self.batch_job.running

    def take_psf(self, psf: str, depth: str) -> None:
        """The live reconstruction's PSF and depth, carried into the batch fields (unless
        the operator typed others there)."""
        psf_field = self.batch_fields["--psf"]
        depth_box = self.batch_fields["--depth"]
        if psf_field.text().strip() in ("", self._carried[0]):
            psf_field.setText(psf)
            offer_depths(depth_box, psf)
            self.show_recipe()
        if depth_box.currentText().strip() in ("", self._carried[1]):
            depth_box.setEditText(depth)
        self._carried = (psf, depth)

    # -- recording -----------------------------------------------------------------------
    def toggle_recording(self) -> None:
        if self.recording:
            self.stop_recording()
        else:
            self.start_recording()

    def stop_recording(self) -> None:
        """Stop the recording (what was recorded is kept, the run summarised)."""
        self.stop_event.set()
        if self.recording:
            self.record_button.setText("Stopping ...")

    def start_recording(self) -> Job | None:
        """Record into a new run store on a worker (:func:`gui.jobs.record`)."""
        from ..jobs import record

        self.record_error.setText("")
        if not self.session.connected:
            self.record_error.setText("no bench is connected; press Connect on the Devices "
                                      "panel")
            return None
        try:
            frames = _number(self.frames.text(), "frames", int)
            seconds = _number(self.seconds.text(), "seconds")
            fps = _number(self.fps.text(), "frame rate")
            exposure_s = parse_duration_s(self.exposure.text())
        except InputError as exc:
            self.record_error.setText(str(exc))
            return None
        if seconds is not None:
            frames = None
        out = self.out.text().strip() or f"out/runs/video-{_dt.datetime.now():%Y%m%d-%H%M%S}.zarr"
        self.stop_event = threading.Event()
        self.record_progress.start(frames or 0)
        self.counters.setText("starting the recording ...")
        length = (f"{frames} frames" if frames else f"{seconds:g} s" if seconds
                  else "until stopped")
        announce_job("recording", f"{length} into {out}")
        self.record_job = Job(record, self.session, out, self.stop_event, frames=frames,
                              seconds=seconds, fps=fps, exposure_s=exposure_s,
                              live=getattr(self.live_panel, "live", None),
                              name="record-video", nice=DEVICE_NICE)
        self.record_job.progress.connect(lambda p: self.on_record_progress(p, out))
        self.record_job.succeeded.connect(self.on_recorded)
        self.record_job.failed.connect(lambda text: self.on_record_failed(text, out))
        self.record_button.setText("Stop recording")
        return self.record_job.start()

    def on_record_progress(self, p: dict, out: str = "") -> None:
        recorded = int(p.get("recorded", 0))
        total = self.record_progress.bar.maximum()
        eta = None
        if total and p.get("fps"):
            eta = max(total - recorded, 0) / max(float(p["fps"]), 1e-9)
        self.record_progress.report(recorded, eta_s=eta)
        self.counters.setText(
            f"recording into {out}: written {recorded} frames, {p.get('write_mb_s', 0):.1f} "
            f"MB/s, camera {p.get('fps', 0):.1f} fps; dropped by the camera "
            f"{p.get('dropped_by_camera', 0)}, skipped by the ring {p.get('skipped_by_ring', 0)}"
            f", lost by the recorder {p.get('lost_by_recorder', 0)}")

    def on_recorded(self, summary: dict) -> None:
        self.summary = summary
        self.last_run = summary["path"]
        self.record_button.setText("Start recording")
        self.record_progress.report(int(summary.get("recorded", 0)),
                                    max(int(summary.get("frames_requested", 0)), 1))
        self.record_progress.finish()
        lost = int(summary.get("lost_by_recorder", 0)) + int(summary.get("dropped_by_camera", 0))
        self.counters.setText(
            f"{summary['status']}: {summary.get('recorded', 0)} frames written to "
            f"{summary['path']} at {summary.get('write_mb_s', 0):.1f} MB/s "
            f"({summary.get('fps', 0):.1f} fps); "
            + ("no frame lost" if not lost else f"{lost} frame(s) lost (see runs show)"))
        self.run_path.setText(summary["path"])
        job_ended("recording", self.counters.text(), ok=not lost)

    def on_record_failed(self, text: str, out: str = "") -> None:
        from instrument.runs.runstore import is_run_store

        self.record_button.setText("Start recording")
        self.record_progress.finish("")
        if out and is_run_store(out):  # the run was created: what it holds is kept
            self.last_run = out
            self.counters.setText(f"stopped: the frames recorded so far are kept in {out}")
            self.record_error.setText(f"recording stopped: {text}")
            job_ended("recording", f"stopped: the frames recorded so far are kept in {out}",
                      ok=False)
        else:
            self.counters.setText("not recording")
            self.record_error.setText(f"recording not started: {text}")

    # -- batch ---------------------------------------------------------------------------
    def toggle_batch(self) -> None:
        if self.batch_running:
            self.batch_job.cancel()
            self.batch_button.setText("Cancelling ...")
        else:
            self.start_batch()

    def start_batch(self) -> Job | None:
        """Reconstruct the frames of a run on a worker (:func:`gui.jobs.batch_reconstruct`)."""
        from ..jobs import batch_options, batch_reconstruct

        self.batch_error.setText("")
        run = self.run_path.text().strip() or self.last_run
        if not run:
            self.batch_error.setText("give the run to reconstruct (RUN.zarr)")
            return None
        if not Path(run).exists():
            self.batch_error.setText(f"the run {run} does not exist; record one or give the "
                                     "path of a recorded run")
            return None
        self.show_recipe()  # the PSF field may have changed without leaving it
        texts = self.batch_texts()
        labels = {**self.run_form.flag_labels(), **self.recon_form.flag_labels()}
        try:
            recon, own = batch_options(texts)
        except InputError as exc:
            from ..messages import operator_text

            self.batch_error.setText(operator_text(str(exc), labels))
            return None
        self.batch_progress.start(0)
        self.batch_status.setText(f"reconstructing {run} ...")
        how = ("the PSF's scene-calibration recipe (early-stop calibration: off declines it)"
               if named(recon.early_stop) else
               f"{recon.method}, {recon.iterations} iterations, TV weight {recon.tv}, "
               f"prior {recon.prior}" + (" (the PSF run's recipe declined)"
                                         if self._recipe is not None else ""))
        announce_job("batch reconstruction", f"{run} with {how}")
        self._rate_from = None

        def reconstruct(job: Job):
            try:
                return batch_reconstruct(job, run, recon, own)
            except InputError as exc:
                from ..messages import operator_text

                raise InputError(operator_text(str(exc), labels)) from None

        self.batch_job = Job(reconstruct, name="batch-recon")
        self.batch_job.progress.connect(self.on_batch_progress)
        self.batch_job.succeeded.connect(lambda result: self.on_batch_done(run, result))
        self.batch_job.failed.connect(self.on_batch_failed)
        self.batch_button.setText("Cancel")
        return self.batch_job.start()

    def on_batch_progress(self, p: dict) -> None:
        """A batch's progress: ``{"kind": "start", "total"}`` before the workers start,
        then one report per frame stored. The ETA is the rate since the first frame
        (the workers' start and the first frame's compilation left out), from the
        first frame's own rate until a second one is in."""
        if p.get("kind") == "start":
            self.batch_progress.report(0, int(p["total"]), note="starting the workers")
            self.batch_status.setText(f"reconstructing {p['total']} frames of {p['run']}: "
                                      "starting the workers; the ETA follows the first frame")
            return
        done, total = int(p["done"]), int(p["total"])
        now = time.monotonic()
        if self._rate_from is None:
            self._rate_from = (now, done)
            eta = (total - done) / p["fps"] if p.get("fps") else None
        else:
            t0, d0 = self._rate_from
            eta = (total - done) * (now - t0) / (done - d0) if done > d0 else None
        self.batch_progress.report(done, total, eta_s=eta, note="")
        self.batch_status.setText(f"{p['done']} of {p['total']} frames ({p['skipped']} done "
                                  f"before), {p['fps']:.2f} frames/s")

    def on_batch_done(self, run: str, result: dict) -> None:
        self.batch_result = result
        self.batch_button.setText("Reconstruct run")
        self.batch_progress.finish(ok=not result.get("cancelled") and bool(
            int(result["reconstructed"]) + int(result["skipped"])))
        if result.get("cancelled"):
            self.batch_status.setText(
                f"cancelled: {result['reconstructed']} frames reconstructed and kept in "
                f"{result['product']}; press Reconstruct run again to finish")
            job_ended("batch reconstruction", self.batch_status.text() + f" (run {run})",
                      ok=False)
            return
        failed = list(result.get("failed") or [])
        total = int(result["reconstructed"]) + int(result["skipped"]) + len(failed)
        for line in failed:  # each frame's reason, in the log pane
            gui_log.warning("batch reconstruction refused %s", line)
        if failed:
            self.batch_error.setText(refusal_text(failed, total))
        if not int(result["reconstructed"]) + int(result["skipped"]):
            self.batch_status.setText(
                f"no frame reconstructed: the batch refused every frame of {run} "
                "(the reason is above)" if failed else
                f"no frame reconstructed: {run} has no stored frame in the selection")
            job_ended("batch reconstruction", f"ended with no frame reconstructed ({run})",
                      ok=False)
            return
        self.batch_status.setText(
            f"{result['product']}: {result['reconstructed']} frames reconstructed, "
            f"{result['skipped']} already done"
            + (f", {len(failed)} refused" if failed else "")
            + f", {result['seconds']:.1f} s "
            f"({result['fps']:.2f} frames/s, {result['workers'] or 0} workers)")
        job_ended("batch reconstruction", f"finished: product {result['product']} of {run}, "
                  f"{result['reconstructed']} frames in {result['seconds']:.1f} s"
                  + (f", {len(failed)} refused" if failed else ""), ok=not failed)
        self.result_ready.emit(run, result["product"])

    def on_batch_failed(self, text: str) -> None:
        self.batch_button.setText("Reconstruct run")
        self.batch_progress.finish("")
        self.batch_error.setText(text)
        job_ended("batch reconstruction", f"failed: {text}", ok=False)

    def cancel(self) -> None:
        """Stop a recording and cancel a batch reconstruction (window closing)."""
        self.stop_event.set()
        if self.batch_job is not None:
            self.batch_job.cancel()

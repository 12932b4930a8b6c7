"""The plan runner: executes a plan's steps on a bench, storing every frame.

* Progress: ``on_event(RunEvent)`` after every step and frame (done/total frames,
  ETA, the last frame), and on start, pause, resume, reconnect, abort and end.
* Control: a :class:`RunControl` (thread-safe) pauses, resumes or aborts between
  steps; Ctrl-C (KeyboardInterrupt) aborts too.
* Teardown: on every exit path (done, failed, aborted) each operator change the run
  made and did not put back (the camera capped, the diffuser out:
  :data:`instrument.acquisition.plan.RESTORES`, recorded in the store as ``bench_changes``) is
  put back, in the words of the plan's teardown (:meth:`instrument.acquisition.plan.Plan.teardown`).
* Safety: on abort or error the bench goes to its safe state (LEDs off, stages
  stopped, streams stopped) and the store keeps everything captured, marked
  ``aborted`` / ``failed`` with the reason; :meth:`Runner.resume` continues with
  the first point the store does not hold completely (a point is redone whole).
* Disconnections: a device that disconnects mid-point is reconnected (its settings
  re-applied by ``Device.reconnect``) for up to ``reconnect_timeout_s``; then the
  point is redone. A device timeout redoes the point up to ``max_point_retries``
  times. Otherwise the run fails cleanly, data kept.
* Settle: after each move, the step's ``settle_s`` or the bench config's
  ``calibration.settle_s``, on the bench's clock; after each SLM pattern, the
  SLM's own ``settle_s`` (in :meth:`drivers.slm.Slm.show_image`).
* Session: the plan's :meth:`~instrument.acquisition.plan.Plan.session` context is held around
  setup, points and teardown (entered again on resume) and left before the bench
  is made safe and before the products are computed.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from diffuserlab.errors import DiffuserLabError
from diffuserlab.jsonio import jsonable
from drivers.errors import DeviceDisconnectedError, DeviceError, DeviceTimeoutError

from ..devices.bench import Bench, PromptRefused
from ..runs.coords import coord_specs
from ..runs.run_identity import Difference, format_differences, resume_differences
from ..runs.runstore import RunStore, RunStoreError, software_version, utc_now
from ..runs.runstore_records import video_cannot_continue
from .exposure import ExposureError, autoexpose
from .plan import (
    RESTORES,
    Capture,
    Check,
    CheckFailed,
    Expose,
    Light,
    Move,
    Plan,
    PlanError,
    Prompt,
    ShowSlm,
    plan_from_record,
)
from .preflight import preflight

__all__ = ["RunAborted", "RunControl", "RunEvent", "RunResult", "Runner", "frame_coords"]

log = logging.getLogger(__name__)


class RunAborted(DiffuserLabError):
    """Raised inside the runner when an abort was requested (never escapes it)."""


class RunControl:
    """Pause, resume and abort a run from any thread (checked between steps)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._paused = False
        self._abort_reason: str | None = None

    def pause(self) -> None:
        """Hold the run before its next step."""
        with self._cond:
            self._paused = True

    def resume(self) -> None:
        """Let a paused run continue."""
        with self._cond:
            self._paused = False
            self._cond.notify_all()

    def abort(self, reason: str = "aborted by the operator") -> None:
        """Stop the run before its next step (also wakes a paused run)."""
        with self._cond:
            self._abort_reason = reason
            self._cond.notify_all()

    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def abort_reason(self) -> str | None:
        return self._abort_reason

    def wait_while_paused(self, poll_s: float = 0.1) -> bool:
        """Block while paused; returns True if it had to wait. Raises RunAborted."""
        waited = False
        with self._cond:
            while self._paused and self._abort_reason is None:
                waited = True
                self._cond.wait(poll_s)
            if self._abort_reason is not None:
                raise RunAborted(self._abort_reason)
        return waited


@dataclass
class RunEvent:
    """Progress of a run.

    ``kind``: started, step, frame, point_done, paused, resumed, reconnecting,
    reconnected, retrying, completed, aborted, failed. ``eta_s`` is wall-clock
    seconds, None until a frame of this session was captured. ``last_frame`` is set
    on ``frame`` events.
    """

    kind: str
    path: str
    point: int | None
    frames_done: int
    frames_total: int
    points_done: int
    points_total: int
    elapsed_s: float
    eta_s: float | None
    message: str = ""
    step: str | None = None
    last_frame: np.ndarray | None = field(default=None, repr=False)


@dataclass
class RunResult:
    """How a run ended: ``status`` (complete, aborted, failed), the store path, points
    done, the error text (if any), the plan's summary (complete runs) and the operator
    actions that put the bench back (e.g. "put the diffuser back") which the runner
    asked for on its way out and were not carried out (refused, no operator) -
    needed unless the run is resumed."""

    status: str
    path: Path
    points_done: int
    points_total: int
    error: str | None = None
    summary: dict[str, Any] = field(default_factory=dict)
    pending_actions: list[str] = field(default_factory=list)

    @property
    def resume_hint(self) -> str:
        return (f"resume with `diffuserlab calibrate resume {self.path} BENCH.toml` or "
                f"Runner(bench).resume('{self.path}')")


def frame_coords(bench: Bench, frame) -> dict[str, float]:
    """Per-frame coordinates: camera exposure/gain/timestamps/saturation, every stage
    axis (``<stage id>.<axis>``), LED count/first index/brightness, SLM pattern id, DMD
    exposure/period/running (their units: :mod:`instrument.runs.coords`)."""
    out = {"exposure_s": frame.exposure_s, "gain": frame.gain,
           "device_timestamp_s": frame.device_timestamp_s,
           "host_time_unix_s": frame.host_timestamp_s,
           "saturated_pixels": float(frame.saturated_pixels), "frame_index": float(frame.index)}
    for dev_id, dev in bench.devices.items():
        if dev.kind == "stage":
            for axis, value in dev.positions().items():
                out[f"{dev_id}.{axis}"] = value
        elif dev.kind == "led_array":
            lit = dev.lit()
            out[f"{dev_id}.n_lit"] = float(len(lit))
            out[f"{dev_id}.first_lit"] = float(min(lit)) if lit else -1.0
            out[f"{dev_id}.brightness"] = float(max((b for _, b in lit.values()), default=0.0))
        elif dev.kind == "slm":
            out[f"{dev_id}.pattern_id"] = float(dev.pattern_id)
        elif dev.kind == "dmd":
            out[f"{dev_id}.exposure_s"] = float(dev.exposure_s)
            out[f"{dev_id}.period_s"] = float(dev.period_s)
            out[f"{dev_id}.running"] = float(dev.running)
    return out


def coord_names(bench: Bench) -> list[str]:
    """The names :func:`frame_coords` produces for ``bench``, in order."""
    names = ["exposure_s", "gain", "device_timestamp_s", "host_time_unix_s",
             "saturated_pixels", "frame_index"]
    for dev_id, dev in bench.devices.items():
        if dev.kind == "stage":
            names += [f"{dev_id}.{a}" for a in dev.axes]
        elif dev.kind == "led_array":
            names += [f"{dev_id}.n_lit", f"{dev_id}.first_lit", f"{dev_id}.brightness"]
        elif dev.kind == "slm":
            names.append(f"{dev_id}.pattern_id")
        elif dev.kind == "dmd":
            names += [f"{dev_id}.exposure_s", f"{dev_id}.period_s", f"{dev_id}.running"]
    return names


class Runner:
    """Runs plans on a bench (see the module docstring).

    Parameters
    ----------
    bench : Bench
        The open bench (a :class:`~instrument.devices.virtual_bench.VirtualBench` in tests).
    on_event : callable, optional
        ``on_event(RunEvent)``; exceptions it raises abort the run.
    control : RunControl, optional
    reconnect_timeout_s : float
        How long (bench time) to keep trying to reconnect a disconnected device.
    reconnect_interval_s : float
        Wait between reconnect attempts.
    max_point_retries : int
        Times a point is redone after device timeouts before the run fails.
    frame_timeout_s : float
        Timeout of each camera snap, s.

    Attributes
    ----------
    created : RunStore or None
        The store the last :meth:`run` created (None before, or when it created
        none): its ``creation_token`` lets the caller remove that run, and only it,
        when it failed (:func:`instrument.runs.run_paths.discard_partial_run`).
    """

    created: RunStore | None = None

    def __init__(self, bench: Bench, *, on_event: Callable[[RunEvent], None] | None = None,
                 control: RunControl | None = None, reconnect_timeout_s: float = 30.0,
                 reconnect_interval_s: float = 1.0, max_point_retries: int = 2,
                 frame_timeout_s: float = 10.0) -> None:
        self.bench = bench
        self.on_event = on_event
        self.control = control or RunControl()
        self.reconnect_timeout_s = float(reconnect_timeout_s)
        self.reconnect_interval_s = float(reconnect_interval_s)
        self.max_point_retries = int(max_point_retries)
        self.frame_timeout_s = float(frame_timeout_s)
        self._store: RunStore | None = None
        self._t0 = 0.0
        self._session_frames = 0
        self._frames_done = 0

    # ------------------------------------------------------------------ public
    def run(self, plan: Plan, path: str | Path, *, note: str = "",
            overwrite: bool = False) -> RunResult:
        """Run ``plan`` from the start into a new store at ``path``.

        Raises
        ------
        PlanError
            A malformed plan (nothing captured), or a stage target outside the
            stage's limits (:meth:`preflight`; nothing moved, no store created).
        RunStoreError
            ``path`` exists and ``overwrite`` is False.
        """
        self.created = None
        points = plan.points()
        if not points:
            raise PlanError(f"plan {plan.name!r} has no points; check its parameters")
        self.preflight(plan, points, range(len(points)))
        cam = self.bench.camera
        config = self._config_dump()
        names = coord_names(self.bench)
        store = RunStore.create(
            path, plan_name=plan.name, plan_params=plan.params,
            points=[dict(p.coords) for p in points], frame_tags=[p.tags for p in points],
            frame_shape=cam.image_shape, frame_dtype=cam.dtype,
            coord_names=names, coord_specs=coord_specs(names, self.bench.devices),
            bench_config=config,
            device_settings=self.bench.settings_snapshot(), note=note, overwrite=overwrite)
        self.created = store
        store.lock()
        try:
            store.update_attrs(camera={"id": cam.device_id, "bit_depth": cam.bit_depth,
                                       "full_scale_dn": 2 ** int(cam.bit_depth) - 1,
                                       "pixel_pitch_um": cam.pixel_pitch_um},
                               bench_changes=[])
            return self._execute(plan, store, points, start=0)
        finally:
            store.unlock()

    def resume(self, path: str | Path, plan: Plan | None = None, *,
               redo: Sequence[int] = (), accept_differences: bool = False) -> RunResult:
        """Continue the run stored at ``path`` with its first incomplete point.

        ``plan`` defaults to the one the store recorded (rebuilt by name, see
        :func:`instrument.acquisition.plan.plan_from_record`). ``redo``: plan points whose frames
        are marked not done first, so they are captured again (e.g. a point with a
        damaged frame); points after the first incomplete one that are still
        complete are not captured again.

        Before anything moves, the bench, camera and software are compared with
        what the store recorded (:func:`instrument.runs.run_identity.resume_differences`):
        another device set, geometry, driver parameter or frame format is refused;
        harmless differences (a serial port, the bench name, the software version)
        are refused too unless ``accept_differences``. Every resume is recorded in
        the store (``resumes``: time, first point, bench config, software version,
        accepted differences).

        Raises
        ------
        RunStoreError
            No run at ``path``, a video recording (never continued: its frames are used
            as they are, :func:`instrument.runs.runstore_records.video_cannot_continue`), a
            plan whose name/parameters/points differ from the stored ones, a ``redo``
            point the run does not have, a set-up that differs from the recorded one
            (the differences listed), a damaged frame in a point not in ``redo`` (every
            stored frame is verified first), or another process holds the run's lock.
        """
        store = RunStore.open(path, mode="r+")
        why = video_cannot_continue(store)
        if why is not None:
            raise RunStoreError(why)
        store.lock()
        try:
            return self._resume(store, plan, redo, accept_differences)
        finally:
            store.unlock()

    def preflight(self, plan: Plan, points: Sequence, indices: Sequence[int]) -> None:
        """Check ``points[indices]`` against the bench before the first move
        (:func:`instrument.acquisition.preflight.preflight`).

        Raises
        ------
        PlanError
            A step a device would refuse, naming its point.
        """
        preflight(self.bench, plan, points, indices)

    def _check_identity(self, store: RunStore, accept: bool) -> list[Difference]:
        """The differences a resume may accept; RunStoreError for the others."""
        cam = self.bench.camera
        diffs = resume_differences(
            store.attrs, stored_frame=(store.frame_shape, store.frame_dtype.name),
            bench_config=self._config_dump(), frame=(cam.image_shape, np.dtype(cam.dtype).name),
            software_version=software_version())
        fatal = [d for d in diffs if d.severity == "fatal"]
        if fatal:
            raise RunStoreError(
                f"{store.path} was recorded on another set-up and cannot be resumed on this "
                f"one ({format_differences(fatal)}); resume it with the bench file it "
                "recorded (`diffuserlab runs show` prints it) or start a new run")
        if diffs and not accept:
            raise RunStoreError(
                f"{store.path}: the set-up differs from the recorded one in harmless ways "
                f"({format_differences(diffs)}); check them and pass --accept-differences "
                "(API: accept_differences=True) to resume")
        return diffs

    def _config_dump(self) -> dict[str, Any]:
        config = self.bench.config
        return config.model_dump(mode="json") if config is not None else {}

    def _resume(self, store: RunStore, plan: Plan | None, redo: Sequence[int],
                accept: bool) -> RunResult:
        path = store.path
        for point in redo:
            store.frame_range(int(point))  # RunStoreError for a point the run lacks
        rec = store.attrs["plan"]
        if plan is None:
            plan = plan_from_record(rec["name"], rec["params"])
        points = plan.points()
        same = (plan.name == rec["name"] and jsonable(plan.params) == rec["params"]
                and jsonable([dict(p.coords) for p in points]) == rec["points"]
                and [len(p.tags) for p in points] == rec["frames_per_point"])
        if not same:
            raise RunStoreError(f"{path} was recorded by plan {rec['name']!r} with other "
                                "parameters or points; resume it with the plan it recorded "
                                "(pass plan=None)")
        accepted = self._check_identity(store, accept)
        damaged = [e for e in store.damaged_frames() if e.point not in set(map(int, redo))]
        if damaged:
            bad = ",".join(str(p) for p in sorted({e.point for e in damaged}))
            raise RunStoreError(
                f"{path}: {len(damaged)} damaged frame(s) (frame {damaged[0].index}: "
                f"{damaged[0].reason}); capture their points again: diffuserlab calibrate "
                f"resume {path} BENCH.toml --redo {bad}")
        complete = store.points_done()
        complete[[int(p) for p in redo]] = False
        start = int(np.argmin(complete)) if not complete.all() else len(points)
        if start == len(points):
            log.info("%s: every point is stored; recomputing its products", path)
        skip = {i for i in range(start + 1, len(points)) if complete[i]} if redo else set()
        self.preflight(plan, points, [i for i in range(start, len(points)) if i not in skip])
        for point in redo:
            store.clear_point(int(point))
        store.update_attrs(resumes=[*store.attrs.get("resumes", []), {
            "utc": utc_now(), "point": start, "software_version": software_version(),
            "bench_config": self._config_dump(),
            "accepted_differences": [str(d) for d in accepted]}])
        if 0 < start < len(points):
            self._restore_camera(store, start)
        return self._execute(plan, store, points, start=start, skip=skip)

    # ------------------------------------------------------------------ execution
    def _execute(self, plan: Plan, store: RunStore, points, start: int,
                 skip: set[int] = frozenset()) -> RunResult:
        self._store = store
        self._t0 = time.monotonic()
        self._session_frames = 0
        self._frames_done = int(store.done().sum())
        # the operator changes (RESTORES) made and not put back; a store of an older
        # version does not know them: its teardown then runs whole
        self._changes_known = "bench_changes" in store.attrs
        self._changes = list(store.attrs.get("bench_changes") or [])
        store.update_attrs(status="running", error=None,
                           started_utc=store.attrs.get("started_utc") or utc_now())
        self._emit("started", None, f"{plan.name}: point {start + 1} of {len(points)}")
        status, error, summary = "complete", None, {}
        try:
            with plan.session(self.bench):
                for step in plan.setup():
                    self._do_step(step, None)
                for index in range(start, len(points)):
                    if index in skip:
                        continue
                    self._run_point(plan, store, index, points[index])
                    self._emit("point_done", index)
                for step in plan.teardown():
                    if self._needed(step):
                        self._do_step(step, None)
            summary = plan.reduce(store) or {}
        except (RunAborted, KeyboardInterrupt) as exc:
            status = "aborted"
            error = str(exc) or "interrupted (Ctrl-C)"
        except (DeviceError, CheckFailed, PromptRefused, PlanError, RunStoreError) as exc:
            status, error = "failed", f"{type(exc).__name__}: {exc}"
        except Exception as exc:  # a bug or a callback's error: record it, then re-raise
            # (the finally below makes the bench safe)
            store.update_attrs(status="failed", error=f"{type(exc).__name__}: {exc}",
                               ended_utc=utc_now())
            raise
        finally:
            pending = self._put_back(plan)
            problems = self.bench.safe_state()
            if problems:
                store.add_warning(f"could not make safe: {problems}")
        store.update_attrs(status=status, error=error, ended_utc=utc_now(),
                           summary=summary)
        self._emit({"complete": "completed"}.get(status, status), None, error or "")
        done = int(store.points_done().sum())
        result = RunResult(status, store.path, done, len(points), error, summary, pending)
        if status != "complete":  # the point numbered as the window numbers it (from 1)
            where = (f"at point {done + 1} of {len(points)}" if done < len(points)
                     else f"after all {len(points)} points")
            log.warning("run %s %s %s: %s; %s", store.path, status, where, error,
                        result.resume_hint)
        return result

    def _needed(self, step) -> bool:
        """Whether a teardown step is needed: a :class:`~instrument.acquisition.plan.Prompt` that
        puts back a change (:data:`~instrument.acquisition.plan.RESTORES`) this run did not leave
        outstanding is not (unless the store does not know its changes)."""
        if not isinstance(step, Prompt) or not self._changes_known:
            return True
        undoes = [c for c, (back, _) in RESTORES.items() if back == step.action]
        return not undoes or any(c in self._changes for c in undoes)

    def _carried_out(self, action: str) -> None:
        """Note operator ``action`` done: a change of :data:`~instrument.acquisition.plan.RESTORES`
        outstanding, or one put back; kept in the store (``bench_changes``)."""
        changes = [c for c in self._changes if RESTORES[c][0] != action]
        if action in RESTORES and action not in changes:
            changes.append(action)
        if changes != self._changes:
            self._changes = changes
            self._store.update_attrs(bench_changes=changes)

    def _put_back(self, plan: Plan) -> list[str]:
        """Put back every change still outstanding, newest first, in the words of the
        plan's teardown where it has them (on every exit path: done, failed,
        aborted); returns the words of those that could not be (the operator's to do
        unless the run is resumed)."""
        try:
            words = {s.action: s.message for s in plan.teardown() if isinstance(s, Prompt)}
        except Exception:  # noqa: BLE001 (a broken teardown: the defaults say it)
            log.exception("%s: its teardown could not be read", plan.name)
            words = {}
        pending = []
        for change in reversed(list(self._changes)):
            back, default = RESTORES[change]
            message = words.get(back, default)
            try:
                self.bench.prompt(back, message)
            except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001 (said; left to do)
                log.warning("%s: could not %s (%s); the operator must", plan.name,
                            message.lower(), exc)
                pending.append(message)
                continue
            self._carried_out(back)
            self._emit("step", None, message, step="prompt")
        return pending

    def _run_point(self, plan: Plan, store: RunStore, index: int, point) -> None:
        retries = 0
        deadline = None
        frames = store.frame_range(index)
        while True:
            self.bench.on_point((index,))
            self._frames_done -= int(store.done(frames).sum())
            store.clear_point(index)
            try:
                written = 0
                for step in plan.steps(index, point):
                    written = self._do_step(step, index, written)
                if written != len(point.tags):
                    raise PlanError(f"point {index} captured {written} frames but declared "
                                    f"{len(point.tags)}; fix the plan {plan.name!r}")
                return
            except DeviceDisconnectedError as exc:
                deadline = deadline or self.bench.now_s() + self.reconnect_timeout_s
                self._reconnect(exc, index, deadline)
            except DeviceTimeoutError as exc:
                retries += 1
                if retries > self.max_point_retries:
                    raise
                self._emit("retrying", index, f"{exc}; redoing point {index} "
                           f"(retry {retries} of {self.max_point_retries})")

    def _reconnect(self, exc: DeviceError, index: int, deadline: float) -> None:
        dev = self.bench.devices.get(exc.device_id)
        if dev is None:
            raise exc
        self._emit("reconnecting", index, f"{exc.device_id} disconnected: {exc.problem}; "
                   f"reconnecting for up to {self.reconnect_timeout_s:g} s")
        attempts = 0
        while True:
            self.control.wait_while_paused()
            attempts += 1
            try:
                dev.reconnect()
            except (DeviceDisconnectedError, DeviceTimeoutError) as again:
                if self.bench.now_s() + self.reconnect_interval_s > deadline:
                    raise DeviceDisconnectedError(
                        exc.device_id, f"still disconnected after {attempts} reconnect "
                        f"attempts ({again.problem})",
                        "check cable and power, then resume the run") from again
                self.bench.sleep(self.reconnect_interval_s)
                continue
            self._emit("reconnected", index, f"{exc.device_id} back after {attempts} "
                       f"attempt(s); redoing point {index}")
            return

    def _do_step(self, step, index: int | None, written: int = 0) -> int:
        self._checkpoint(index)
        name = type(step).__name__.lower()
        bench = self.bench
        if isinstance(step, Move):
            stage = bench.device(step.stage)
            stage.move_to(dict(step.targets), timeout_s=step.timeout_s)
            settle = step.settle_s
            if settle is None:
                settle = bench.config.calibration.settle_s if bench.config else 0.0
            bench.sleep(settle)
        elif isinstance(step, Light):
            leds = bench.device(step.device)
            if isinstance(step.leds, str):
                if step.leds != "all":
                    raise PlanError(f"Light(leds={step.leds!r}): use a list of indices or 'all'")
                leds.set_leds(np.arange(leds.n_leds), step.colour, step.brightness)
            elif len(step.leds) == 0 or step.brightness == 0:
                leds.all_off()
            else:
                leds.set_leds(list(step.leds), step.colour, step.brightness)
        elif isinstance(step, ShowSlm):
            slm = bench.device(step.device)
            if step.gray is not None:
                slm.show_image(step.gray, timeout_s=step.timeout_s)
            else:
                slm.show_phase(step.phase_rad, timeout_s=step.timeout_s)
        elif isinstance(step, Expose):
            self._expose(step, index)
        elif isinstance(step, Capture):
            written = self._capture(step, index, written)
        elif isinstance(step, Check):
            step.func(bench, self._store, index)
        elif isinstance(step, Prompt):
            bench.prompt(step.action, step.message)
            self._carried_out(step.action)
        else:
            raise PlanError(f"unknown step {step!r}")
        self._emit("step", index, getattr(step, "label", ""), step=name)
        return written

    def _expose(self, step: Expose, index: int | None) -> None:
        cam = self.bench.camera
        if step.exposure_s is not None:
            cam.exposure_s = step.exposure_s
        if step.auto is None:
            return
        a = step.auto
        bounds = a.bounds_s or (self.bench.config.calibration.exposure_bounds_s
                                if self.bench.config else (1e-5, 1.0))
        try:
            autoexpose(cam, target=a.target, tolerance=a.tolerance, bounds_s=tuple(bounds),
                       dark_level=a.dark_level_dn, timeout_s=self.frame_timeout_s)
        except ExposureError as exc:
            if a.required:
                raise
            text = f"point {index}: {exc.problem}; kept exposure {cam.exposure_s:.4g} s"
            self._store.add_warning(text)
            log.warning(text)
        if a.headroom != 1.0:
            cam.exposure_s = max(cam.exposure_s * a.headroom, float(bounds[0]))

    def _capture(self, step: Capture, index: int | None, written: int) -> int:
        if index is None:
            raise PlanError("Capture outside a point (setup/teardown cannot capture)")
        store = self._store
        frames = store.frame_range(index)
        cam = self.bench.camera
        for _ in range(step.n):
            if written >= len(frames):
                raise PlanError(f"point {index} captures more than its {len(frames)} frames")
            expected = store.tag_of(frames.start + written)
            if expected != step.tag:
                raise PlanError(f"point {index} frame {written} captured as {step.tag!r} but "
                                f"declared {expected!r}")
            frame = cam.snap(timeout_s=self.frame_timeout_s)
            store.write_frame(frames.start + written, frame.image,
                              frame_coords(self.bench, frame))
            written += 1
            self._frames_done += 1
            self._session_frames += 1
            self._emit("frame", index, step="capture", last_frame=frame.image)
            self._checkpoint(index)
        return written

    def _checkpoint(self, index: int | None) -> None:
        """Between steps: raise RunAborted if asked; block (with events) while paused."""
        if self.control.paused and self.control.abort_reason is None:
            self._emit("paused", index, "paused; resume() to continue, abort() to stop")
            self.control.wait_while_paused()
            self._emit("resumed", index)
        else:
            self.control.wait_while_paused()

    def _restore_camera(self, store: RunStore, start: int) -> None:
        """Exposure and gain as they were after the last complete point."""
        _, coords = store.point_frames(start - 1)
        last = coords[-1]
        cam = self.bench.camera
        cam.apply_settings({"exposure_s": last["exposure_s"], "gain": last["gain"]})

    def _emit(self, kind: str, point: int | None, message: str = "", *,
              step: str | None = None, last_frame: np.ndarray | None = None) -> None:
        if self.on_event is None:
            return
        store = self._store
        total = store.n_frames
        elapsed = time.monotonic() - self._t0
        eta = None
        if self._session_frames:
            eta = elapsed / self._session_frames * max(total - self._frames_done, 0)
        pts = store.attrs["plan"]["frames_per_point"]
        done_pts = int(np.searchsorted(np.cumsum(pts), self._frames_done, side="right"))
        self.on_event(RunEvent(kind, str(store.path), point, self._frames_done, total,
                               done_pts, len(pts), elapsed, eta, message, step, last_frame))

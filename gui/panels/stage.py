"""A stage's controls: jog, go-to, stop, and named positions recalled with one click.

Every move goes through the stage's :class:`MotionQueue`, which asks the bench's
service to move the stage by its id (:meth:`instrument.bench.bench_service.BenchService.move`):
one worker moves the stage at a time, in the order asked. Jogs add to the *target* of
the jogs before them, not to wherever the stage happens to be while it moves: three
quick +1 mm clicks end 3 mm from where the first started. Stop empties the queue and
stops the stage at once (on its own worker, not behind the move). Stored positions
belong to the bench file (:func:`gui.fields.bench_key`) and survive the session.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from PySide6.QtCore import QObject, Qt, Signal
from PySide6.QtWidgets import (
    QDoubleSpinBox,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QMenu,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from ..device_settings import parse_value
from ..fields import load_json, store_json, wheel_needs_focus
from ..workers import DEVICE_NICE, InputError, Job

__all__ = ["JogButton", "MotionQueue", "StageControls"]


class MotionQueue(QObject):
    """Moves of one stage, made one at a time on a worker, jogs adding to their target.

    Parameters
    ----------
    service : instrument.bench.bench_process.BenchClient
        The bench's typed service.
    stage : str
        The stage's device id.

    Signals
    -------
    failed(str)
        A move was refused or failed (the queue is emptied).
    idle()
        The queue ran empty.
    """

    failed = Signal(str)
    idle = Signal()

    def __init__(self, service, stage: str) -> None:
        super().__init__()
        self.service, self.stage = service, stage
        self._lock = threading.Lock()
        self._ops: list[tuple[str, dict[str, float]]] = []
        self._goal: dict[str, float] | None = None
        self._active = False
        self.job: Job | None = None

    @property
    def busy(self) -> bool:
        """True while a move is queued or under way."""
        with self._lock:
            return bool(self._ops) or self._active

    def jog(self, deltas: dict[str, float]) -> Job:
        """Queue a relative move; consecutive jogs merge (their deltas add up)."""
        with self._lock:
            if self._ops and self._ops[-1][0] == "by":
                last = self._ops[-1][1]
                for axis, d in deltas.items():
                    last[axis] = last.get(axis, 0.0) + float(d)
            else:
                self._ops.append(("by", {a: float(d) for a, d in deltas.items()}))
        return self._ensure_worker()

    def move_to(self, targets: dict[str, float]) -> Job:
        """Queue an absolute move (after the moves queued before it)."""
        with self._lock:
            self._ops.append(("to", {a: float(v) for a, v in targets.items()}))
        return self._ensure_worker()

    def stop(self) -> Job:
        """Empty the queue and stop the stage now (on a worker of its own)."""
        with self._lock:
            self._ops.clear()
            self._goal = None
        job = Job(lambda job: self.service.stop_motion(self.stage), name=f"stop-{self.stage}",
                  nice=DEVICE_NICE)
        job.failed.connect(self.failed)
        return job.start()

    def _ensure_worker(self) -> Job:
        with self._lock:  # the worker leaves under this lock once the queue is empty
            if self._active:
                return self.job
            self._active = True
        self.job = Job(self._run, name=f"motion-{self.stage}", nice=DEVICE_NICE)
        self.job.failed.connect(self.failed)
        self.job.finished.connect(self.idle)
        return self.job.start()

    def _run(self, job: Job) -> None:
        try:
            while True:
                with self._lock:
                    if not self._ops:
                        self._goal = None
                        self._active = False
                        return
                    kind, values = self._ops.pop(0)
                    goal = self._goal
                if goal is None:
                    goal = self.service.positions(self.stage)
                if kind == "by":
                    targets = {a: goal[a] + d for a, d in values.items()}
                else:
                    targets = dict(values)
                self.service.move(self.stage, targets)
                with self._lock:
                    self._goal = {**goal, **targets}
        except BaseException:
            with self._lock:
                self._ops.clear()
                self._goal = None
                self._active = False
            raise


class JogButton(QPushButton):
    """A jog button: a quick second click is a second click (Qt's double click would
    swallow it: three quick clicks jogged twice)."""

    def mouseDoubleClickEvent(self, event) -> None:  # noqa: N802 (Qt's name)
        self.mousePressEvent(event)


class StageControls(QWidget):
    """Jog (step per axis, -/+), go-to (Enter or Go), Stop, stored positions.

    Parameters
    ----------
    stage : instrument.bench.bench_service.DeviceInfo
        An open stage (its axes, their units and travel).
    queue : MotionQueue
    bench_key : str
        Settings group of the bench (stored positions belong to it).
    on_error : callable
        ``on_error(text)`` shows a refusal.
    """

    def __init__(self, stage, queue: MotionQueue, bench_key: str,
                 on_error: Callable[[str], None], parent=None) -> None:
        super().__init__(parent)
        self.stage, self.queue, self.on_error = stage, queue, on_error
        self.key = f"{bench_key}/positions/{stage.name}"
        dev_id = stage.name
        outer = QVBoxLayout(self)
        outer.setContentsMargins(0, 0, 0, 0)
        grid = QGridLayout()
        for col, head in enumerate(("axis", "position", "jog step", "", "", "go to", "")):
            if head:
                grid.addWidget(QLabel(f"<b>{head}</b>"), 0, col)
        self.positions: dict[str, QLabel] = {}
        self.jog_steps: dict[str, QDoubleSpinBox] = {}
        self.targets: dict[str, QLineEdit] = {}
        travel = stage.travel
        for row, axis in enumerate(stage.axes, start=1):
            unit = stage.units[axis]
            grid.addWidget(QLabel(f"{axis} ({unit})"), row, 0)
            self.positions[axis] = QLabel("-")
            self.positions[axis].setObjectName(f"{dev_id}.position.{axis}")
            grid.addWidget(self.positions[axis], row, 1)
            step = QDoubleSpinBox()
            step.setObjectName(f"{dev_id}.step.{axis}")
            step.setMaximumWidth(120)
            step.setDecimals(4)
            lo, hi = (float(v) for v in travel[axis])
            span = hi - lo if hi - lo < 1e6 else 360.0
            step.setRange(0.0001, span)
            step.setValue(1.0 if unit == "mm" else 0.1)
            step.setSuffix(f" {unit}")
            wheel_needs_focus(step)
            self.jog_steps[axis] = step
            grid.addWidget(step, row, 2)
            for col, sign in ((3, -1), (4, +1)):
                b = JogButton("-" if sign < 0 else "+")
                b.setFixedWidth(34)
                b.setObjectName(f"{dev_id}.jog.{axis}{'-+'[sign > 0]}")
                b.setToolTip(f"move {axis} by {'-' if sign < 0 else '+'}one step (clicks add "
                             "up: each adds a step to the target)")
                b.clicked.connect(lambda _=False, a=axis, s=sign: self.jog(a, s))
                grid.addWidget(b, row, col)
            target = QLineEdit()
            target.setMaximumWidth(90)
            target.setPlaceholderText(unit)
            target.setObjectName(f"{dev_id}.goto.{axis}")
            target.returnPressed.connect(lambda a=axis: self.go_to(a))
            self.targets[axis] = target
            grid.addWidget(target, row, 5)
            go = QPushButton("Go")
            go.setFixedWidth(40)
            go.setObjectName(f"{dev_id}.go.{axis}")
            go.clicked.connect(lambda _=False, a=axis: self.go_to(a))
            grid.addWidget(go, row, 6)
        outer.addLayout(grid)
        row = QHBoxLayout()
        stop = QPushButton("Stop")
        stop.setObjectName(f"{dev_id}.stop")
        stop.setStyleSheet("font-weight: bold;")
        stop.clicked.connect(self.stop)
        row.addWidget(stop)
        row.addSpacing(12)
        row.addWidget(QLabel("stored positions:"))
        self.position_name = QLineEdit()
        self.position_name.setPlaceholderText("name")
        self.position_name.setObjectName(f"{dev_id}.position-name")
        self.position_name.returnPressed.connect(self.store_position)
        row.addWidget(self.position_name, 1)
        store = QPushButton("Store here")
        store.setObjectName(f"{dev_id}.store-position")
        store.clicked.connect(self.store_position)
        row.addWidget(store)
        outer.addLayout(row)
        self.stored_row = QHBoxLayout()
        self.stored_box = QWidget()
        self.stored_box.setLayout(self.stored_row)
        self.stored_row.setContentsMargins(0, 0, 0, 0)
        outer.addWidget(self.stored_box)
        self.stored_buttons: dict[str, QPushButton] = {}
        self.jobs: list[Job] = []
        self._show_stored()

    # -- motion ----------------------------------------------------------------------------
    def jog(self, axis: str, sign: int) -> Job:
        """Add one jog step of ``axis`` in direction ``sign`` to the queue's target."""
        return self.queue.jog({axis: sign * self.jog_steps[axis].value()})

    def go_to(self, axis: str) -> Job | None:
        """Move ``axis`` to its go-to field's value (the stage checks its limits)."""
        text = self.targets[axis].text().strip()
        value = parse_value(text)
        if not isinstance(value, int | float) or isinstance(value, bool):
            self.on_error(f"go to {axis}: {text!r} is not a number; type the position in "
                          f"{self.stage.units[axis]}")
            return None
        return self.queue.move_to({axis: float(value)})

    def stop(self) -> Job:
        """Stop all motion of this stage now (queued moves are dropped)."""
        return self.queue.stop()

    def show_positions(self, positions: dict[str, float]) -> None:
        for axis, label in self.positions.items():
            if axis in positions:
                label.setText(f"{positions[axis]:.4f}")

    # -- stored positions ------------------------------------------------------------------
    def stored(self) -> dict[str, dict[str, float]]:
        """``{name: {axis: position}}`` stored for this stage on this bench."""
        return load_json(self.key, {})

    def store_position(self, name: str | None = None) -> Job | None:
        """Store the stage's current position under ``name`` (the name field's text)."""
        name = (name if isinstance(name, str) else self.position_name.text()).strip()
        if not name:
            self.on_error("type a name for the position, then press Store here")
            return None
        job = Job(lambda job: self.queue.service.positions(self.stage.name),
                  name="read-position", owner=self,
                  nice=DEVICE_NICE)
        job.succeeded.connect(lambda pos: self._stored(name, pos))
        job.failed.connect(self.on_error)
        self.jobs = [j for j in self.jobs if j.running] + [job]
        return job.start()

    def _stored(self, name: str, positions: dict[str, float]) -> None:
        stored = self.stored()
        stored[name] = {a: float(v) for a, v in positions.items()}
        store_json(self.key, stored)
        self.position_name.clear()
        self._show_stored()

    def recall(self, name: str) -> Job:
        """Move to the stored position ``name``.

        Raises
        ------
        gui.workers.InputError
            No position of that name.
        """
        stored = self.stored()
        if name not in stored:
            raise InputError(f"no stored position named {name!r}")
        return self.queue.move_to(stored[name])

    def forget(self, name: str) -> None:
        stored = self.stored()
        stored.pop(name, None)
        store_json(self.key, stored)
        self._show_stored()

    def _show_stored(self) -> None:
        while self.stored_row.count():
            item = self.stored_row.takeAt(0)
            if item.widget() is not None:
                item.widget().setParent(None)
                item.widget().deleteLater()
        self.stored_buttons = {}
        for name, pos in self.stored().items():
            b = QPushButton(name)
            b.setObjectName(f"{self.stage.name}.recall.{name}")
            b.setToolTip("go to " + ", ".join(f"{a} {v:.4g}" for a, v in pos.items())
                         + " (right click: forget)")
            b.clicked.connect(lambda _=False, n=name: self.recall(n))
            menu = QMenu(b)
            menu.addAction("Forget this position", lambda n=name: self.forget(n))
            b.setContextMenuPolicy(Qt.ContextMenuPolicy.CustomContextMenu)
            b.customContextMenuRequested.connect(lambda p, m=menu, w=b: m.popup(w.mapToGlobal(p)))
            self.stored_row.addWidget(b)
            self.stored_buttons[name] = b
        self.stored_row.addStretch(1)


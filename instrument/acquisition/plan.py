"""Plans: what a calibration or acquisition does, as points made of steps.

A plan declares all of its points up front (:meth:`Plan.points`: a JSON-able
description and the tags of the frames each point captures), then yields, per
point, a generator of steps (:meth:`Plan.steps`). The runner
(:mod:`instrument.acquisition.runner`) executes the steps, stores each captured frame, and can
resume a run at the first point the store does not hold completely; a point is the
unit of resumption, so a point's steps must bring the bench into the state they
need from any starting state (move, light, expose before capturing).

Steps
-----
:class:`Move`, :class:`Light`, :class:`ShowSlm`, :class:`Expose`, :class:`Capture`,
:class:`Check` and :class:`Prompt` (an operator action such as removing the diffuser).

A plan may also hold a context open around its whole execution
(:meth:`Plan.session`, e.g. the holography mask retracted and put back whatever
happens), entered on every run and resume.

Plans register by name (:func:`register_plan`) so a stored run can rebuild its
plan from the name and parameters it recorded (:func:`plan_from_record`).
"""

from __future__ import annotations

import abc
import contextlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from diffuserlab.errors import DiffuserLabError, InputError

__all__ = [
    "PLAN_TYPES", "RESTORES", "AutoExposure", "Capture", "Check", "CheckFailed", "Expose",
    "Light", "Move", "Plan", "PlanError", "PlanPoint", "Prompt", "ShowSlm", "Step",
    "plan_from_record", "register_plan",
]


class PlanError(InputError):
    """A plan is malformed or its parameters are invalid (the message names the fix)."""


class CheckFailed(DiffuserLabError, RuntimeError):
    """A :class:`Check` step found the bench unfit to continue; ``fix`` says what to do."""

    def __init__(self, problem: str, fix: str) -> None:
        super().__init__(f"{problem}; {fix}")
        self.problem, self.fix = problem, fix


@dataclass(frozen=True)
class Move:
    """Move a stage (``stage``: device id or role) to absolute ``targets`` {axis: value}
    and wait for it, then wait ``settle_s`` (None: the bench config's default)."""

    stage: str
    targets: Mapping[str, float]
    settle_s: float | None = None
    timeout_s: float = 60.0


@dataclass(frozen=True)
class Light:
    """Set the LED array: ``leds`` = indices to light (empty: all off; ``"all"``: every
    LED), at ``brightness`` in ``colour``."""

    leds: Sequence[int] | str = ()
    brightness: float = 1.0
    colour: str = "white"
    device: str = "led_array"


@dataclass(frozen=True)
class AutoExposure:
    """Auto-exposure target: the peak (99.99th percentile minus ``dark_level_dn``) in
    ``[target - tolerance, target + tolerance]`` of full scale with no saturated
    pixel; ``bounds_s`` the allowed exposures. ``required=False`` accepts the bound
    (with a warning in the run) when the target is out of reach. ``headroom`` (in
    (0, 1]) then scales the exposure reached (not below the lower bound): a spot
    covering fewer pixels than the percentile's 1e-4 of the frame ends just below
    saturation (the longest unsaturated exposure), and e.g. 0.5 keeps its noise and
    any sensor non-linearity away from full scale."""

    target: float = 0.6
    tolerance: float = 0.2
    bounds_s: tuple[float, float] | None = None
    dark_level_dn: float = 0.0
    required: bool = False
    headroom: float = 1.0

    def __post_init__(self) -> None:
        if not 0 < self.headroom <= 1:
            raise PlanError(f"AutoExposure(headroom={self.headroom!r}): use a factor in (0, 1]")


@dataclass(frozen=True)
class Expose:
    """Set the camera exposure: a fixed ``exposure_s``, or ``auto``; neither keeps the
    current one."""

    exposure_s: float | None = None
    auto: AutoExposure | None = None


@dataclass(frozen=True)
class Capture:
    """Snap ``n`` frames and store each with tag ``tag``."""

    n: int
    tag: str


@dataclass(frozen=True)
class Check:
    """Call ``func(bench, store, point)``; it raises :class:`CheckFailed` to stop the run."""

    name: str
    func: Callable[..., None] = field(compare=False)


@dataclass(frozen=True)
class ShowSlm:
    """Display an SLM pattern and wait for the panel (the SLM's settle time included).

    Exactly one of ``gray`` (uint8 ``(rows, cols)``, shown as is) or ``phase_rad``
    (float ``(rows, cols)``, radians, converted by the SLM's LUT inverse) is given.
    ``label`` names the pattern in the run's events; every frame records the SLM's
    pattern id (``<slm id>.pattern_id``). ``device``: SLM id or role; ``timeout_s``:
    longest wait for the panel update, s.
    """

    gray: np.ndarray | None = field(default=None, compare=False, repr=False)
    phase_rad: np.ndarray | None = field(default=None, compare=False, repr=False)
    label: str = ""
    device: str = "slm"
    timeout_s: float = 5.0

    def __post_init__(self) -> None:
        if (self.gray is None) == (self.phase_rad is None):
            raise PlanError(f"ShowSlm({self.label!r}): give exactly one of gray (uint8 image) "
                            "or phase_rad (radians)")
        if not self.timeout_s > 0:
            raise PlanError(f"ShowSlm({self.label!r}): timeout_s must be > 0 s")


@dataclass(frozen=True)
class Prompt:
    """An operator action (``action`` key, human ``message``), e.g. remove the diffuser."""

    action: str
    message: str


Step = Move | Light | ShowSlm | Expose | Capture | Check | Prompt

#: The operator actions that take the bench out of its working state, each with the
#: action that puts it back (and the words the runner asks with when the plan's
#: teardown does not say it). The runner records each one a run carried out and not
#: yet put back (the store's ``bench_changes``), and puts it back on every exit path:
#: done, failed, aborted (:meth:`Plan.teardown`).
RESTORES: dict[str, tuple[str, str]] = {
    "cap_camera": ("uncap_camera", "Uncap the camera"),
    "remove_diffuser": ("install_diffuser", "Install the diffuser and its aperture again"),
    "remove_pinhole": ("install_pinhole", "Install the pinhole again"),
    "insert_nd_filter": ("remove_nd_filter", "Remove the ND filter"),
}


@dataclass(frozen=True)
class PlanPoint:
    """One point of a plan: JSON-able ``coords`` and the ``tags`` of its frames."""

    coords: Mapping[str, Any]
    tags: tuple[str, ...]


#: Registered plan classes by name.
PLAN_TYPES: dict[str, type[Plan]] = {}


def register_plan(cls: type[Plan]) -> type[Plan]:
    """Class decorator: make ``cls`` rebuildable from a stored run by its ``name``."""
    if not getattr(cls, "name", None):
        raise PlanError(f"{cls.__name__} needs a class attribute `name`")
    PLAN_TYPES[cls.name] = cls
    return cls


def plan_from_record(name: str, params: Mapping[str, Any]) -> Plan:
    """Rebuild a plan from the name and parameters a run store recorded.

    Raises
    ------
    PlanError
        No plan of that name is registered (import the package defining it, e.g.
        ``calibration_routines``).
    """
    if name not in PLAN_TYPES:
        raise PlanError(f"no plan named {name!r} is registered ({sorted(PLAN_TYPES)}); "
                        "import the package that defines it (e.g. calibration_routines)")
    return PLAN_TYPES[name].from_params(params)


class Plan(abc.ABC):
    """A plan: points declared up front, steps per point, products at the end.

    Subclasses set ``name``, implement :meth:`points` and :meth:`steps`, and may
    override :meth:`setup` / :meth:`teardown` (steps before the first and after the
    last point, run again on resume) and :meth:`reduce` (products from the stored
    frames). ``params`` must be JSON-able and rebuild the plan through
    :meth:`from_params`.
    """

    name: ClassVar[str] = ""

    def __init__(self, **params: Any) -> None:
        self.params = dict(params)

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Plan:
        """Rebuild from stored parameters (default: ``cls(**params)``)."""
        return cls(**dict(params))

    @abc.abstractmethod
    def points(self) -> list[PlanPoint]:
        """Every point of the plan, in order."""

    @abc.abstractmethod
    def steps(self, index: int, point: PlanPoint) -> Iterator[Step]:
        """The steps of point ``index``; its :class:`~instrument.acquisition.plan.Capture` steps
        must
        add up to ``point.tags`` in order. The runner's preflight walks this generator
        ahead without executing it (:meth:`~instrument.acquisition.plan.Plan.checked_steps`), so the
        generator itself must have no side effects: act on the bench or the plan's state
        in steps (e.g. a :class:`~instrument.acquisition.plan.Check`)."""

    def setup(self) -> Iterator[Step]:
        """Steps before the first point (also on resume)."""
        return iter(())

    def session(self, bench) -> contextlib.AbstractContextManager:
        """A context the runner holds open around setup, points and teardown, on every
        run and resume, and exits whatever happens (abort, error), before the bench is
        made safe; e.g. take the holography mask out of the beam and put it back.
        Errors on entering or leaving fail the run like a step's. Default: nothing."""
        return contextlib.nullcontext()

    def teardown(self) -> Iterator[Step]:
        """Steps after the last point, and the plan's declaration of how it puts the
        bench back.

        After a complete run every step runs (a :class:`~instrument.acquisition.plan.Prompt`
        that puts back a change of :data:`~instrument.acquisition.plan.RESTORES` the run did not
        make, or made and put back already, is skipped). On every exit path (done,
        failed, aborted) the runner then carries out, newest first, the putting back
        of each change of :data:`~instrument.acquisition.plan.RESTORES` still outstanding, in
        this teardown's words where it has a :class:`~instrument.acquisition.plan.Prompt` of that
        action (a dark run aborted with the camera capped is uncapped); the bench
        then goes to its safe state and the store is kept for resuming."""
        return iter(())

    def checked_steps(self, points: Sequence[PlanPoint], indices: Sequence[int]
                      ) -> Iterator[tuple[int | None, Move | Expose | Light]]:
        """The steps the runner's preflight checks against the devices before the
        first move: every :class:`Move` (stage limits, backlash), fixed
        :class:`Expose` (the camera's exposure range) and :class:`Light` (LED
        indices and brightness), in order.

        Yields ``(point index, step)`` pairs, ``None`` for setup and teardown, for
        the points ``indices`` of ``points``. The default walks :meth:`setup`,
        :meth:`steps` of each point and :meth:`teardown` without executing anything;
        a plan whose steps depend on what earlier steps measured (so its generators
        cannot be walked ahead) overrides this with the steps it can promise.
        """
        kinds = (Move, Expose, Light)
        yield from ((None, s) for s in self.setup() if isinstance(s, kinds))
        for i in indices:
            yield from ((i, s) for s in self.steps(i, points[i]) if isinstance(s, kinds))
        yield from ((None, s) for s in self.teardown() if isinstance(s, kinds))

    def reduce(self, store) -> dict[str, Any]:
        """Derive products from a complete run's frames (write them with
        ``store.write_product``); return a JSON-able summary."""
        return {}

"""An open bench as the plans see it: devices by role, time, safe state, prompts.

:class:`Bench` wraps the opened devices of a bench config (real, simulated or
mixed) and gives the plan runner what it needs beyond the devices themselves:

* devices by id or by role (``camera``, ``source_stage``, ``mask_stage``,
  ``led_array``, ``slm``);
* time: :meth:`Bench.sleep` and :meth:`Bench.now_s` (wall clock here; the virtual
  bench runs them on its simulated clock, so settle times cost nothing in tests);
* :meth:`Bench.safe_state`: LEDs off, stages stopped, streams stopped - every
  device attempted, failures logged, never raised (used on abort and error);
* :meth:`Bench.prompt`: an operator action a plan needs (cap the camera, remove
  the diffuser, ...), handed to a callback (the CLI asks the operator; the
  virtual bench carries it out itself);
* :meth:`Bench.on_point`: a hook called before each plan point (the virtual bench
  reseeds its noise there so simulated runs are reproducible point by point).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from diffuserlab.errors import DiffuserLabError
from diffuserlab.jsonio import jsonable
from drivers.errors import DeviceError

from ..config import BenchConfig
from .bench_setup import OpenBench, open_bench

__all__ = ["ROLES", "Bench", "BenchRoleError", "PromptRefused"]

log = logging.getLogger(__name__)

#: Roles a plan may ask for, and what each means.
ROLES = {
    "camera": "the (single) camera",
    "source_stage": "the stage carrying the point source (has z, no rotation axis)",
    "mask_stage": "the 6-axis stage of the holography mask mount (has a rotation axis)",
    "led_array": "the LED array behind the pinhole",
    "slm": "the SLM of the holography branch",
}


class BenchRoleError(DiffuserLabError, LookupError):
    """The bench has no device for a role (or the name is neither a role nor an id)."""


class PromptRefused(DiffuserLabError, RuntimeError):
    """The operator (or the absence of one) did not carry out a plan's prompt."""


def _role_filter(role: str) -> tuple[str, Callable[[Any], bool] | None]:
    if role == "source_stage":
        return "stage", lambda d: "z" in d.axes and "rotation" not in d.axes
    if role == "mask_stage":
        return "stage", lambda d: "rotation" in d.axes
    return role, None


class Bench:
    """Opened devices of one bench, by id and by role.

    Parameters
    ----------
    devices : Mapping[str, drivers.base.Device]
        ``{device id: open device}``, e.g. what :func:`instrument.devices.bench_setup.open_bench`
        returns.
    config : BenchConfig, optional
        The bench's config (its calibration defaults and geometry are read by plans).
    on_prompt : callable, optional
        ``on_prompt(action, message) -> bool``: ask the operator to carry out
        ``action``; False (or no callback) refuses. See :meth:`prompt`.
    """

    def __init__(self, devices: Mapping[str, Any] | None = None, *,
                 config: BenchConfig | None = None,
                 on_prompt: Callable[[str, str], bool] | None = None) -> None:
        self.devices: Mapping[str, Any] = devices if devices is not None else {}
        self.config = config
        self.on_prompt = on_prompt

    @classmethod
    def open(cls, config: BenchConfig, *, simulate: bool = False,
             timeout_s: float | None = None,
             on_prompt: Callable[[str, str], bool] | None = None,
             cancel: threading.Event | None = None) -> Bench:
        """Open every device of ``config`` (:func:`open_bench`: concurrently where they
        share no connection, within ``timeout_s`` if given, stopped early when
        ``cancel`` is set); close with :meth:`close`."""
        return cls(open_bench(config, simulate=simulate, timeout_s=timeout_s, cancel=cancel),
                   config=config, on_prompt=on_prompt)

    def close(self) -> None:
        """Close every device, last opened first (idempotent)."""
        if isinstance(self.devices, OpenBench):
            self.devices.close()
        self.devices = {}

    def __enter__(self) -> Bench:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- devices ------------------------------------------------------------------------
    def device(self, name: str):
        """The device with id ``name``, or the one filling role ``name`` (:data:`ROLES`).

        Raises
        ------
        BenchRoleError
            No such device id or role, or no device fills the role.
        """
        if not self.devices:
            raise BenchRoleError("the bench is not open; open it first (e.g. `with bench:`)")
        if name in self.devices:
            return self.devices[name]
        if name not in ROLES:
            raise BenchRoleError(
                f"{name!r} is neither a device id ({sorted(self.devices)}) nor a role "
                f"({sorted(ROLES)})")
        kind, want = _role_filter(name)
        found = [d for d in self.devices.values() if d.kind == kind and (want is None or want(d))]
        if not found:
            raise BenchRoleError(f"the bench has no {name} ({ROLES[name]}); add one to the "
                                 "bench config")
        return found[0]

    def has(self, name: str) -> bool:
        """True if :meth:`device` would find ``name``."""
        try:
            self.device(name)
        except BenchRoleError:
            return False
        return True

    @property
    def camera(self):
        """The (single) camera."""
        return self.device("camera")

    @property
    def source_stage(self):
        """The stage carrying the pinhole point source."""
        return self.device("source_stage")

    @property
    def mask_stage(self):
        """The 6-axis stage of the holography mask mount."""
        return self.device("mask_stage")

    @property
    def led_array(self):
        """The LED array behind the pinhole."""
        return self.device("led_array")

    @property
    def slm(self):
        """The SLM of the holography branch."""
        return self.device("slm")

    # -- time ---------------------------------------------------------------------------
    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` (bench time)."""
        if seconds > 0:
            time.sleep(seconds)

    def now_s(self) -> float:
        """Bench time in seconds (monotonic)."""
        return time.monotonic()

    # -- hooks --------------------------------------------------------------------------
    def on_point(self, key: tuple[int, ...]) -> None:  # noqa: B027 (optional hook)
        """Called by the runner before each plan point (``key`` = (point index,))."""

    def prompt(self, action: str, message: str) -> None:
        """Have the operator carry out ``action`` (described by ``message``).

        Raises
        ------
        PromptRefused
            No ``on_prompt`` callback, or it returned False.
        """
        if self.on_prompt is None or not self.on_prompt(action, message):
            raise PromptRefused(
                f"the plan needs the operator to: {message} - run it from the CLI (which "
                "asks) or pass on_prompt=... to the Bench")

    # -- state --------------------------------------------------------------------------
    def safe_state(self) -> dict[str, str]:
        """LEDs off, stages stopped, camera streams stopped.

        Every device is attempted; a failure is logged and returned, never raised
        (this runs while handling another error).

        Returns
        -------
        dict
            ``{device id: problem}`` for the devices that could not be made safe.
        """
        problems: dict[str, str] = {}
        for dev_id, dev in list(self.devices.items()):
            try:
                if not dev.is_open:
                    continue
                if dev.kind == "led_array":
                    dev.all_off()
                elif dev.kind == "stage":
                    dev.stop()
                elif dev.kind == "camera" and dev.is_streaming:
                    dev.stop_stream()
            except (DeviceError, OSError) as exc:
                log.warning("could not make %s safe: %s", dev_id, exc)
                problems[dev_id] = str(exc)
        return problems

    def settings_snapshot(self) -> dict[str, Any]:
        """``{device id: settings()}`` of every open device (an error text if one fails)."""
        out: dict[str, Any] = {}
        for dev_id, dev in self.devices.items():
            try:
                out[dev_id] = {"kind": dev.kind, "driver": type(dev).__name__,
                               "settings": dev.settings()}
            except DeviceError as exc:
                out[dev_id] = {"kind": dev.kind, "driver": type(dev).__name__,
                               "error": str(exc)}
        return jsonable(out)

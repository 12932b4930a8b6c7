"""The open bench's typed service: commands on devices named by id, events pushed.

What a client of the bench process (the operator's window, a notebook, a second
window) may ask of the open bench, as :class:`BenchService` commands whose arguments
and results are plain data: device ids (the bench file's names), settings and
positions as dicts, a :class:`DeviceInfo` per device, a :class:`CameraFormat`. No
device object crosses to the client, as pymmcore-plus's ``CMMCorePlus`` and PyMoDAQ's
module interface keep theirs on the far side of a fixed set of commands.

What changes on the bench is pushed as :class:`BenchEvent` (``status``, ``settings``,
``positions``, ``bench``, ``job``) into an :class:`EventLog`, which every client reads with a
long poll (:meth:`BenchService.events_after` returns as soon as an event is logged):
each command that changes a device logs its new settings or positions at once, and a
watcher thread of the bench process reads every device's status once a second there
(no message to any client) and logs it only when it changed (a stage moved by a job,
a camera disconnected, a setting a job applied).

:class:`instrument.bench.bench_host.BenchHost` is the service (it adds the stream, the
frames and the jobs); :class:`instrument.bench.bench_process.BenchClient` calls it in the
bench process or in its own.
"""

from __future__ import annotations

import dataclasses
import importlib
import logging
import threading
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from diffuserlab.errors import DiffuserLabError

__all__ = ["WATCH_PERIOD_S", "BenchEvent", "BenchGoneError", "BenchService", "BenchServiceError",
           "CameraFormat", "DeviceInfo", "EventLog", "device_info", "same_value"]

log = logging.getLogger(__name__)

#: How often, s, the bench process reads every device's status for changes.
WATCH_PERIOD_S = 1.0


class BenchServiceError(DiffuserLabError, RuntimeError):
    """A command the bench cannot serve: no bench open, an unknown device, a device of
    another kind than the command needs."""


class BenchGoneError(BenchServiceError):
    """The bench process cannot be reached: it ended (killed, crashed, closed) or never
    ran at the address given."""


@dataclasses.dataclass(frozen=True, eq=False)
class DeviceInfo:
    """One device of the open bench, as plain data.

    Attributes
    ----------
    name : str
        Its id in the bench file.
    kind : str
        ``camera``, ``stage``, ``led_array``, ``slm``, ``dmd``, ...
    driver : str
        Its class, ``"module:qualname"`` (:attr:`driver_class` imports it here).
    info : dict
        :attr:`drivers.base.Device.info` (the limits of its settings).
    axes : tuple of str
        A stage's axes (else empty).
    travel : dict
        A stage's ``{axis: (low, high)}`` in the axis's unit.
    units : dict
        A stage's ``{axis: unit}``.
    led_positions_mm : numpy.ndarray or None
        An LED array's ``(n_leds, 2)`` float positions, mm.
    resolution : tuple of int or None
        An SLM's or DMD's ``(rows, cols)``.
    """

    name: str
    kind: str
    driver: str
    info: dict = dataclasses.field(default_factory=dict)
    axes: tuple = ()
    travel: dict = dataclasses.field(default_factory=dict)
    units: dict = dataclasses.field(default_factory=dict)
    led_positions_mm: np.ndarray | None = None
    resolution: tuple | None = None

    @property
    def driver_name(self) -> str:
        """The driver class's name (``SimulatedStage``)."""
        return self.driver.rpartition(":")[2].rpartition(".")[2]

    @property
    def driver_class(self) -> type:
        """The driver class as imported here (its ``SETTINGS`` declarations).

        Raises
        ------
        BenchServiceError
            The class cannot be imported in this process.
        """
        module, _, qualname = self.driver.partition(":")
        try:
            obj: Any = importlib.import_module(module)
            for part in qualname.split("."):
                obj = getattr(obj, part)
        except (ImportError, AttributeError) as exc:
            raise BenchServiceError(f"{self.name}'s driver {self.driver} cannot be imported "
                                    f"here ({exc}); install the same DiffuserLab as the bench "
                                    "process runs") from None
        return obj

    @property
    def settings_declared(self) -> tuple:
        """The driver's :class:`~drivers.settings.Setting` declarations, in order."""
        return tuple(self.driver_class.SETTINGS)


@dataclasses.dataclass(frozen=True)
class CameraFormat:
    """The camera's frames: ``image_shape`` (rows, cols), ``bit_depth`` and, for a
    simulated camera, its ``dark_offset_dn`` (None for a real one)."""

    image_shape: tuple
    bit_depth: int
    dark_offset_dn: float | None = None


@dataclasses.dataclass(frozen=True)
class BenchEvent:
    """A change on the bench.

    Attributes
    ----------
    seq : int
        Its number in the :class:`EventLog` (1, 2, ...).
    kind : str
        ``status`` (``data``: ``{"status": dict, "settings": dict or None, "values":
        dict or None}``, what the device box shows), ``settings`` (``data``: the
        device's :meth:`~drivers.base.Device.setting_values`), ``positions``
        (``data``: a stage's ``{axis: position}``), ``bench`` (``device`` None,
        ``data``: ``{"open": bool, "devices": [ids]}``), ``job`` (``device`` None,
        ``data``: ``{"id", "name", "state", "owner", "holds", "run"}``, a job started,
        ``running``, or ended, ``done`` or ``failed``:
        :meth:`instrument.bench.bench_job_handle.JobInfo.as_event`), ``message`` (``device``
        None, ``data``: a line for the operator, e.g. which job took the live view's
        camera).
    device : str or None
    data : object
    """

    seq: int
    kind: str
    device: str | None
    data: Any


def same_value(a: Any, b: Any) -> bool:
    """Whether two plain values are equal (arrays compared element by element)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)
                and a.shape == b.shape and bool(np.array_equal(a, b)))
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        return a.keys() == b.keys() and all(same_value(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(same_value(x, y) for x, y in zip(a, b, strict=True))
    try:
        return bool(a == b)
    except (TypeError, ValueError):
        return False


class EventLog:
    """The last ``maxlen`` :class:`BenchEvent` s; readers wait for the next.

    Parameters
    ----------
    maxlen : int
        Events kept (a reader that fell further behind gets the newest ``maxlen``).
    """

    def __init__(self, maxlen: int = 2048) -> None:
        self._events: deque[BenchEvent] = deque(maxlen=maxlen)
        self._seq = 0
        self._cond = threading.Condition()

    @property
    def last_seq(self) -> int:
        return self._seq

    def put(self, kind: str, device: str | None = None, data: Any = None) -> BenchEvent:
        """Log an event and wake the readers."""
        with self._cond:
            self._seq += 1
            event = BenchEvent(self._seq, kind, device, data)
            self._events.append(event)
            self._cond.notify_all()
        return event

    def after(self, seq: int | None, timeout_s: float = 1.0) -> tuple[int, list[BenchEvent]]:
        """The events logged after ``seq``, waiting up to ``timeout_s`` for one.

        ``seq`` None: none (returns at once), with the number to ask after next.

        Returns
        -------
        tuple
            ``(last seq, [events])``.
        """
        with self._cond:
            if seq is None:
                return self._seq, []
            self._cond.wait_for(lambda: self._seq > seq, max(0.0, float(timeout_s)))
            return self._seq, [e for e in self._events if e.seq > seq]


def device_info(name: str, dev) -> DeviceInfo:
    """The :class:`DeviceInfo` of an open device ``dev`` named ``name``."""
    cls = type(dev)
    extra: dict[str, Any] = {}
    if dev.kind == "stage":
        extra.update(axes=tuple(dev.axes), units={a: dev.units(a) for a in dev.axes},
                     travel={a: tuple(float(v) for v in t) for a, t in dev.travel.items()})
    elif dev.kind == "led_array":
        extra["led_positions_mm"] = np.asarray(dev.positions_mm, dtype=float)
    elif hasattr(dev, "resolution"):
        extra["resolution"] = tuple(int(v) for v in dev.resolution)
    return DeviceInfo(name, dev.kind, f"{cls.__module__}:{cls.__qualname__}", dict(dev.info),
                      **extra)


class BenchService:
    """The commands on the open bench (see the module docstring); ``self.bench`` is the
    open :class:`~instrument.devices.bench.Bench` (or virtual bench, None when none is open),
    ``self.device_events`` its :class:`EventLog`.

    Every command raises :class:`BenchServiceError` when no bench is open or the device
    is unknown or of another kind, and the driver's own error
    (:class:`drivers.errors.DeviceError` and its kinds, e.g.
    :class:`~drivers.errors.StageLimitError`) when the device refuses.
    """

    bench: Any = None
    device_events: EventLog

    # -- the devices -------------------------------------------------------------------
    def _device(self, name: str, kind: str | Sequence[str] | None = None):
        if self.bench is None:
            raise BenchServiceError("no bench is open; press Connect first")
        dev = self.bench.devices.get(name)
        if dev is None:
            raise BenchServiceError(f"the bench has no device {name!r}; its devices are "
                                    f"{', '.join(self.bench.devices)}")
        kinds = (kind,) if isinstance(kind, str) else kind
        if kinds is not None and dev.kind not in kinds:
            raise BenchServiceError(f"{name} is a {dev.kind}, not a {' or '.join(kinds)}; "
                                    "name one that is")
        return dev

    def devices(self) -> list[DeviceInfo]:
        """Every device of the open bench, in the bench file's order (empty: none open)."""
        if self.bench is None:
            return []
        return [device_info(name, dev) for name, dev in self.bench.devices.items()]

    def is_virtual(self) -> bool:
        """Whether the open bench is the virtual bench (``--simulate``)."""
        return self.bench is not None and hasattr(self.bench, "set_scene")

    def status(self, device: str) -> dict:
        """:meth:`drivers.base.Device.status` of ``device``."""
        return self._device(device).status()

    def settings(self, device: str) -> dict:
        """:meth:`drivers.base.Device.settings` (cached, no device I/O)."""
        return self._device(device).settings()

    def setting_values(self, device: str) -> dict:
        """:meth:`drivers.base.Device.setting_values` (every declared setting)."""
        return self._device(device).setting_values()

    def settings_snapshot(self) -> dict:
        """:meth:`instrument.devices.bench.Bench.settings_snapshot` (for a record's metadata)."""
        if self.bench is None:
            raise BenchServiceError("no bench is open; press Connect first")
        return self.bench.settings_snapshot()

    def apply_settings(self, device: str, values: Mapping[str, Any]) -> dict:
        """Apply ``values`` (validated first: none applied if one is refused).

        Returns
        -------
        dict
            The device's setting values after (what it holds, not what was asked).
        """
        dev = self._device(device)
        dev.apply_settings(dict(values))
        return self._settings_changed(device, dev)

    def reconnect(self, device: str) -> dict:
        """Close and open ``device`` again, its settings re-applied
        (:meth:`drivers.base.Device.reconnect`); returns its setting values."""
        dev = self._device(device)
        dev.reconnect()
        return self._settings_changed(device, dev)

    def _settings_changed(self, name: str, dev) -> dict:
        values = dev.setting_values()
        self.device_events.put("settings", name, values)
        return values

    # -- stages ------------------------------------------------------------------------
    def positions(self, stage: str) -> dict:
        """The stage's ``{axis: position}`` in each axis's unit (mm, deg)."""
        return self._device(stage, "stage").positions()

    def move(self, stage: str, targets: Mapping[str, float], *, relative: bool = False,
             timeout_s: float = 30.0) -> dict:
        """Move the stage's axes to ``targets`` (``relative``: by them) and wait.

        Parameters
        ----------
        stage : str
        targets : dict
            ``{axis: position}`` in the axis's unit; axes not named stay.
        relative : bool
        timeout_s : float
            Longest wait for the move, s.

        Returns
        -------
        dict
            The positions after the move (also pushed as a ``positions`` event).
        """
        dev = self._device(stage, "stage")
        targets = {str(a): float(v) for a, v in targets.items()}
        if relative:
            dev.move_by(targets, timeout_s=timeout_s)
        else:
            dev.move_to(targets, timeout_s=timeout_s)
        return self._moved(stage, dev)

    def stop_motion(self, stage: str) -> dict:
        """Stop the stage now; returns (and pushes) where it stopped."""
        dev = self._device(stage, "stage")
        dev.stop()
        return self._moved(stage, dev)

    def _moved(self, name: str, dev) -> dict:
        positions = dev.positions()
        self.device_events.put("positions", name, positions)
        return positions

    # -- patterns ----------------------------------------------------------------------
    def show(self, device: str, pattern: Any) -> Any:
        """Show ``pattern`` on an LED array or an SLM.

        Parameters
        ----------
        device : str
        pattern : str, sequence of int or numpy.ndarray
            LED array: a pattern name (:data:`drivers.led_array.PATTERNS`), ``"off"``,
            or LED indices lit alone at the array's colour and brightness settings.
            SLM: a float phase array, rad, of its resolution (or its uint8 gray image).

        Returns
        -------
        object
            LED array: :meth:`~drivers.led_array.LedArray.lit` after; SLM: the pattern
            id ``show_phase``/``show_image`` returned.
        """
        dev = self._device(device, ("led_array", "slm"))
        if dev.kind == "led_array":
            if isinstance(pattern, str):
                dev.all_off() if pattern == "off" else dev.set_pattern(pattern)
            else:
                dev.set_leds([int(i) for i in pattern], dev.colour, dev.brightness)
            return self.lit(device)
        image = np.asarray(pattern)
        if np.issubdtype(image.dtype, np.floating):
            return dev.show_phase(image)
        return dev.show_image(image)

    def lit(self, led_array: str) -> dict:
        """``{index: (colour, brightness)}`` of the lit LEDs."""
        return dict(self._device(led_array, "led_array").lit())

    # -- the camera --------------------------------------------------------------------
    def camera_format(self) -> CameraFormat:
        """The camera's image shape and bit depth (at its present ROI and binning)."""
        cam = self._camera()
        offset = getattr(cam, "dark_offset_dn", None)
        return CameraFormat(tuple(int(v) for v in cam.image_shape), int(cam.bit_depth),
                            None if offset is None else float(offset))

    def snap(self) -> Any:
        """One frame (:meth:`drivers.camera.Camera.snap`; not while streaming)."""
        return self._camera().snap()

    def _camera(self):
        if self.bench is None:
            raise BenchServiceError("no bench is open; press Connect first")
        return self.bench.camera

    # -- events ------------------------------------------------------------------------
    def events_after(self, seq: int | None, timeout_s: float = 1.0) -> tuple[int, list]:
        """:meth:`EventLog.after`: the events after ``seq``, waiting up to ``timeout_s``
        for one."""
        return self.device_events.after(seq, min(float(timeout_s), 5.0))

    def _watch(self, stop: threading.Event, period_s: float = WATCH_PERIOD_S) -> None:
        """Read every device's status once a ``period_s`` and log what changed."""
        last: dict[str, dict] = {}
        wait_s = 0.0  # the first reading at once
        while not stop.wait(wait_s):
            wait_s = period_s
            bench = self.bench
            if bench is None:
                return
            for name, dev in list(bench.devices.items()):
                if stop.is_set():
                    return
                now = _read_device(dev)
                before = last.get(name)
                if before is not None and same_value(before, now):
                    continue
                last[name] = now
                self.device_events.put("status", name, now)
                if before is not None and now["values"] is not None and not same_value(
                        before["values"], now["values"]):
                    self.device_events.put("settings", name, now["values"])
                positions = now["status"].get("positions")
                if before is not None and isinstance(positions, dict) and not same_value(
                        before["status"].get("positions"), positions):
                    self.device_events.put("positions", name, positions)


def _read_device(dev) -> dict:
    """``{"status", "settings", "values"}`` of ``dev`` (settings and values: None when
    it is closed or disconnected; a status that fails reads as disconnected)."""
    try:
        status = dev.status()
    except Exception as exc:  # noqa: BLE001 (shown as the device's state)
        try:
            is_open = dev.is_open
        except Exception:  # noqa: BLE001 (the bench closed meanwhile)
            is_open = False
        return {"status": {"is_open": is_open, "disconnected": True, "error": str(exc)},
                "settings": None, "values": None}
    settings = values = None
    if status.get("is_open") and not status.get("disconnected"):
        try:
            settings, values = dev.settings(), dev.setting_values()
        except Exception:  # noqa: BLE001 (gone between the reads: shown so)
            pass
    return {"status": status, "settings": settings, "values": values}

"""From a bench file to open devices: the steps that need both the bench
configuration (:mod:`instrument.config`) and the driver registry
(:mod:`instrument.devices.registry`).

* :func:`parse_bench` / :func:`load_bench`: a bench file validated (models and bench
  rules, :func:`instrument.config.validate_bench_text`) and checked against the
  installed drivers (:func:`instrument.devices.registry.driver_problems`, optionally
  :func:`instrument.devices.registry.construction_problems`);
* :func:`simulated_twin` / :func:`with_simulated_drivers`: the simulated stand-ins of
  a bench's devices (their parameters filtered by what the twin's driver takes);
* :func:`open_bench`: construct and open every device, concurrently where they share
  no connection, within the caller's timeout and cancel event, closing the opened ones
  if any fails (every failure reported), so nothing is left half-open.

This module imports both; neither :mod:`instrument.config` nor
:mod:`instrument.devices.registry` imports it or the other's dependants, so the two stay free
of cycles.
"""

from __future__ import annotations

import inspect
import logging
import re
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from diffuserlab.errors import DiffuserLabError
from drivers.errors import DeviceCancelledError

from ..config import (
    DEFAULT_TRAVEL,
    SIMULATED_DRIVERS,
    TWIN_PARAM_ALIASES,
    BenchConfig,
    DeviceConfig,
    GeometryConfig,
    Problem,
    raise_problems,
    read_bench_text,
    validate_bench_text,
    within,
)
from ..config.rules import ID_TABLES
from .registry import (
    RegistryError,
    accepted_params,
    device_construction_problems,
    driver_problems,
    one_view,
    required_params,
    resolve,
)

__all__ = [
    "CONNECTION_PARAMS",
    "BenchOpenError",
    "OpenBench",
    "independent_groups",
    "load_bench",
    "open_bench",
    "parse_bench",
    "simulated_twin",
    "with_simulated_drivers",
]

log = logging.getLogger(__name__)

# -------------------------------------------------------------- loading a bench file


def parse_bench(
    text: str,
    *,
    source: str | None = None,
    check_drivers: bool = True,
    simulate: bool = False,
    construct: bool = False,
) -> BenchConfig:
    """Validate TOML text as a bench; raises ``BenchConfigError`` with every problem.

    Parameters
    ----------
    text, source : str
        The TOML document, and the name used in messages (a file path; optional).
    check_drivers : bool
        Also check every driver name in the registry and its kind (imports the
        drivers).
    simulate : bool
        Return the bench with every device swapped for its simulated twin
        (:func:`with_simulated_drivers`); the drivers checked are then the twins, so a
        lab file validates on a machine without its hardware drivers.
    construct : bool
        Also construct every device (without opening it), so parameter values the
        driver refuses are reported here rather than at open (``validate`` does).
        A device is constructed whenever its kind and driver are usable, whatever
        the problems elsewhere in the file, without the parameters that have problems
        of their own.

    Returns
    -------
    BenchConfig

    Raises
    ------
    instrument.config.BenchConfigError
        TOML syntax error (line and column), missing keys, unknown keys, wrong units or
        ranges, duplicate ids, bench rules, unknown drivers or a driver of another
        kind, refused parameters: every problem found, each with location and fix.
    """
    with one_view():  # the installed drivers read once
        return _parse_bench(text, source, check_drivers, simulate, construct)


def _parse_bench(
    text: str, source: str | None, check_drivers: bool, simulate: bool, construct: bool
) -> BenchConfig:
    raw, config, problems = validate_bench_text(text, source=source)
    devices = raw.get("devices")
    entries = devices if isinstance(devices, list) else []
    geometry = config.geometry if config is not None else _valid_geometry(raw.get("geometry"))
    if check_drivers:
        checked = [
            _as_driven(i, d, config, geometry) if simulate else d for i, d in enumerate(entries)
        ]
        found = driver_problems(checked)
        if simulate:  # a twin drops what its driver does not take: check the real driver's
            found += [p for p in driver_problems(entries)  # names where it is installed
                      if ".params." in p.location and "takes no parameter" in p.message]
        # A parameter the driver does not take: its value's problems are moot.
        moot = [p.location for p in found if ".params." in p.location]
        problems = [p for p in problems if not any(within(p.location, m) for m in moot)]
        problems += found
    if construct:
        for i, entry in enumerate(entries):
            device = _constructible(i, entry, problems, simulate)
            if device is None:
                continue
            locations: dict[str, str] = {}
            if simulate:
                device, locations = _twin_with_locations(i, device, geometry)
            problems += device_construction_problems(i, device, locations=locations)
    raise_problems(problems, text, source)
    assert config is not None
    return with_simulated_drivers(config) if simulate else config


def _valid_geometry(raw: Any) -> GeometryConfig | None:
    """The geometry table as a model, None if it has problems (reported elsewhere)."""
    try:
        return GeometryConfig.model_validate(raw)
    except ValidationError:
        return None


def _as_driven(
    index: int, entry: Any, config: BenchConfig | None, geometry: GeometryConfig | None
) -> Any:
    """A raw ``[[devices]]`` entry as its simulated twin (for the driver checks).

    The twin's translated parameters when the device is valid; otherwise only its
    driver name (the parameters have problems of their own, and a twin drops the ones
    it does not take anyway).
    """
    if config is not None:
        return simulated_twin(config.devices[index], geometry)[0].model_dump()
    kind = _kind(entry)
    if kind is None:
        return entry
    return {"id": entry.get("id"), "kind": kind, "driver": SIMULATED_DRIVERS[kind]}


def _kind(entry: Any) -> str | None:
    """The valid kind of a raw ``[[devices]]`` entry, None if it has none."""
    kind = entry.get("kind") if isinstance(entry, dict) else None
    return kind if isinstance(kind, str) and kind in SIMULATED_DRIVERS else None


def _constructible(
    index: int, entry: Any, problems: list[Problem], simulate: bool
) -> DeviceConfig | None:
    """The device to construct for a raw ``[[devices]]`` entry, None if it cannot be.

    A device is constructed when its kind, driver and parameters table are valid and
    the driver resolves (no problem at ``devices[i].driver``; with ``simulate``, the
    twin's driver), with every parameter that has a problem of its own left out (its
    problem is reported already; constructing with it would only report it again) -
    unless the driver requires that parameter. A duplicate or malformed id does not
    stop the construction.
    """
    here = f"devices[{index}]"
    kind = _kind(entry)
    if kind is None:
        return None
    driver, params = entry.get("driver"), entry.get("params", {})
    if not isinstance(driver, str) or not driver.strip() or not isinstance(params, dict):
        return None
    mine = [p.location for p in problems if within(p.location, here)]
    if any(loc in (here, f"{here}.params") or within(loc, f"{here}.driver") for loc in mine):
        return None
    prefix = f"{here}.params."  # keys with problems, given or missing (a stage's axes)
    bad = {re.split(r"[.\[]", loc[len(prefix):])[0] for loc in mine if loc.startswith(prefix)}
    try:
        required = required_params(resolve(SIMULATED_DRIVERS[kind] if simulate else driver, kind))
    except RegistryError:
        return None
    if bad & (required | set(ID_TABLES)):  # constructed without them it would be another
        return None  # device (a controller layout the file does not describe)
    dev_id = entry.get("id")
    return DeviceConfig.model_construct(
        id=dev_id if isinstance(dev_id, str) and dev_id.strip() else f"device-{index}",
        kind=kind,
        driver=driver,
        params={k: v for k, v in params.items() if k not in bad},
    )


def _twin_with_locations(
    index: int, device: DeviceConfig, geometry: GeometryConfig | None
) -> tuple[DeviceConfig, dict[str, str]]:
    """The simulated twin, and where each of its parameters comes from in the file where
    that is not under the twin's own name (an alias, or the geometry)."""
    twin, _ = simulated_twin(device, geometry)
    here = f"devices[{index}].params"
    locations = {}
    for name, sources in TWIN_PARAM_ALIASES[device.kind].items():
        found = next((src for src in sources if src in device.params), None)
        if found is not None:
            locations[name] = f"{here}.{found}"
    from_geometry = {
        ("camera", "sensor_shape"): "geometry.sensor_shape_px",
        ("camera", "pixel_pitch_um"): "geometry.sensor_pixel_pitch_um",
        ("slm", "wavelength_nm"): "geometry.wavelength_nm",
    }
    for (kind, name), loc in from_geometry.items():
        if kind == device.kind and name in twin.params and name not in device.params:
            locations.setdefault(name, loc)
    return twin, locations


def load_bench(
    path: str | Path,
    *,
    check_drivers: bool = True,
    simulate: bool = False,
    construct: bool = False,
) -> BenchConfig:
    """Read and validate a bench TOML file (options as in :func:`parse_bench`).

    Raises
    ------
    instrument.config.BenchConfigError
        Unreadable file, TOML syntax error (line and column), missing keys, unknown
        keys, wrong units or ranges, duplicate ids, bench rules, unknown drivers or a
        driver of another kind: every problem found, each with location and fix.
    """
    return parse_bench(
        read_bench_text(path),
        source=str(path),
        check_drivers=check_drivers,
        simulate=simulate,
        construct=construct,
    )


# ------------------------------------------------------------------ simulated twins


def simulated_twin(
    device: DeviceConfig, geometry: GeometryConfig | None = None
) -> tuple[DeviceConfig, list[str]]:
    """The simulated twin of one device, and the names of the parameters it dropped.

    The twin keeps the id and kind and takes the driver :data:`SIMULATED_DRIVERS`
    names for the kind. Parameters are translated where they mean the same thing:

    * names in :data:`TWIN_PARAM_ALIASES` are renamed (``bit_depth`` -> ``adc_bits``,
      an SLM's ``shape_px`` -> ``resolution``, ...);
    * a camera without ``sensor_shape``/``pixel_pitch_um`` takes them from the
      geometry, an SLM without ``wavelength_nm`` the geometry's wavelength;
    * a stage whose ``axes`` is an array of names gets travel ranges from
      ``limits_mm``/``limits_deg`` (``{axis = [low, high]}``) or defaults;
    * any other parameter is kept if the twin's constructor takes it by that name,
      otherwise dropped (ports, serial numbers, ...). If the twin cannot be imported,
      only the translated parameters are kept.
    """
    kind = device.kind
    driver = SIMULATED_DRIVERS[kind]
    rest = dict(device.params)
    out: dict[str, Any] = {}
    for name, sources in TWIN_PARAM_ALIASES[kind].items():
        found = [src for src in sources if src in rest]
        if found:
            out[name] = rest[found[0]]
            for src in found:
                rest.pop(src)
    if kind == "camera" and geometry is not None:
        out.setdefault("sensor_shape", list(geometry.sensor_shape_px))
        out.setdefault("pixel_pitch_um", rest.pop("pixel_pitch_um", geometry.sensor_pixel_pitch_um))
    if kind == "slm" and geometry is not None:
        out.setdefault("wavelength_nm", rest.pop("wavelength_nm", geometry.wavelength_nm))
    if kind == "stage" and isinstance(rest.get("axes"), list):
        limits = {**_as_dict(rest.pop("limits_mm", {})), **_as_dict(rest.pop("limits_deg", {}))}
        out["axes"] = {
            a: list(limits.get(a, DEFAULT_TRAVEL.get(a, (-1.0, 1.0)))) for a in rest.pop("axes")
        }
    try:
        accepted = accepted_params(resolve(driver, kind))
    except RegistryError:
        accepted = set()
    dropped = []
    for key, value in rest.items():
        if accepted is None or key in accepted:
            out.setdefault(key, value)
        else:
            dropped.append(key)
    twin = device.model_copy(update={"driver": driver, "params": out})
    return twin, dropped


def _as_dict(value: Any) -> dict[str, Any]:
    return value if isinstance(value, dict) else {}


def with_simulated_drivers(config: BenchConfig) -> BenchConfig:
    """The same bench with every device driven by its simulated twin.

    Ids, kinds, geometry and calibration are kept; parameters are translated as in
    :func:`simulated_twin` (shapes, pitches, stage travel kept; ports, serial numbers
    and other hardware addresses dropped).
    """
    devices = [simulated_twin(d, config.geometry)[0] for d in config.devices]
    return config.model_copy(update={"devices": devices})


# ------------------------------------------------------------------- opening a bench


class BenchOpenError(DiffuserLabError, RuntimeError):
    """Devices failed to construct or open; every device opened was closed again.

    Attributes
    ----------
    device_id : str
        The first device (in bench order) that failed.
    driver : str
        Its driver.
    failures : dict[str, BaseException]
        Every device that failed, in bench order, with its error.
    stopped : list[str]
        Devices whose open was stopped because another failed (or never started).
    closed : list[str]
        Ids of the devices opened and closed again.
    close_errors : dict[str, BaseException]
        Devices whose close failed during that cleanup.
    """

    def __init__(
        self,
        device_id: str,
        driver: str,
        cause: BaseException,
        closed: list[str],
        close_errors: dict[str, BaseException],
        failures: dict[str, tuple[str, BaseException]] | None = None,
        stopped: list[str] | None = None,
    ):
        self.device_id = device_id
        self.driver = driver
        self.closed = closed
        self.close_errors = close_errors
        failures = failures or {device_id: (driver, cause)}
        self.failures = {k: e for k, (_, e) in failures.items()}
        self.stopped = list(stopped or [])
        text = "; ".join(
            f"opening device {dev!r} (driver {drv!r}) failed: {type(exc).__name__}: {exc}"
            for dev, (drv, exc) in failures.items())
        if self.stopped:
            text += f"; not opened: {', '.join(self.stopped)}"
        text += f"; closed again: {', '.join(closed) or 'none'}"
        if close_errors:
            text += "; close failed for: " + ", ".join(
                f"{k} ({type(e).__name__}: {e})" for k, e in close_errors.items()
            )
        super().__init__(text)

    def __reduce__(self):
        return (type(self), (self.device_id, self.driver, self.failures.get(self.device_id),
                             self.closed, self.close_errors, None, self.stopped))


class OpenBench(dict[str, Any]):
    """``{device id: opened device}``, in bench order; a context manager that closes them.

    ``close()`` closes every device in reverse order (each close is attempted even if
    another fails; failures are logged and returned), then empties the mapping.
    """

    def close(self) -> dict[str, BaseException]:
        """Close every device, last opened first; returns ``{id: error}`` of failed closes."""
        errors = _close_all(list(self.items()))
        self.clear()
        return errors

    def __enter__(self) -> OpenBench:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _close_all(devices: list[tuple[str, Any]]) -> dict[str, BaseException]:
    errors: dict[str, BaseException] = {}
    for dev_id, dev in reversed(devices):
        try:
            dev.close()
        except Exception as exc:  # keep closing the others
            log.warning("closing device %s failed: %s: %s", dev_id, type(exc).__name__, exc)
            errors[dev_id] = exc
    return errors


#: Bench-file parameters that name a connection a device holds (a port, a unit's serial
#: number, an address): devices sharing one are opened one after another, in bench order.
CONNECTION_PARAMS = frozenset({"port", "ports", "serial_number", "serial_numbers", "address",
                               "ip", "device", "device_path", "camera_id"})


def _connections(dev_cfg: DeviceConfig) -> set[str]:
    out: set[str] = set()
    for name, value in dev_cfg.params.items():
        if name not in CONNECTION_PARAMS:
            continue
        values = (value.values() if isinstance(value, dict)
                  else value if isinstance(value, list | tuple) else [value])
        out.update(f"{v}" for v in values if v not in (None, ""))
    return out


def independent_groups(devices: list[DeviceConfig],
                       shared: list[set[str]] | None = None) -> list[list[int]]:
    """Indices of ``devices`` in groups that may open concurrently: devices sharing a
    connection (:data:`CONNECTION_PARAMS`), or another key of ``shared[i]`` (e.g. one
    simulated clock), are in one group, in bench order."""
    group_of: dict[str, int] = {}
    groups: list[list[int]] = []
    for i, dev in enumerate(devices):
        keys = _connections(dev) | (shared[i] if shared else set())
        hits = sorted({group_of[k] for k in keys if k in group_of})
        if not hits:
            groups.append([i])
            target = len(groups) - 1
        else:
            target = hits[0]
            for other in hits[1:]:  # this device joins groups that were apart
                groups[target].extend(groups[other])
                groups[other] = []
                group_of.update({k: target for k, g in group_of.items() if g == other})
            groups[target].append(i)
        group_of.update(dict.fromkeys(keys, target))
    return [sorted(g) for g in groups if g]


def open_bench(
    config: BenchConfig,
    *,
    simulate: bool = False,
    timeout_s: float | None = None,
    construct: Callable[[DeviceConfig, type], Any] | None = None,
    cancel: threading.Event | None = None,
) -> OpenBench:
    """Construct and open every device of ``config``; usable as a context manager.

    Every driver is resolved (and its kind checked) and every device constructed (as
    ``cls(device_id, **params)``; constructor errors of all devices reported) before
    any device is opened, with ``open(timeout_s, cancel=...)``. Devices are opened
    concurrently, one thread per group of devices that share no connection
    (:func:`independent_groups`; a group opens in bench order). If any fails, the
    others are told to stop (their waits, homing included, end within 0.1 s), every
    device that opened is closed again, last first, and one error lists every device
    that failed: nothing is left half-open.

    Parameters
    ----------
    config : BenchConfig
    simulate : bool
        Swap every device for its simulated twin first (:func:`with_simulated_drivers`).
    timeout_s : float, optional
        Bounds each device's whole open (homing at open included); None: each
        device's own bounds (:meth:`drivers.base.Device.open`).
    construct : callable, optional
        ``construct(device_config, cls) -> device`` replaces the plain
        ``cls(device_id, **params)``, e.g. to couple simulated devices to a virtual
        bench; the open/close-on-failure semantics stay the same.
    cancel : threading.Event, optional
        Set from another thread (a GUI's cancel) to stop the open: every device's
        waits check it, and the devices already open are closed.

    Raises
    ------
    RegistryError
        A driver is unknown, cannot load, or is of another kind (nothing opened).
    BenchOpenError
        Devices failed to construct or open, or the open was cancelled (the others
        are closed again).
    """
    if timeout_s is not None and not (timeout_s > 0):
        raise ValueError(f"timeout_s must be > 0, got {timeout_s!r}")
    if simulate:
        config = with_simulated_drivers(config)
    classes = [(d, resolve(d.driver, d.kind)) for d in config.devices]
    halt = threading.Event()  # the caller's cancel, or another device failed
    made: dict[int, Any] = {}
    opened: set[int] = set()
    failures: dict[int, BaseException] = {}

    for i, (dev_cfg, cls) in enumerate(classes):  # every constructor, before any open
        try:
            made[i] = cls(dev_cfg.id, **dev_cfg.params) if construct is None else (
                construct(dev_cfg, cls))
        except Exception as exc:
            failures[i] = exc

    def open_group(group: list[int]) -> None:
        for i in group:
            if halt.is_set():
                return
            try:
                log.debug("opening %s (%s)", classes[i][0].id, classes[i][0].driver)
                _open_device(made[i], timeout_s, halt)
                opened.add(i)
            except BaseException as exc:  # reported below, every device's
                failures[i] = exc
                halt.set()

    # simulated devices advancing one clock are not independent: their opens would
    # interleave the simulated time
    clocks = [{f"clock:{id(made[i].clock)}"} if getattr(made.get(i), "clock", None)
              is not None else set() for i in range(len(classes))]
    groups = [] if failures else independent_groups([d for d, _ in classes], clocks)
    interrupted: BaseException | None = None
    with ThreadPoolExecutor(max_workers=max(1, min(8, len(groups))),
                            thread_name_prefix="open-bench") as pool:
        futures = [pool.submit(open_group, g) for g in groups]
        try:
            while not all(f.done() for f in futures):
                if cancel is not None and cancel.is_set():
                    halt.set()
                wait(futures, timeout=0.05)
        except BaseException as exc:  # Ctrl-C while waiting: stop the opens, clean up
            interrupted = exc
            halt.set()
            wait(futures)
    if cancel is not None and cancel.is_set():
        halt.set()
    bench = OpenBench((classes[i][0].id, made[i]) for i in range(len(classes)) if i in opened)
    if not failures and interrupted is None and not (cancel is not None and cancel.is_set()):
        return bench
    pending = [(classes[i][0].id, made[i]) for i in sorted(made)]  # failed ones too
    errors = _close_all(pending)
    bench.clear()
    base_exc = interrupted or next((e for e in failures.values()
                                    if not isinstance(e, Exception)), None)
    if base_exc is not None:
        raise base_exc
    cancelled = cancel is not None and cancel.is_set()
    real = {i: e for i, e in sorted(failures.items())
            if cancelled or not isinstance(e, DeviceCancelledError)}
    if not real:  # cancelled before any device reported
        real = {i: DeviceCancelledError(classes[i][0].id, "open cancelled", "open it again")
                for i in range(len(classes)) if i not in opened}
    first = min(real)
    stopped = [classes[i][0].id for i in range(len(classes))
               if i not in real and i not in opened]
    closed = [classes[i][0].id for i in sorted(opened) if classes[i][0].id not in errors]
    for i in real:
        errors.pop(classes[i][0].id, None)
    raise BenchOpenError(
        classes[first][0].id, classes[first][0].driver, real[first], closed, errors,
        failures={classes[i][0].id: (classes[i][0].driver, e) for i, e in real.items()},
        stopped=stopped,
    ) from real[first]


def _open_device(device: Any, timeout_s: float | None, halt: threading.Event) -> None:
    """``device.open(timeout_s, cancel=halt)``; a driver's ``open`` without a cancel
    parameter gets the timeout only."""
    try:
        takes_cancel = "cancel" in inspect.signature(device.open).parameters
    except (TypeError, ValueError):
        takes_cancel = False
    if takes_cancel:
        device.open(timeout_s, cancel=halt)
    elif timeout_s is None:
        device.open()
    else:
        device.open(timeout_s)

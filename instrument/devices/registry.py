"""Driver registry: drivers by name, and what the installed drivers say about a bench.

Drivers are found by name through the entry-point group ``diffuserlab.drivers``, so a
third-party driver is a pip plugin declaring, in its own ``pyproject.toml``::

    [project.entry-points."diffuserlab.drivers"]
    my-camera = "my_package.camera:MyCamera"

The target is a device class (a subclass of ``drivers.base.Device``) with a class
attribute ``kind`` (one of :data:`instrument.config.KINDS`) and the constructor
``(device_id, **params)``. Entry points are read on each lookup and modules are
imported only when a driver is resolved. :func:`register` adds drivers in-process
(notebooks, tests); those take precedence over entry points of the same name.

:func:`driver_problems` and :func:`construction_problems` check a bench's devices
against the drivers. This module imports :mod:`instrument.config` and never the
reverse; loading a bench file with these checks, simulated twins and opening a bench
(:func:`instrument.devices.bench_setup.open_bench`) are in :mod:`instrument.devices.bench_setup`,
which imports both.
"""

from __future__ import annotations

import difflib
import inspect
import logging
import re
from collections.abc import Iterator
from contextlib import contextmanager
from importlib.metadata import entry_points
from typing import Any

from diffuserlab.errors import DiffuserLabError
from instrument.config import KINDS, SIMULATED_DRIVERS, BenchConfig, DeviceConfig, Problem

__all__ = [
    "ENTRY_POINT_GROUP",
    "DriverKindError",
    "DriverLoadError",
    "RegistryError",
    "UnknownDriverError",
    "accepted_params",
    "available",
    "construction_problems",
    "device_construction_problems",
    "driver_problems",
    "names",
    "one_view",
    "register",
    "required_params",
    "resolve",
    "unregister",
]

log = logging.getLogger(__name__)

#: The entry-point group drivers are declared in.
ENTRY_POINT_GROUP = "diffuserlab.drivers"

_local: dict[str, type] = {}


class RegistryError(DiffuserLabError, LookupError):
    """A driver name that cannot be used; the message names the fix."""


class UnknownDriverError(RegistryError):
    """No driver of that name is installed or registered."""

    def __init__(self, name: str, known: list[str]):
        self.name = name
        self.known = known
        super().__init__(
            f"unknown driver {name!r}; available: {', '.join(known) or 'none'}"
            " (install the package that provides it, or use a simulated-* driver)"
        )


class DriverLoadError(RegistryError):
    """A driver is declared but its module or class cannot be loaded.

    ``reason`` says what failed, ``fix`` what to do about it.
    """

    def __init__(self, name: str, reason: str, fix: str):
        self.name, self.reason, self.fix = name, reason, fix
        super().__init__(f"driver {name!r}: {reason}; {fix}")


class DriverKindError(RegistryError):
    """A driver whose kind differs from the device's configured kind."""

    def __init__(self, name: str, driver_kind: str, kind: str):
        self.name, self.driver_kind, self.kind = name, driver_kind, kind
        super().__init__(
            f"driver {name!r} drives a {driver_kind}, not a {kind}: use a {kind} driver "
            f"(e.g. {SIMULATED_DRIVERS.get(kind, '?')!r}) or set kind = {driver_kind!r}"
        )


_snapshot: dict[str, list[Any]] | None = None


@contextmanager
def one_view() -> Iterator[None]:
    """Read the installed drivers' entry points once for the whole block.

    Reading them takes ~20 ms (every installed distribution's metadata); checking a
    bench resolves each driver several times. Inside the block every lookup sees the
    same drivers; outside, each lookup reads them afresh (a plugin installed meanwhile
    is found). Nested blocks share the outermost view.
    """
    global _snapshot
    outer = _snapshot
    if outer is None:
        _snapshot = _read_entry_points()
    try:
        yield
    finally:
        _snapshot = outer


def _entry_points() -> dict[str, list[Any]]:
    """Entry points of the group by name (the :func:`one_view` snapshot inside one)."""
    return _snapshot if _snapshot is not None else _read_entry_points()


def _read_entry_points() -> dict[str, list[Any]]:
    """Entry points of the group by name, duplicates with the same target merged."""
    out: dict[str, list[Any]] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        same = out.setdefault(ep.name, [])
        if all(e.value != ep.value for e in same):
            same.append(ep)
    return out


def register(name: str, cls: type) -> None:
    """Register a driver class in this process (takes precedence over entry points)."""
    _check_class(name, cls)
    _local[name] = cls


def unregister(name: str) -> None:
    """Remove a driver registered with :func:`register` (no error if absent)."""
    _local.pop(name, None)


def names() -> list[str]:
    """Every driver name known here, sorted (imports nothing)."""
    return sorted(set(_local) | set(_entry_points()))


def _check_class(name: str, cls: Any) -> None:
    if not isinstance(cls, type):
        raise DriverLoadError(
            name, f"{cls!r} is not a device class", "point the entry point at the class"
        )
    kind = getattr(cls, "kind", None)
    if kind not in KINDS:
        raise DriverLoadError(
            name,
            f"{cls.__module__}.{cls.__qualname__} declares kind {kind!r}",
            f"a driver class sets kind to one of {', '.join(KINDS)}",
        )


def resolve(name: str, kind: str | None = None) -> type:
    """The device class registered under ``name``.

    Parameters
    ----------
    name : str
        Driver name (entry point name in ``diffuserlab.drivers``).
    kind : str, optional
        The kind the caller expects; a driver of another kind raises
        :class:`DriverKindError`.

    Raises
    ------
    UnknownDriverError, DriverLoadError, DriverKindError
    """
    if name in _local:
        cls = _local[name]
    else:
        eps = _entry_points().get(name)
        if not eps:
            raise UnknownDriverError(name, names())
        if len(eps) > 1:
            targets = ", ".join(f"{e.value} ({_dist_name(e)})" for e in eps)
            raise DriverLoadError(
                name, f"declared by more than one package: {targets}", "uninstall one of them"
            )
        try:
            cls = eps[0].load()
        except Exception as exc:
            raise DriverLoadError(
                name,
                f"{eps[0].value} failed to load: {type(exc).__name__}: {exc}",
                f"reinstall {_dist_name(eps[0])} (or the dependencies it needs)",
            ) from exc
        _check_class(name, cls)
    if kind is not None and cls.kind != kind:
        raise DriverKindError(name, cls.kind, kind)
    return cls


def _dist_name(ep: Any) -> str:
    dist = getattr(ep, "dist", None)
    return getattr(dist, "name", None) or "unknown package"


def accepted_params(cls: type) -> set[str] | None:
    """Parameter names a driver's constructor takes after ``device_id`` (None: any).

    Python-only arguments (``clock``, ``irradiance``) are included; a bench file
    cannot give them values of the right type anyway.
    """
    try:
        sig = inspect.signature(cls.__init__)
    except (TypeError, ValueError):
        return None
    names = set()
    for i, p in enumerate(sig.parameters.values()):
        if p.kind is p.VAR_KEYWORD:
            return None
        if i < 2 or p.kind in (p.VAR_POSITIONAL, p.POSITIONAL_ONLY):  # self, device_id
            continue
        names.add(p.name)
    return names


def available() -> dict[str, str | None]:
    """``{driver name: kind}`` for every driver, the kind read from its class on call.

    A driver that is declared but cannot be loaded here maps to ``None``
    (:func:`resolve` gives the reason).
    """
    out: dict[str, str | None] = {}
    for name in names():
        try:
            out[name] = resolve(name).kind
        except RegistryError as exc:
            log.debug("driver %s unavailable: %s", name, exc)
            out[name] = None
    return out


def driver_problems(devices: Any) -> list[Problem]:
    """Problems with the drivers of raw ``[[devices]]`` tables: unknown name, a driver
    of another kind, a parameter the driver's constructor does not take.

    Used by :func:`instrument.devices.bench_setup.parse_bench`; tolerates malformed entries (those
    are
    reported by the model validation).
    """
    if not isinstance(devices, list):
        return []
    problems = []
    for i, dev in enumerate(devices):
        if not isinstance(dev, dict) or not isinstance(dev.get("driver"), str):
            continue
        if not dev["driver"].strip():  # the model reports the empty name
            continue
        name = dev["driver"]
        kind = dev.get("kind") if dev.get("kind") in KINDS else None
        label = f" of device {dev['id']!r}" if isinstance(dev.get("id"), str) else ""
        try:
            cls = resolve(name, kind)
        except UnknownDriverError as exc:
            usable = [n for n, k in available().items() if kind is None or k == kind]
            what = f"{kind} drivers" if kind else "drivers"
            problems.append(
                Problem(
                    f"devices[{i}].driver",
                    f"unknown driver {name!r}{label}",
                    f"install the plugin that provides {name!r} (entry-point group "
                    f"{ENTRY_POINT_GROUP}) or use one of the {what} installed here: "
                    f"{', '.join(usable or exc.known) or 'none'}; `diffuserlab validate "
                    "--simulate` checks the file with simulated twins",
                )
            )
        except DriverKindError as exc:
            same_kind = [n for n, k in available().items() if k == kind]
            problems.append(
                Problem(
                    f"devices[{i}].driver",
                    f"driver {name!r}{label} drives a {exc.driver_kind}, but kind = {kind!r}",
                    f"use a {kind} driver ({', '.join(same_kind) or 'none installed'}) "
                    f"or set kind = {exc.driver_kind!r}",
                )
            )
        except DriverLoadError as exc:
            problems.append(
                Problem(
                    f"devices[{i}].driver",
                    f"driver {name!r}{label} cannot be loaded: {exc.reason}",
                    exc.fix,
                )
            )
        else:
            params = dev.get("params")
            accepted = accepted_params(cls)
            if accepted is None or not isinstance(params, dict):
                continue
            for key in params:
                if key in accepted:
                    continue
                close = difflib.get_close_matches(key, sorted(accepted), 1)
                hint = f"did you mean {close[0]!r}? " if close else ""
                problems.append(
                    Problem(
                        f"devices[{i}].params.{key}",
                        f"driver {name!r}{label} takes no parameter {key!r}",
                        f"{hint}remove it or use one of: {', '.join(sorted(accepted))}",
                    )
                )
    return problems


def construction_problems(config: BenchConfig) -> list[Problem]:
    """Construct every device of ``config`` without opening it; report the refusals
    (:func:`device_construction_problems` for each device).

    Parameters
    ----------
    config : BenchConfig

    Returns
    -------
    list of Problem
        Located at ``devices[i].params.NAME`` (the parameter refused) or
        ``devices[i].params`` (not known which), or ``devices[i].driver``.
    """
    problems = []
    for i, dev in enumerate(config.devices):
        problems += device_construction_problems(i, dev)
    return problems


def device_construction_problems(
    index: int, device: DeviceConfig, *, locations: dict[str, str] | None = None
) -> list[Problem]:
    """Construct one device without opening it; report every parameter value it refuses.

    A driver's constructor validates its parameters and touches no hardware (the
    device lifecycle connects in ``open``), so this finds bad parameter values (an
    SLM resolution of 0, axes the driver cannot use, ...) before anything is opened.
    A constructor stops at the first value it refuses; that parameter is found (the
    first named in the message, else the one whose removal changes the outcome) and
    the device is constructed again without it (never without a required parameter),
    so every refused value is reported in one pass. Errors carrying
    ``problem``/``fix`` (``drivers.errors.DeviceError``) keep them. A device
    constructed is closed again (a no-op for an unopened ``Device``).

    Parameters
    ----------
    index : int
        The device's position in ``[[devices]]`` (for the locations).
    device : DeviceConfig
        Id, kind, driver and the parameters to construct with.
    locations : dict, optional
        ``{parameter name: dotted location}`` where a parameter's location is not
        ``devices[index].params.NAME`` (a simulated twin's parameter taken from a key
        of another name, or from the geometry).

    Returns
    -------
    list of Problem
        Empty if the device constructs.
    """
    try:
        cls = resolve(device.driver, device.kind)
    except RegistryError as exc:
        return [Problem(f"devices[{index}].driver", str(exc), "see the message")]
    locations = locations or {}
    params = dict(device.params)
    required = required_params(cls)
    problems = []
    while True:
        refusal = _construct(cls, device.id, params)
        if refusal is None:
            return problems
        problem = getattr(refusal, "problem", None) or f"{type(refusal).__name__}: {refusal}"
        fix = getattr(refusal, "fix", None) or f"check the parameters {device.driver!r} takes"
        key = _refused_param(cls, device.id, params, refusal, required)
        where = f"devices[{index}].params"
        if key is not None:
            where = locations.get(key, f"{where}.{key}")
        problems.append(
            Problem(
                where,
                f"driver {device.driver!r} refused the parameters of device {device.id!r}: "
                f"{problem}",
                fix,
            )
        )
        if key is None or key in required:  # not known which, or cannot be left out
            return problems
        params.pop(key)


def _construct(cls: type, device_id: str, params: dict[str, Any]) -> Exception | None:
    """Construct (and close again) a device; the exception its constructor raised, if any."""
    try:
        device = cls(device_id, **params)
    except Exception as exc:  # any refusal is reported, never raised
        return exc
    close = getattr(device, "close", None)
    if callable(close):
        try:
            close()  # not open: a no-op for a Device, releases anything a driver took
        except Exception as exc:  # never fail validation on this
            log.debug("close after construction of %s failed: %s", device_id, exc)
    return None


def required_params(cls: type) -> set[str]:
    """Names of the constructor parameters after ``device_id`` that have no default.

    Parameters
    ----------
    cls : type
        A device class.

    Returns
    -------
    set of str
        Empty if the signature cannot be read.
    """
    try:
        sig = inspect.signature(cls.__init__)
    except (TypeError, ValueError):
        return set()
    return {
        p.name
        for i, p in enumerate(sig.parameters.values())
        if i >= 2
        and p.default is p.empty
        and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
    }


def _refused_param(
    cls: type, device_id: str, params: dict[str, Any], refusal: Exception, required: set[str]
) -> str | None:
    """The parameter whose value the constructor refused, or None if not known.

    The one named in the error (the first named, by position in the message), else the
    one whose removal makes the constructor pass or fail otherwise (never a required
    parameter: its removal fails anyway).
    """
    text = str(getattr(refusal, "problem", None) or refusal)
    named = [
        (m.start(), key)
        for key in params
        if (m := re.search(rf"(?<![A-Za-z0-9_]){re.escape(key)}(?![A-Za-z0-9_])", text))
    ]
    if named:
        return min(named)[1]
    for key in params:
        if key in required:
            continue
        other = _construct(cls, device_id, {k: v for k, v in params.items() if k != key})
        if other is None or str(other) != str(refusal):
            return key
    return None

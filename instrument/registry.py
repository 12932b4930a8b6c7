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
(:func:`instrument.bench_setup.open_bench`) are in :mod:`instrument.bench_setup`,
which imports both.
"""

from __future__ import annotations

import difflib
import inspect
import logging
from importlib.metadata import entry_points
from typing import Any

from instrument.config import KINDS, SIMULATED_DRIVERS, BenchConfig, Problem

__all__ = [
    "ENTRY_POINT_GROUP",
    "DriverKindError",
    "DriverLoadError",
    "RegistryError",
    "UnknownDriverError",
    "accepted_params",
    "available",
    "construction_problems",
    "driver_problems",
    "names",
    "register",
    "resolve",
    "unregister",
]

log = logging.getLogger(__name__)

#: The entry-point group drivers are declared in.
ENTRY_POINT_GROUP = "diffuserlab.drivers"

_local: dict[str, type] = {}


class RegistryError(LookupError):
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


def _entry_points() -> dict[str, list[Any]]:
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

    Used by :func:`instrument.bench_setup.parse_bench`; tolerates malformed entries (those are
    reported by the model validation).
    """
    if not isinstance(devices, list):
        return []
    problems = []
    for i, dev in enumerate(devices):
        if not isinstance(dev, dict) or not isinstance(dev.get("driver"), str):
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
    """Construct every device of ``config`` without opening it; report the refusals.

    A driver's constructor validates its parameters and touches no hardware (the
    device lifecycle connects in ``open``), so this finds bad parameter values (an
    SLM resolution of 0, axes the driver cannot use, ...) before anything is opened.
    Errors carrying ``problem``/``fix`` (``drivers.errors.DeviceError``) keep them.
    """
    problems = []
    for i, dev in enumerate(config.devices):
        try:
            cls = resolve(dev.driver, dev.kind)
            device = cls(dev.id, **dev.params)
        except RegistryError as exc:
            problems.append(Problem(f"devices[{i}].driver", str(exc), "see the message"))
            continue
        except Exception as exc:
            problem = getattr(exc, "problem", None) or f"{type(exc).__name__}: {exc}"
            fix = getattr(exc, "fix", None) or f"check the parameters {dev.driver!r} takes"
            problems.append(
                Problem(
                    f"devices[{i}].params",
                    f"driver {dev.driver!r} refused the parameters of device {dev.id!r}: {problem}",
                    fix,
                )
            )
            continue
        close = getattr(device, "close", None)
        if callable(close):
            try:
                close()  # not open: a no-op for a Device, releases anything a driver took
            except Exception as exc:  # never fail validation on this
                log.debug("close after construction of %s failed: %s", dev.id, exc)
    return problems

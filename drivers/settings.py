"""Device settings declared once: :class:`Setting`.

Each device kind declares its settings as a tuple of :class:`Setting` (the class
attribute ``SETTINGS`` of :class:`~drivers.base.Device`, in the order
:meth:`~drivers.base.Device.apply_settings` applies them), as python-microscope's
``add_setting`` and ScopeFoundry's ``LoggedQuantity`` do. From the declaration come:

- the validation and its error messages (:meth:`Setting.validate`, called by
  :meth:`~drivers.base.Device.check_settings`): dtype, static limits, limits read
  from the open device's ``info`` (:func:`info`), choices, per-axis or per-colour
  mappings;
- a machine-readable description (:meth:`Setting.describe`,
  :meth:`~drivers.base.Device.setting_specs`) for operator interfaces and schemas;
- the limits as an operator reads them (:meth:`Setting.limits_text`);
- a pydantic model of a settings table (:func:`settings_model`), hence a JSON
  schema for files that hold settings;
- the settings tables of the driver documentation (:func:`settings_markdown`,
  written to docs/drivers/settings.md by ``python -m instrument.writer.docpage``).

A driver extends or narrows its kind's table with :func:`with_settings`.
Constraints between settings (a DMD's exposure within its period) stay in the
kind's ``_check_settings``; the declaration's description names them.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["FromInfo", "Setting", "info", "setting_property", "settings_markdown", "settings_model",
           "with_settings"]

_FIELD = re.compile(r"\{([^{}]+)\}")


@dataclass(frozen=True)
class FromInfo:
    """A limit or a list of choices read from an open device's ``info``.

    Parameters
    ----------
    text : str
        How the documentation names it, e.g. ``"info.exposure_range_s[0]"``.
    read : callable
        ``read(info, key) -> value``; ``key`` is the axis or colour of a per-key
        setting, else None.
    """

    text: str
    read: Callable[[Mapping[str, Any], str | None], Any] = field(compare=False)

    def __call__(self, info_: Mapping[str, Any], key: str | None = None) -> Any:
        return self.read(info_, key)


def info(path: str, *, transform: Callable[[Any], Any] | None = None,
         text: str | None = None) -> FromInfo:
    """A :class:`FromInfo` reading ``path`` in the device's info.

    Parameters
    ----------
    path : str
        Keys separated by dots, list indices in brackets, ``{key}`` for the axis or
        colour of a per-key setting: ``"gain_range_db[1]"``,
        ``"axes.{key}.max_velocity"``.
    transform : callable, optional
        Applied to the value read (e.g. a filter of choices, a difference).
    text : str, optional
        The documentation's words; default ``"info." + path``.
    """
    steps = [(part.split("[")[0], [int(i) for i in re.findall(r"\[(\d+)\]", part)])
             for part in path.split(".")]

    def read(info_: Mapping[str, Any], key: str | None) -> Any:
        value: Any = info_
        for name, indices in steps:
            value = value[key if name == "{key}" else name]
            for i in indices:
                value = value[i]
        return value if transform is None else transform(value)

    return FromInfo(text or "info." + path.replace(".{key}", "[<key>]"), read)


def _resolve(value: Any, info_: Mapping[str, Any] | None, key: str | None) -> Any:
    if isinstance(value, FromInfo):
        return None if info_ is None else value(info_, key)
    return value


def _text(value: Any) -> str:
    if isinstance(value, FromInfo):
        return value.text
    if isinstance(value, float | int):
        return f"{value:g}"
    return str(value)


@dataclass(frozen=True)
class Setting:
    """One setting of a device kind: everything the code, the GUI and the docs need.

    Parameters
    ----------
    name : str
        The key in :meth:`~drivers.base.Device.settings`, e.g. ``"exposure_s"``.
    dtype : str
        ``"float"``, ``"int"``, ``"str"`` (one of ``choices``) or the shape of a
        compound value validated by ``check`` (``"int[4]"``, ``"float[256]"``,
        ``"(float, float)"``).
    unit : str
        SI unit (``"s"``, ``"Hz"``, ``"dB"``, ``"rad"``, ``"px"``); ``"{unit}"``
        stands for the unit of the key of a per-key setting (``key_units``).
    description : str
        One sentence for tooltips and documentation.
    low, high : float or FromInfo, optional
        Inclusive limits, static or read from the open device's info.
    low_open : bool
        ``low`` itself is excluded.
    positive : bool
        The value must be > 0, checked before ``low``/``high`` (so a negative
        exposure is named as such, not as outside the sensor's range).
    choices : tuple of str or FromInfo, optional
        Allowed values of a ``"str"`` setting.
    per : str, optional
        The value is a mapping ``{key: value}`` keyed by the keys of this info
        entry (``"axes"``, ``"colours"``); a partial mapping updates the others.
    key_name : str
        What one key is called in messages (``"axis"``, ``"colour"``).
    key_units : Mapping[str, str], optional
        Unit of each key, substituted for ``{unit}``.
    check : callable, optional
        ``check(device, label, value, low, high) -> value`` for a compound value
        (low/high resolved); raises DeviceValueError through ``device._error``.
    bounds : str, optional
        The limits in words for a ``check`` setting; ``{path}`` fields are filled
        from the info (``"within {sensor_shape[1]} x {sensor_shape[0]} px"``).
    read_only : bool
        Shown, never applied (:meth:`~drivers.base.Device.apply_settings` refuses it).
    tags : frozenset of str
        Kind-specific flags, e.g. ``"stream_locked"`` (a camera refuses the change
        while streaming).
    """

    name: str
    dtype: str
    unit: str = ""
    description: str = ""
    low: float | FromInfo | None = None
    high: float | FromInfo | None = None
    low_open: bool = False
    positive: bool = False
    choices: tuple[str, ...] | FromInfo | None = None
    per: str | None = None
    key_name: str = "key"
    key_units: Mapping[str, str] | None = None
    check: Callable[..., Any] | None = field(default=None, compare=False)
    bounds: str | None = None
    read_only: bool = False
    tags: frozenset[str] = frozenset()

    def replace(self, **changes: Any) -> Setting:
        """This setting with some fields changed (a driver's narrower limits or choices)."""
        return dataclasses.replace(self, **changes)

    # ----------------------------------------------------------- validation
    def validate(self, device: Any, value: Any, pending: Mapping[str, Any]) -> Any:
        """``value`` checked and normalised, or DeviceValueError from ``device``.

        Parameters
        ----------
        device : drivers.base.Device
            The open device (its info gives the limits; its helpers raise the errors).
        value : object
            The requested value (JSON types accepted).
        pending : Mapping
            The settings as they will be before this one applies (a per-key
            setting's partial mapping updates ``pending[name]``).
        """
        from drivers.errors import DeviceValueError

        info_ = device._info
        if self.per is None:
            return self._one(device, self.name, value, info_, None)
        keys = list(info_[self.per])
        if not isinstance(value, Mapping):
            raise device._error(
                DeviceValueError, f"{self.name} {value!r} is not one value per "
                f"{self.key_name}", f"give a value for each {self.key_name} to change "
                f"({', '.join(keys)}), e.g. {{'{keys[0]}': ...}}")
        out = dict(pending[self.name])
        for key, v in value.items():
            if not isinstance(key, str) or key not in keys:
                raise device._error(DeviceValueError, f"unknown {self.key_name} {key!r}",
                                    f"use one of {keys}")
            out[key] = self._one(device, f"{self.name}[{key}]", v, info_, key)
        return out

    def _one(self, device: Any, label: str, value: Any, info_: Mapping[str, Any],
             key: str | None) -> Any:
        low, high = _resolve(self.low, info_, key), _resolve(self.high, info_, key)
        if self.check is not None:
            return self.check(device, label, value, low, high)
        if self.dtype == "float":
            if self.positive:
                value = device._float(label, value, low=0.0, low_open=True)
            return device._float(label, value, low=low, high=high, low_open=self.low_open)
        if self.dtype == "int":
            return device._int(label, value, low=low, high=high)
        return device._choice(label, value, _resolve(self.choices, info_, key))

    # ----------------------------------------------------------- description
    def unit_of(self, key: str | None = None) -> str:
        """The unit, for one key of a per-key setting (``"{unit}"`` filled)."""
        if "{unit}" not in self.unit:
            return self.unit
        if key is None or self.key_units is None:
            return self.unit.replace("{unit}", f"{self.key_name} unit")
        return self.unit.replace("{unit}", self.key_units[key])

    def limits_text(self, info_: Mapping[str, Any] | None = None) -> str:
        """The limits as an operator reads them.

        With the open device's info: numbers (``"1e-05 to 10 s"``,
        ``"x <= 20 mm/s; y <= 20 mm/s"``, ``"one of mono8, mono12"``); without:
        where they come from (``"info.exposure_range_s[0] to ... s"``).
        """
        if self.per is not None and info_ is not None:
            return "; ".join(f"{k} {self._range_text(info_, k)}".rstrip()
                             for k in info_[self.per])
        return self._range_text(info_, None)

    def _range_text(self, info_: Mapping[str, Any] | None, key: str | None) -> str:
        unit = self.unit_of(key)
        if self.bounds is not None:
            if info_ is None:
                return _FIELD.sub(lambda m: "info." + m.group(1), self.bounds)
            fields = {"key": key, **info_}
            return self.bounds.replace("{key}", str(key)).format(**fields)
        if self.choices is not None:
            choices = _resolve(self.choices, info_, key)
            return "one of " + (self.choices.text if choices is None else ", ".join(choices))
        low, high = (_resolve(v, info_, key) if info_ is not None else v
                     for v in (self.low, self.high))
        if info_ is None:
            return self._range_words(low, high, unit).replace("<key>", self.key_name)
        return self._range_words(low, high, unit)

    def _range_words(self, low: Any, high: Any, unit: str) -> str:
        if low is None and high is None:
            return "> 0" if self.positive else ""
        if low is None:
            return f"<= {_text(high)} {unit}".rstrip()
        lo = f"{_text(low)} (excl.)" if self.low_open else _text(low)
        return f"{lo} to {_text(high) if high is not None else 'inf'} {unit}".rstrip()

    def describe(self, info_: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """A JSON-able description (for a GUI's rows, a schema, the docs).

        Parameters
        ----------
        info_ : Mapping, optional
            The open device's info: limits and choices are then numbers and lists
            (per key for a per-key setting); without it they are the info paths.

        Returns
        -------
        dict
            ``name``, ``dtype``, ``unit``, ``description``, ``read_only``, ``per``,
            ``low``, ``high``, ``low_open``, ``positive``, ``choices``, ``limits``
            (:meth:`limits_text`), ``tags``.
        """
        def value(v: Any) -> Any:
            if not isinstance(v, FromInfo):
                return list(v) if isinstance(v, tuple) else v
            if info_ is None:
                return {"info": v.text}
            if self.per is None:
                return v(info_)
            return {k: v(info_, k) for k in info_[self.per]}

        return {
            "name": self.name, "dtype": self.dtype, "unit": self.unit_of(),
            "description": self.description, "read_only": self.read_only, "per": self.per,
            "low": value(self.low), "high": value(self.high), "low_open": self.low_open,
            "positive": self.positive, "choices": value(self.choices),
            "limits": self.limits_text(info_), "tags": sorted(self.tags),
        }


def setting_property(name: str, doc: str) -> property:
    """A read-write property for the setting ``name`` of a device kind.

    Reading returns the device's current value (``Device._get``: the device must be
    open); writing validates and applies it (``Device._set``, through
    :meth:`~drivers.base.Device.apply_settings`).

    Parameters
    ----------
    name : str
        The setting's name in the kind's ``SETTINGS``.
    doc : str
        The property's docstring (meaning, unit, range).

    Returns
    -------
    property
    """
    def fget(self: Any) -> Any:
        return self._get(name)

    def fset(self: Any, value: Any) -> None:
        self._set(name, value)

    return property(fget, fset, doc=doc)


def with_settings(base: tuple[Setting, ...], *changes: Setting,
                  remove: tuple[str, ...] = ()) -> tuple[Setting, ...]:
    """A driver's table: ``base`` with same-named settings replaced (in place), new
    ones appended, and ``remove`` left out.

    Example: ``SETTINGS = with_settings(Camera.SETTINGS,
    Camera.setting("gain").replace(high=12.0))`` caps a camera's gain at 12 dB.
    """
    by_name = {s.name: s for s in changes}
    out = tuple(by_name.pop(s.name, s) for s in base if s.name not in remove)
    return out + tuple(by_name.values())


def _row(s: Setting) -> str:
    dtype = s.dtype if s.per is None else f"{{{s.key_name}: {s.dtype}}}"
    notes = [s.description] + (["read-only"] if s.read_only else []) + (
        ["not while streaming"] if "stream_locked" in s.tags else [])
    cells = [f"`{s.name}`", f"`{dtype}`", s.unit_of(), s.limits_text(),
             "; ".join(n for n in notes if n)]
    return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"


_HEADER = ["| setting | type | unit | limits | description |", "|---|---|---|---|---|"]


def settings_markdown(kinds: Mapping[str, type], drivers: tuple[type, ...] = ()) -> str:
    """The settings tables of the documentation, generated from the declarations.

    Parameters
    ----------
    kinds : Mapping[str, type]
        ``{title: Device subclass}``, e.g. ``{"camera": Camera}``.
    drivers : tuple of type
        Driver classes; those whose table differs from their kind's get a section
        with the rows they change or add.

    Returns
    -------
    str
        Markdown: one table per kind (setting, type, unit, limits, description).
    """
    lines = ["# Device settings", "",
             "Generated from the declarations in `drivers/` (`Device.SETTINGS`) by "
             "`python -m instrument.writer.docpage`; do not edit by hand. `info.*` limits are "
             "read from the open device (`Device.info`); a mapping setting takes a "
             "partial `{key: value}` and keeps the other keys.", ""]
    for title, cls in kinds.items():
        lines += [f"## {title} (`{cls.__module__}.{cls.__name__}`)", "", *_HEADER]
        lines += [_row(s) for s in cls.SETTINGS] + [""]
    by_kind = {cls.kind: cls for cls in kinds.values()}
    changed = [(d, [s for s in d.SETTINGS if s not in by_kind[d.kind].SETTINGS],
                [n for n in by_kind[d.kind]._SPECS if n not in d._SPECS])
               for d in drivers if d.SETTINGS != by_kind[d.kind].SETTINGS]
    if changed:
        lines += ["## Drivers that change their kind's settings", ""]
    for d, rows, removed in changed:
        lines += [f"### `{d.__module__}.{d.__name__}` ({d.kind})", "", *_HEADER]
        lines += [_row(s) for s in rows] + [""]
        if removed:
            lines += ["Not offered: " + ", ".join(f"`{n}`" for n in removed) + ".", ""]
    return "\n".join(lines)


_PY_TYPES = {"float": float, "int": int, "str": str, "(float, float)": tuple[float, float],
             "int[4]": tuple[int, int, int, int], "float[256]": list[float]}


def settings_model(cls: type) -> type:
    """A pydantic model of the writable settings of device class ``cls``.

    Every field is optional (a file may hold some settings); static limits and
    choices are checked, limits read from a device's info are named in the field's
    description (they are checked when the settings reach the open device).
    ``settings_model(Camera).model_json_schema()`` is the JSON schema.

    Parameters
    ----------
    cls : type
        A :class:`~drivers.base.Device` subclass.

    Returns
    -------
    type
        A ``pydantic.BaseModel`` subclass named ``<Class>Settings``, refusing
        unknown names.
    """
    from typing import Annotated, Literal

    import pydantic

    fields: dict[str, Any] = {}
    for s in cls.SETTINGS:
        if s.read_only:
            continue
        if s.dtype == "str" and isinstance(s.choices, tuple):
            kind: Any = Literal[s.choices]
        else:
            kind = _PY_TYPES[s.dtype]
        limits: dict[str, float] = {}
        if s.dtype in ("float", "int") and s.check is None:
            if s.positive:
                limits["gt"] = 0
            if isinstance(s.low, int | float):
                limits["gt" if s.low_open else "ge"] = s.low
            if isinstance(s.high, int | float):
                limits["le"] = s.high
        kind = Annotated[kind, pydantic.Field(**limits)] if limits else kind
        if s.per is not None:
            kind = dict[str, kind]
        unit = s.unit_of()
        text = f"{s.description}" + (f" [{unit}]" if unit else "") + (
            f"; limits: {s.limits_text()}" if s.limits_text() else "")
        fields[s.name] = (kind | None, pydantic.Field(None, description=text))
    return pydantic.create_model(f"{cls.__name__}Settings",
                                 __config__=pydantic.ConfigDict(extra="forbid"), **fields)

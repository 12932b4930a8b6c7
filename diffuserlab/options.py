"""Typed parameter models from which command-line options and GUI forms are generated.

Layer 0, so every layer declares its parameters with it: the calibration routines'
(:mod:`calibration_routines.parameters`) and the reconstruction's
(:class:`recon.options.ReconOptions`). A command's parameters are one pydantic
model (a subclass of :class:`Options`), each field declared with :func:`option`
(help, unit, limits, the command-line flag). From the model come:

- the ``argparse`` options (:meth:`Options.add_arguments`: flag, type, default,
  choices, required, help with the unit, the limits and the default);
- a form's fields (:meth:`Options.specs`: one :class:`OptionSpec` per field);
- the validated value from a parsed command line (:meth:`Options.from_namespace`),
  from a form's texts (:meth:`Options.from_text`) or from a Python call's keywords
  (:meth:`Options.validated` with ``front="python"``), a bad value raising
  :class:`diffuserlab.errors.InputError` that names the option as that front end
  spells it (``--tv`` on the command line, ``tv=`` in Python) and its limits;
- documentation tables (:meth:`Options.markdown`).

The declarations import nothing heavy (a command's parser and ``--help`` are built
without pydantic); the pydantic model that validates is made on first use.
"""

from __future__ import annotations

import argparse
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

from diffuserlab.errors import InputError

__all__ = ["OptionSpec", "Options", "option"]


def option(default: Any = ..., *, help: str, unit: str = "", flag: str | None = None,
           default_text: str = "", parse: Any = None, metavar: str | None = None,
           kinds: tuple[str, ...] = (), methods: tuple[str, ...] = (), label: str = "",
           **limits: Any) -> Any:
    """A field of an :class:`Options` model.

    Parameters
    ----------
    default : object
        The default; ``...`` for a required option; None for "chosen by the plan"
        (``help`` then says how).
    help : str
        What the value is, without the unit (``"nearest depth"``).
    unit : str
        SI unit (``"mm"``, ``"s"``, ``"deg"``); ``""`` for a count or a name.
    flag : str, optional
        The command-line option, default ``--`` + the name with dashes
        (``z_min_mm`` -> ``--z-min-mm``).
    default_text : str
        What a None default means (``"the camera's current one"``).
    parse : callable, optional
        Text to value, for a value that is more than a number or a name (``"auto"`` or
        a number, a dark run): the command line's ``type`` and a form's conversion;
        it raises ValueError or ``argparse.ArgumentTypeError`` on bad text.
    metavar : str, optional
        The value's name in ``--help`` (``auto|none|DN|DARK_RUN``).
    kinds, methods : tuple of str
        Who uses the value (the reconstruction's model kinds and methods); empty:
        every one.
    label : str
        A short name of the value for messages (``"TV weight"``); default ``help``.
    **limits
        pydantic's ``gt``, ``ge``, ``lt``, ``le`` and ``allow_inf_nan``.
    """
    unknown = set(limits) - {"gt", "ge", "lt", "le", "allow_inf_nan"}
    if unknown:
        raise TypeError("option() takes the limits gt, ge, lt, le, allow_inf_nan, not "
                        f"{sorted(unknown)}")
    return _Option(default, help, unit, flag, default_text, limits, parse, metavar,
                   tuple(kinds), tuple(methods), label)


@dataclass(frozen=True)
class _Option:
    """A field's declaration (what :func:`option` returns)."""

    default: Any
    help: str
    unit: str
    flag: str | None
    default_text: str
    limits: dict
    parse: Any = None
    metavar: str | None = None
    kinds: tuple[str, ...] = ()
    methods: tuple[str, ...] = ()
    label: str = ""


def _num(v: Any) -> str:
    if isinstance(v, tuple | list):
        return " ".join(_num(x) for x in v)
    return f"{v:g}" if isinstance(v, int | float) else str(v)


@dataclass(frozen=True)
class OptionSpec:
    """One field of an :class:`Options` model as a command line and a form need it.

    Attributes
    ----------
    dest : str
        The field's name.
    flag : str
        The command-line option (``--z-min``).
    type : type
        ``int``, ``float``, ``str`` or ``bool`` (an on/off flag).
    default : object
        None: chosen by the plan; ``...``: required.
    required : bool
    choices : tuple of str or None
    unit : str
    description : str
        The declared help, without the unit.
    limits : str
        ``"> 0"``, ``"8 to 256"``, ``""``.
    default_text : str
        What a None default means.
    nargs : int or None
        The number of values of a tuple option (``--sim-translation-px TX TY``).
    parse : callable or None
        Text to value where it is more than ``type`` (:func:`option`).
    metavar : str or None
    kinds, methods : tuple of str
        Who uses the value (empty: every one).
    label : str
        A short name for messages (default: the description).
    """

    dest: str
    flag: str
    type: type
    default: Any
    required: bool
    choices: tuple[str, ...] | None
    unit: str
    description: str
    limits: str
    default_text: str = ""
    nargs: int | None = None
    parse: Any = None
    metavar: str | None = None
    kinds: tuple[str, ...] = ()
    methods: tuple[str, ...] = ()
    label: str = ""

    @property
    def kind_text(self) -> str:
        """What a value is, in words: ``"a whole number"``, ``"a number or auto"``."""
        kind = {int: "a whole number", float: "a number"}.get(self.type, "text")
        return kind + "".join(f" or {c}" for c in self.choices or ()
                              ) if self.type is not str else kind

    def name(self, front: str = "cli") -> str:
        """The option as a front end spells it: ``--bin`` (``"cli"``) or
        ``bin_factor=`` (``"python"``)."""
        return self.flag if front == "cli" else f"{self.dest}="

    @property
    def is_flag(self) -> bool:
        """An on/off option (``store_true``)."""
        return self.type is bool

    @property
    def help(self) -> str:
        """The help text: description, unit, limits, default."""
        text = self.description + (f", {self.unit}" if self.unit else "")
        if self.limits:
            text += f"; {self.limits}"
        if self.required:
            text += " (required)"
        elif self.default is not None and not self.is_flag:
            text += f" (default {_num(self.default)})"
        elif self.default_text:
            text += f" (default: {self.default_text})"
        return text


#: pydantic's error types of a value outside its limits.
_LIMIT_ERRORS = ("greater_than", "greater_than_equal", "less_than", "less_than_equal")


def _limits_text(limits: Mapping[str, Any]) -> str:
    limits = {k: v for k, v in limits.items() if k != "allow_inf_nan"}
    low_open, high_open = "gt" in limits, "lt" in limits
    low = limits.get("gt", limits.get("ge"))
    high = limits.get("lt", limits.get("le"))
    if low is None and high is None:
        return ""
    if high is None:
        return f"{'>' if low_open else '>='} {_num(low)}"
    if low is None:
        return f"{'<' if high_open else '<='} {_num(high)}"
    return (f"{_num(low)}{' (excl.)' if low_open else ''} to {_num(high)}"
            f"{' (excl.)' if high_open else ''}")


def _field(pydantic, kind: Any, opt: _Option) -> tuple[Any, Any]:
    """A pydantic field of a declaration: a union's numeric member (``float`` of
    ``float | Literal["auto"]``) carries the limits, the other members none."""
    members = typing.get_args(kind)
    if opt.limits and typing.get_origin(kind) in (typing.Union, types.UnionType) and any(
            m in (int, float) for m in members):
        kind = typing.Union[tuple(  # noqa: UP007 (members built at run time)
            typing.Annotated[m, pydantic.Field(**opt.limits)] if m in (int, float) else m
            for m in members)]
        return kind, pydantic.Field(opt.default, description=opt.help)
    return kind, pydantic.Field(opt.default, description=opt.help, **opt.limits)


def _base_type(annotation: Any) -> tuple[type, tuple[str, ...] | None, int | None]:
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        names = tuple(str(c) for a in args if typing.get_origin(a) is Literal
                      for c in typing.get_args(a))
        others = [a for a in args if typing.get_origin(a) is not Literal]
        if names and others:  # a number or a name: tv is a weight or "auto"
            return others[0], names, None
        annotation = args[0]
    if typing.get_origin(annotation) is Literal:
        return str, tuple(str(c) for c in typing.get_args(annotation)), None
    if typing.get_origin(annotation) is tuple:
        items = typing.get_args(annotation)
        return items[0], None, len(items)
    return annotation, None, None


class Options:
    """Base of a command's parameter model (see the module docstring).

    Subclasses declare fields as ``name: type = option(...)``; an instance holds the
    validated values as attributes and is frozen.
    """

    #: The command the options belong to, for messages (``"calibrate psf-sweep"``).
    command: ClassVar[str] = ""
    _fields: ClassVar[dict[str, tuple[Any, _Option]]] = {}
    _pydantic: ClassVar[Any] = None

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        fields: dict[str, tuple[Any, _Option]] = {}
        for klass in reversed(cls.__mro__):
            decl = {k: v for k, v in vars(klass).items() if isinstance(v, _Option)}
            if decl:
                hints = typing.get_type_hints(klass)
                for name, opt in decl.items():
                    fields[name] = (hints[name], opt)
        cls._fields = fields
        cls._pydantic = None

    def __init__(self, **values: Any) -> None:
        object.__setattr__(self, "_values", dict(values))
        for name, value in values.items():
            object.__setattr__(self, name, value)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} is frozen: build a new one")

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and other._values == self._values

    def __hash__(self) -> int:
        return hash((type(self), tuple(sorted(map(repr, self._values.items())))))

    def __repr__(self) -> str:
        inner = ", ".join(f"{k}={v!r}" for k, v in self._values.items())
        return f"{type(self).__name__}({inner})"

    def model_dump(self) -> dict[str, Any]:
        """The values, ``{field: value}``."""
        return dict(self._values)

    def replace(self, **changes: Any):
        """A copy with ``changes`` (values a caller derived from validated ones, e.g. the
        solver an automatic method resolves to); not validated again."""
        unknown = set(changes) - set(type(self)._fields)
        if unknown:
            raise TypeError(f"{type(self).__name__} has no field {sorted(unknown)}")
        return type(self)(**{**self._values, **changes})

    @classmethod
    def from_defaults(cls, **changes: Any):
        """The declared defaults with ``changes``: the options a library call below the
        front door starts from (values checked where they are used, not validated
        here, as :meth:`replace`).

        Raises
        ------
        TypeError
            A name that is no field.
        """
        unknown = set(changes) - set(cls._fields)
        if unknown:
            raise TypeError(f"{cls.__name__} has no field {sorted(unknown)}")
        return cls(**{**cls.defaults(), **changes})

    @classmethod
    def _model(cls):
        """The pydantic model that validates (made on first use)."""
        if cls.__dict__.get("_pydantic") is None:
            import pydantic

            fields = {name: _field(pydantic, kind, opt) for name, (kind, opt)
                      in cls._fields.items()}
            cls._pydantic = pydantic.create_model(
                f"{cls.__name__}Model", __config__=pydantic.ConfigDict(extra="forbid"),
                **fields)
        return cls._pydantic

    @classmethod
    def model_json_schema(cls) -> dict[str, Any]:
        """The JSON schema of the options (pydantic's)."""
        return cls._model().model_json_schema()

    @classmethod
    def specs(cls) -> list[OptionSpec]:
        """One :class:`OptionSpec` per field, in declaration order."""
        out = []
        for name, (annotation, opt) in cls._fields.items():
            kind, choices, nargs = _base_type(annotation)
            flag = opt.flag or "--" + name.replace("_", "-")
            required = opt.default is ...
            out.append(OptionSpec(name, flag, kind, opt.default, required, choices, opt.unit,
                                  opt.help, _limits_text(opt.limits), opt.default_text,
                                  nargs, opt.parse, opt.metavar, opt.kinds, opt.methods,
                                  opt.label))
        return out

    @classmethod
    def spec(cls, name: str) -> OptionSpec:
        """The :class:`OptionSpec` of field ``name``."""
        return next(s for s in cls.specs() if s.dest == name)

    @classmethod
    def add_arguments(cls, parser, containers: Mapping[str, Any] | None = None, *,
                      fields: tuple[str, ...] | None = None,
                      overrides: Mapping[str, Mapping[str, Any]] | None = None) -> None:
        """Add one ``argparse`` option per field to ``parser``.

        Parameters
        ----------
        parser : argparse.ArgumentParser
        containers : Mapping, optional
            ``{field: group}``: add that field's option to another container (a
            mutually exclusive group) instead.
        fields : tuple of str, optional
            Only these fields, in this order (a command that takes some of them).
        overrides : Mapping, optional
            ``{field: {argparse keyword: value}}``: what one command says or accepts
            differently (a narrower ``choices``, a ``help`` naming its own
            behaviour); the default stays the declared one.
        """
        specs = {s.dest: s for s in cls.specs()}
        for name in fields or tuple(specs):
            s = specs[name]
            target = (containers or {}).get(s.dest, parser)
            extra = dict((overrides or {}).get(s.dest, {}))
            text = s.help.replace("%", "%%")  # argparse formats help with %
            if s.is_flag:
                target.add_argument(s.flag, action="store_true", dest=s.dest,
                                    help=extra.get("help", text))
                continue
            kw: dict[str, Any] = {"dest": s.dest, "help": text,
                                  "type": s.parse or (s.type if s.type in (int, float)
                                                      else str)}
            if s.metavar:
                kw["metavar"] = s.metavar
            if s.choices and s.type is str:
                kw["choices"] = s.choices
            if s.nargs:
                kw["nargs"] = s.nargs
            if s.required:
                kw["required"] = True
            else:
                kw["default"] = s.default
            kw.update(extra)
            target.add_argument(s.flag, **kw)

    @classmethod
    def validated(cls, data: Mapping[str, Any], *, front: str = "cli"):
        """The model of ``data`` (``{field: value}``).

        Parameters
        ----------
        data : Mapping
        front : {"cli", "python"}
            How a message names the option: its flag (``--tv``) or its keyword
            (``tv=``).

        Raises
        ------
        diffuserlab.errors.InputError
            A value outside its limits, of the wrong type, not among the choices, or a
            required one missing; the message names the option, its limits and unit;
            values that cannot be used together (:meth:`check_together`).
        """
        import pydantic

        try:
            model = cls._model().model_validate(dict(data))
        except pydantic.ValidationError as exc:
            raise InputError(cls._message(exc.errors()[0], front)) from None
        values = dict(model)
        for name, value in data.items():  # a parsed value keeps its own type (DarkOption)
            if name in cls._fields and cls._fields[name][1].parse is not None:
                values[name] = value
        cls.check_together(values, front=front)
        return cls(**values)

    @classmethod
    def check_together(cls, values: Mapping[str, Any], *, front: str = "cli") -> None:
        """The checks between fields (what one option's value asks of another's), run by
        :meth:`validated` after each field's own; a model with such rules overrides
        this (here: none).

        Parameters
        ----------
        values : Mapping
            ``{field: value}``; a field left out has its declared default.
        front : {"cli", "python"}
            How a message names the options (as :meth:`validated`).

        Raises
        ------
        diffuserlab.errors.InputError
            Values that cannot be used together (the message names both and the fix).
        """

    @classmethod
    def _message(cls, err: Mapping[str, Any], front: str = "cli") -> str:
        name = str(err["loc"][0]) if err.get("loc") else ""
        if name not in cls._fields:
            return f"{cls.command}: {err.get('msg')}"
        s = cls.spec(name)
        flag = s.name(front)
        what = (s.label or s.description) + (f" in {s.unit}" if s.unit not in ("",
                                                                             "unitless")
                                             else "")
        if err["type"] == "missing":
            return f"give {flag} ({what})"
        value = err.get("input")
        given = f"{flag}{value!r}" if front == "python" else f"{flag} {value!r}"
        if s.choices and s.type is str:
            return f"{given}: use one of {', '.join(s.choices)}"
        if err["type"] == "finite_number":
            return f"{given}: give a finite number ({what})"
        if s.limits and err["type"] in _LIMIT_ERRORS:
            unit = "" if s.unit == "unitless" else s.unit
            return (f"{given} is outside its limits: {what} must be {s.limits}"
                    f" {unit}").rstrip()
        return f"{given}: give {s.kind_text} ({what})"

    @classmethod
    def from_namespace(cls, args: argparse.Namespace):
        """The model of a parsed command line (its fields' ``dest``); InputError as
        :meth:`validated`."""
        return cls.validated({s.dest: getattr(args, s.dest) for s in cls.specs()
                              if hasattr(args, s.dest)})

    @classmethod
    def from_text(cls, values: Mapping[str, Any]):
        """The model of a form's values ``{flag or field: text or bool}``; an empty
        text takes the default.

        Raises
        ------
        diffuserlab.errors.InputError
            Text that is not a number where one is needed (``"--n-depths: 'many' is
            not a whole number"``), and as :meth:`validated`.
        """
        by_key = {s.flag: s for s in cls.specs()} | {s.dest: s for s in cls.specs()}
        data: dict[str, Any] = {}
        for key, value in values.items():
            s = by_key.get(key)
            if s is None:
                raise InputError(f"{cls.command}: unknown option {key!r}; use one of "
                                 f"{[x.flag for x in cls.specs()]}")
            if s.is_flag:
                data[s.dest] = bool(value)
                continue
            text = "" if value is None else str(value).strip()
            if not text:
                continue
            if s.parse is not None:
                try:
                    data[s.dest] = s.parse(text)
                except (ValueError, TypeError, argparse.ArgumentTypeError) as exc:
                    why = (f"is not {s.kind_text}" if s.type in (int, float)
                           else f"is refused: {exc}")
                    raise InputError(f"{s.flag}: {text!r} {why}") from None
            elif s.type in (int, float):
                parts = text.replace(",", " ").split() if s.nargs else [text]
                what = "a whole number" if s.type is int else "a number"
                if s.nargs and len(parts) != s.nargs:
                    raise InputError(f"{s.flag}: {text!r} is not {s.nargs} numbers")
                try:
                    values_ = [s.type(p) for p in parts]
                except ValueError:
                    raise InputError(f"{s.flag}: {text!r} is not {what}") from None
                data[s.dest] = tuple(values_) if s.nargs else values_[0]
            else:
                data[s.dest] = text
        return cls.validated(data)

    @classmethod
    def bounds(cls, name: str) -> dict[str, Any]:
        """The declared limits of field ``name`` (``{"ge": 1, "le": 50}``), for a form's
        spin box."""
        return dict(cls._fields[name][1].limits)

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """``{field: declared default}`` (the very objects the declarations hold)."""
        return {name: opt.default for name, (_, opt) in cls._fields.items()}

    @classmethod
    def markdown(cls) -> str:
        """A Markdown table of the options (option, type, unit, limits, default, what)."""
        used = any(s.kinds or s.methods for s in cls.specs())
        rows = ["| option | type | unit | limits | default | description |"
                + (" used by |" if used else ""),
                "|---|---|---|---|---|---|" + ("---|" if used else "")]
        for s in cls.specs():
            kind = ("flag" if s.is_flag else "one of " + ", ".join(s.choices)
                    if s.choices and s.type is str else
                    " or ".join((s.type.__name__, *(s.choices or ()))))
            if s.nargs:
                kind += f" x {s.nargs}"
            default = ("required" if s.required else "off" if s.is_flag else
                       (s.default_text or "-") if s.default is None else _num(s.default))
            cells = [f"`{s.flag}`", kind, s.unit, s.limits, default, s.description]
            if used:
                cells.append(", ".join((*s.kinds, *s.methods)) or "all")
            rows.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
        return "\n".join(rows)

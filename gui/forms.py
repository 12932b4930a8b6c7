"""Forms generated from a parameter declaration (:class:`diffuserlab.options.Options`).

One builder makes the GUI's forms of the reconstruction's parameters (the Record
panel's batch form, the Live panel's settings, the napari Reconstruct widget) from the
declarations the command line is generated from (:class:`recon.options.ReconOptions`,
:class:`recon.options.LiveOptions`, ``recon-run``'s
:class:`instrument.options.RunOptions`), as a settings collection makes its
widgets: a new declared field appears in each form that takes its command's fields.

Each field becomes one widget, by its declared type and choices:

- an on/off flag: a :class:`QCheckBox`;
- a name among choices (``method``): a :class:`QComboBox` of the choices;
- a number or a name (``tv``: a weight or ``auto``): an editable :class:`QComboBox`
  offering the names, showing the default;
- a whole number with a default: a :class:`QSpinBox` within the declared limits; a
  number with both limits declared: a :class:`QDoubleSpinBox`;
- anything else (a path, an optional number, a dark level): a :class:`QLineEdit`
  whose placeholder says what empty means (the default).

:meth:`OptionsForm.texts` reads the widgets as ``{field: text}`` (a value left at its
default is left out, so the declared default object is kept, as argparse keeps it);
:meth:`OptionsForm.values` turns them into the validated options object
(:meth:`~diffuserlab.options.Options.from_text`: types, choices, limits and the
checks between fields, :meth:`~diffuserlab.options.Options.check_together`);
:meth:`OptionsForm.set_values` shows an options object.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QGridLayout,
    QLabel,
    QLineEdit,
    QSpinBox,
    QWidget,
)

from diffuserlab.options import Options, OptionSpec

from .fields import remember, wheel_needs_focus

__all__ = ["LABELS", "OptionsForm", "field_label", "lay_out"]

#: Form labels of the fields whose declaration names none (``option(label=...)``),
#: by field name.
LABELS = {"method": "method", "iterations": "ADMM iterations per frame",
          "allow_mixed_ranges": "mixed ranges", "overwrite": "overwrite product"}

#: The largest value a spin box offers when the declaration sets no upper limit.
_INT_MAX = 2**31 - 1


def field_label(spec: OptionSpec) -> str:
    """A field's form label: its declared ``label`` (else :data:`LABELS`), with the unit
    (``"time budget (s)"``).

    Raises
    ------
    KeyError
        A field with no label declared and none in :data:`LABELS`.
    """
    text = spec.label or LABELS[spec.dest]
    return text + (f" ({spec.unit})" if spec.unit not in ("", "unitless") else "")


def _text(value: Any) -> str:
    """A value as a form shows it (``200``, ``0.001``, ``auto``)."""
    if isinstance(value, bool) or value is None:
        return ""
    if isinstance(value, int | float):
        return f"{value:g}"
    return str(value)


class OptionsForm:
    """The widgets of some fields of an :class:`~diffuserlab.options.Options` class.

    Parameters
    ----------
    options : type of Options
        The declaration (``ReconOptions``).
    fields : iterable of str
        The fields shown, in order (a command's, e.g.
        :data:`instrument.options.COMMAND_FIELDS`).
    name : str
        Prefix of the widgets' object names (``batch`` -> ``batch--iterations``).
    remember_as : str, optional
        Settings group under which each value is remembered between sessions
        (:func:`gui.fields.remember`; ``batch`` -> ``batch/iterations``).
    widgets : mapping, optional
        ``{field: widget}``: a widget the caller made for a field (the depth field
        that offers a stack's depths), read by its text.

    Attributes
    ----------
    widgets : dict
        ``{field: QWidget}`` in form order.
    labels : dict
        ``{field: QLabel}``.
    """

    def __init__(self, options: type[Options], fields: Iterable[str], *, name: str = "",
                 remember_as: str | None = None,
                 widgets: Mapping[str, QWidget] | None = None) -> None:
        self.options = options
        self.specs = {s.dest: s for s in options.specs()}
        self.widgets: dict[str, QWidget] = {}
        self.labels: dict[str, QLabel] = {}
        for field in fields:
            spec = self.specs[field]
            widget = (widgets or {}).get(field) or self._widget(spec)
            if not widget.objectName():
                widget.setObjectName(f"{name}{spec.flag}")
            if not widget.toolTip():
                widget.setToolTip(spec.help)
            if remember_as:
                remember(widget, f"{remember_as}/{spec.flag[2:]}")
            self.widgets[field] = widget
            self.labels[field] = QLabel(field_label(spec) + ":")
            self.labels[field].setToolTip(spec.help)

    # -- building ------------------------------------------------------------------------
    def _widget(self, s: OptionSpec) -> QWidget:
        if s.is_flag:
            box = QCheckBox(field_label(s))
            box.setChecked(bool(s.default))
            return box
        if s.choices and s.nargs is None:
            combo = QComboBox()
            combo.addItems(list(s.choices))
            if s.type is not str:  # a number or a name: typed, or a name picked
                combo.setEditable(True)
            combo.setCurrentText(_text(s.default))
            wheel_needs_focus(combo)
            return combo
        limits = self.options.bounds(s.dest)
        low = limits.get("ge", limits.get("gt"))
        high = limits.get("le", limits.get("lt"))
        if s.type is int and s.parse is None and s.nargs is None and isinstance(
                s.default, int):
            spin = QSpinBox()
            spin.setRange(int(low) if low is not None else -_INT_MAX,
                          int(high) if high is not None else _INT_MAX)
            spin.setValue(s.default)
            wheel_needs_focus(spin)
            return spin
        if (s.type is float and s.parse is None and s.nargs is None and low is not None
                and high is not None and isinstance(s.default, int | float)):
            spin = QDoubleSpinBox()
            spin.setDecimals(3)
            spin.setRange(float(low), float(high))
            spin.setSingleStep((float(high) - float(low)) / 100)
            spin.setValue(float(s.default))
            wheel_needs_focus(spin)
            return spin
        edit = QLineEdit()
        edit.setPlaceholderText(s.default_text if s.default is None else _text(s.default))
        return edit

    # -- reading and showing -------------------------------------------------------------
    @staticmethod
    def widget_text(widget: QWidget) -> str | bool:
        """What ``widget`` holds: its text, or a check box's state."""
        if isinstance(widget, QCheckBox):
            return widget.isChecked()
        if isinstance(widget, QComboBox):
            return widget.currentText().strip()
        if isinstance(widget, QSpinBox | QDoubleSpinBox):
            return f"{widget.value():g}"
        return widget.text().strip()

    def texts(self, *, flags: bool = False) -> dict[str, str | bool]:
        """The values the operator set, ``{field: text or bool}`` (``{flag: ...}`` with
        ``flags``); a value left empty or at its default is left out (the declared
        default object is kept)."""
        out: dict[str, str | bool] = {}
        for field, widget in self.widgets.items():
            s = self.specs[field]
            value = self.widget_text(widget)
            if isinstance(value, bool):
                if value != bool(s.default):
                    out[s.flag if flags else field] = value
            elif value and value != _text(s.default):
                out[s.flag if flags else field] = value
        return out

    def values(self):
        """The form's values as the validated options object (the fields not shown take
        their defaults).

        Raises
        ------
        diffuserlab.errors.InputError
            A value the field's type, choices or limits refuse, or values that cannot be
            used together; the message names the flag (``--iterations 0 is outside its
            limits: ...``).
        """
        return self.options.from_text(self.texts())

    def set_values(self, values: Options) -> None:
        """Show ``values`` (an options object of the form's declaration) in the widgets;
        a default shows as the empty field's placeholder."""
        for field, widget in self.widgets.items():
            value = getattr(values, field)
            default = self.specs[field].default
            if isinstance(widget, QCheckBox):
                widget.setChecked(bool(value))
            elif isinstance(widget, QComboBox):
                widget.setCurrentText(_text(value))
            elif isinstance(widget, QSpinBox | QDoubleSpinBox):
                widget.setValue(value)
            else:
                widget.setText("" if value is default or value is None else _text(value))

    def flag_labels(self) -> dict[str, str]:
        """``{flag: label}`` of the fields shown, for messages that name a flag
        (:func:`gui.messages.operator_text`)."""
        return {self.specs[f].flag: field_label(self.specs[f]) for f in self.widgets}

    def rows(self, fields: Iterable[str] | None = None) -> list[tuple[QWidget, QWidget]]:
        """``(label, widget)`` of ``fields`` (default: all, in form order); a check box
        carries its own label (the label cell stays empty)."""
        out = []
        for f in fields or self.widgets:
            widget = self.widgets[f]
            out.append((QLabel("") if isinstance(widget, QCheckBox) else self.labels[f],
                        widget))
        return out


def lay_out(grid: QGridLayout, rows: list[tuple[QWidget, QWidget]], *, row: int = 0,
            columns: int = 1) -> int:
    """Put ``(label, widget)`` pairs into ``grid`` from ``row``, ``columns`` pairs per
    row (label, then widget); returns the next free row."""
    for i, (label, widget) in enumerate(rows):
        r, c = row + i // columns, 2 * (i % columns)
        grid.addWidget(label, r, c)
        grid.addWidget(widget, r, c + 1)
    return row + (len(rows) + columns - 1) // columns

"""Messages for people: the library's messages as an operator at the GUI reads them.

The library writes its messages for the command line and for code (``--depth``,
``call reconnect()``, ``resume() to continue``, ``-inf <= x <= 60``). The GUI shows
the same problem and fix in its own words: a command-line option becomes the name of
the field that holds it, an API call the button that does it, an unbounded range its
one bound. :func:`operator_text` does that translation; the panels pass it the labels
of their fields.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from diffuserlab.processes import how_it_ended

__all__ = ["how_it_ended", "operator_text"]

#: API calls in device and runner messages, and the GUI's way of doing them.
_CALLS = (
    (re.compile(r"\b(then )?call (?:faults\.allow_reconnect\(\), then )?reconnect\(\)"
                r"(?: and start the stream again)?"),
     r"\1press Reconnect on the device (Devices panel)"),
    (re.compile(r" \(faults\.disconnect\(\)\)"), ""),  # the simulated bench's fault
    (re.compile(r"\breconnect\(\)"), "Reconnect (Devices panel)"),
    (re.compile(r"resume\(\) to continue, abort\(\) to stop"),
     "press Continue to go on or Abort to stop"),
    (re.compile(r"call open\(\) first or use the device as a context manager"),
     "press Connect on the Devices panel"),
    (re.compile(r"resume with `diffuserlab calibrate resume [^`]*` or "
                r"Runner\(bench\)\.resume\('[^']*'\)"),
     "press Resume run on the Calibration panel to go on from there"),
    (re.compile(r" or Runner\(bench\)\.resume\('[^']*'\)"), ""),
    (re.compile(r"\bcall stop_stream\(\) (?:first|before a new stream)"),
     "stop the live stream first (Stop stream on the Live panel)"),
    (re.compile(r"\bsnap\(\) while streaming"), "a snapshot while the camera streams"),
    (re.compile(r"\bresume\(\)"), "Resume"),
    (re.compile(r"\[Errno \d+\] "), ""),  # the OS's number: the reason's words stay
)
_NUMBER = r"[-+]?[0-9][0-9.e+-]*"
_RANGES = (
    (re.compile(r"-inf <= (\w+) <= inf"), r"a finite number for \1"),
    (re.compile(rf"-inf <= (\w+) <= ({_NUMBER})"), r"\1 <= \2"),
    (re.compile(rf"({_NUMBER}) <= (\w+) <= inf"), r"\2 >= \1"),
    (re.compile(rf"({_NUMBER}) < (\w+) <= inf"), r"\2 > \1"),
    (re.compile(r"-inf\s*(?:\.\.|to)\s*inf"), "no limit"),
)
#: A setting refused by its range, as the device interface words it for code.
_OUT_OF_RANGE = re.compile(r"\b([a-z_]+(?:\[\w+\])?)=(\S+) is not a number in range")
_FLAG = re.compile(r"(?<![\w-])--([a-z][a-z0-9-]*)")
_COMMAND = re.compile(r"`diffuserlab [^`]*`")


def operator_text(text: str, labels: Mapping[str, str] | None = None) -> str:
    """``text`` with command-line options, API calls and open ranges put in the GUI's terms.

    Parameters
    ----------
    text : str
        A message written by the library (problem and fix).
    labels : mapping, optional
        ``{flag: label}``: the GUI field that holds each command-line option
        (``{"--depth": "depth (mm)"}``); other options are named by their words
        (``--z-min`` becomes 'z min').

    Returns
    -------
    str
        The message with every ``--flag`` replaced by its field's name in quotes,
        every API call by the button that does it, and ``-inf``/``inf`` bounds dropped.
    """
    labels = dict(labels or {})
    out = text
    for pattern, repl in _CALLS:
        out = pattern.sub(repl, out)
    for pattern, repl in _RANGES:
        out = pattern.sub(repl, out)
    out = _OUT_OF_RANGE.sub(lambda m: f"{m.group(1)} {m.group(2)} is out of range", out)

    def flag(m: re.Match) -> str:
        name = labels.get(f"--{m.group(1)}") or m.group(1).replace("-", " ")
        return f"'{name.rstrip(':')}'"

    out = _FLAG.sub(flag, out)
    return _COMMAND.sub("the command line", out)

"""Device status as an operator reads it: a state word and a few named fields.

:meth:`drivers.base.Device.status` is a dict for code (``is_open``, ``disconnected``,
``positions``, ``dropped_frames``, ...). :func:`device_state` turns it into the state
the status area shows (open, streaming, moving, disconnected, closed) with its
colour, :func:`status_fields` into labelled fields for the device's box (a driver's
nested setup dicts, e.g. the APT controllers' parameters, are left to the log), and
:func:`status_line` into the short line of the window's permanent status area. The
camera's exposure comes from its settings (cached by the interface: no device I/O).
"""

from __future__ import annotations

from typing import Any

__all__ = ["STATE_COLOURS", "device_state", "status_fields", "status_line"]

#: Colour of each state in the status area.
STATE_COLOURS = {"disconnected": "#c00020", "closed": "#808080", "moving": "#b06000",
                 "streaming": "#006000", "open": "#004080", "unknown": "#808080"}
_SKIP = {"device_id", "kind", "driver", "is_open", "disconnected", "streaming", "moving",
         "positions", "homed", "ring", "time_s"}


def device_state(status: dict[str, Any]) -> str:
    """``"disconnected"``, ``"closed"``, ``"moving"``, ``"streaming"`` or ``"open"``."""
    if not status:
        return "unknown"
    if status.get("disconnected"):
        return "disconnected"
    if not status.get("is_open"):
        return "closed"
    if status.get("moving"):
        return "moving"
    if status.get("streaming"):
        return "streaming"
    return "open"


def _number(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _exposure(settings: dict[str, Any] | None) -> str | None:
    if not settings or "exposure_s" not in settings:
        return None
    e = float(settings["exposure_s"])
    return f"{1e3 * e:.3g} ms" if e < 1.0 else f"{e:.3g} s"


def status_fields(kind: str, status: dict[str, Any],
                  settings: dict[str, Any] | None = None) -> list[tuple[str, str]]:
    """``[(label, text)]`` for a device's box: state first, then the kind's fields.

    Parameters
    ----------
    kind : str
        The device kind (``camera``, ``stage``, ...).
    status : dict
        :meth:`drivers.base.Device.status`.
    settings : dict, optional
        The device's cached settings (the camera's exposure and frame rate).

    Returns
    -------
    list of tuple
        Texts in the operator's words (a driver's message such as "call reconnect()"
        read by :func:`gui.messages.operator_text`).
    """
    from drivers.stage import AXIS_UNITS

    from .messages import operator_text

    out = [("state", device_state(status))]
    if kind == "camera":
        exposure = _exposure(settings)
        if exposure:
            out.append(("exposure", exposure))
        if settings and "frame_rate_hz" in settings:
            out.append(("frame rate", f"{float(settings['frame_rate_hz']):.4g} Hz"))
    if kind == "stage" and isinstance(status.get("positions"), dict):
        out.append(("position", ", ".join(
            f"{a} {v:.4f} {AXIS_UNITS.get(a, '')}".rstrip()
            for a, v in status["positions"].items())))
        homed = status.get("homed")
        if isinstance(homed, dict) and homed:
            done = [a for a, h in homed.items() if h]
            out.append(("homed", ", ".join(done) if done else "no axis"))
    for key, value in status.items():
        if key in _SKIP or value is None:
            continue
        if isinstance(value, dict):
            if any(isinstance(v, dict) for v in value.values()):
                continue  # a driver's setup per axis or controller: for code and the log
            if all(isinstance(v, list | tuple) for v in value.values()):
                # per-axis flags (a Zaber axis's warnings): the axes that have some
                value = "; ".join(f"{k} {', '.join(map(str, v))}" for k, v in value.items()
                                  if v) or "none"
            else:
                value = ", ".join(f"{k} {_number(v)}" for k, v in value.items())
        elif isinstance(value, list | tuple):
            value = ", ".join(_number(v) for v in value)
        text = _number(value)
        if isinstance(value, str):  # a driver's message: in the GUI's words
            text = operator_text(text)
        out.append((key.replace("_", " "), text))
    return out


def status_line(device_id: str, kind: str, status: dict[str, Any],
                settings: dict[str, Any] | None = None) -> str:
    """The status area's line of one device: ``"camera: streaming, 10 ms"``."""
    state = device_state(status)
    extra = ""
    if state not in ("disconnected", "closed") and kind == "camera":
        extra = _exposure(settings) or ""
    elif state == "moving" and isinstance(status.get("positions"), dict):
        extra = ", ".join(f"{a} {v:.2f}" for a, v in status["positions"].items()
                          if a in ("x", "y", "z"))
    return f"{device_id}: {state.upper() if state == 'disconnected' else state}" + (
        f", {extra}" if extra else "")

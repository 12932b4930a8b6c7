"""Resume identity: is the bench that resumes a run the bench that started it?

A run store records the bench configuration it was started with (``bench_config``:
the bench file as parsed), the plan (name, parameters, points) and the software
version. Before a resume captures anything, :func:`resume_differences` compares
them with the bench and software at hand and classifies each difference:

``fatal``
    The data would mix two set-ups: another device set (ids, kinds, drivers),
    another optical geometry, another driver parameter that is not a connection
    detail (sensor shape, stage axes, pitches, ...), or a camera whose frames have
    another shape or dtype. Never accepted: start a new run.
``acceptable``
    Harmless for the data but recorded: the bench name or description, connection
    details of a device (:data:`CONNECTION_PARAMS`: a serial port that moved, a new
    address), the calibration defaults section (the plan's own parameters are
    recorded and used as stored), the software version. Refused unless the
    operator accepts them explicitly (``calibrate resume --accept-differences``).

The runner records every resume with its bench configuration, software version and
the differences accepted (``resumes`` in the store's attributes).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

__all__ = ["CONNECTION_PARAMS", "Difference", "bench_differences", "format_differences",
           "resume_differences"]

#: Driver parameters that say how to reach a device, not what it measures: a
#: difference in these is acceptable on resume (with the explicit flag).
CONNECTION_PARAMS = frozenset({
    "port", "serial_port", "serial_number", "serial_numbers", "address", "host", "ip",
    "url", "device_index", "baudrate", "timeout_s", "usb_vendor_id", "usb_product_id",
})


@dataclass(frozen=True)
class Difference:
    """One difference between the recorded and the current set-up.

    Attributes
    ----------
    where : str
        Dotted location, e.g. ``geometry.diffuser_sensor_distance_mm`` or
        ``devices.source_stage.params.port``.
    recorded, current : Any
        The two values (None: absent on that side).
    severity : {"fatal", "acceptable"}
        See the module docstring.
    """

    where: str
    recorded: Any
    current: Any
    severity: Literal["fatal", "acceptable"]

    def __str__(self) -> str:
        return f"{self.where}: {_short(self.recorded)} -> {_short(self.current)}"


def _short(value: Any, limit: int = 40) -> str:
    text = "absent" if value is None else repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _walk(where: str, a: Any, b: Any, severity: str, out: list[Difference]) -> None:
    """Append the leaf differences of two JSON-like values."""
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        for key in sorted(set(a) | set(b), key=str):
            _walk(f"{where}.{key}", a.get(key), b.get(key), severity, out)
    elif a != b:
        out.append(Difference(where, a, b, severity))


def _devices(config: Mapping[str, Any]) -> dict[str, Mapping[str, Any]]:
    return {str(d.get("id")): d for d in config.get("devices", []) or []}


def bench_differences(recorded: Mapping[str, Any],
                      current: Mapping[str, Any]) -> list[Difference]:
    """Every difference between two bench configurations (``BenchConfig.model_dump(
    mode="json")`` dictionaries), classified as in the module docstring.

    An empty ``recorded`` (a run started without a bench configuration) matches
    only an empty ``current``.
    """
    if not recorded or not current:
        if bool(recorded) != bool(current):
            return [Difference("bench_config", "recorded" if recorded else None,
                               "given" if current else None, "fatal")]
        return []
    out: list[Difference] = []
    rec_dev, cur_dev = _devices(recorded), _devices(current)
    for dev_id in sorted(set(rec_dev) | set(cur_dev)):
        a, b = rec_dev.get(dev_id), cur_dev.get(dev_id)
        where = f"devices.{dev_id}"
        if a is None or b is None:
            out.append(Difference(where, a and f"{a.get('kind')} {a.get('driver')}",
                                  b and f"{b.get('kind')} {b.get('driver')}", "fatal"))
            continue
        for key in ("kind", "driver"):
            _walk(f"{where}.{key}", a.get(key), b.get(key), "fatal", out)
        pa, pb = a.get("params") or {}, b.get("params") or {}
        for key in sorted(set(pa) | set(pb)):
            severity = "acceptable" if key in CONNECTION_PARAMS else "fatal"
            _walk(f"{where}.params.{key}", pa.get(key), pb.get(key), severity, out)
    _walk("geometry", recorded.get("geometry"), current.get("geometry"), "fatal", out)
    _walk("branches", recorded.get("branches"), current.get("branches"), "fatal", out)
    skip = {"devices", "geometry", "branches"}
    for key in sorted((set(recorded) | set(current)) - skip):
        _walk(key, recorded.get(key), current.get(key), "acceptable", out)
    return out


def resume_differences(attrs: Mapping[str, Any], *, stored_frame: tuple[Sequence[int], str],
                       bench_config: Mapping[str, Any], frame: tuple[Sequence[int], str],
                       software_version: str) -> list[Difference]:
    """The differences between a stored run and the set-up resuming it.

    Parameters
    ----------
    attrs : Mapping
        The run store's attributes (``instrument.runs.runstore.RunStore.attrs``).
    stored_frame : (shape, dtype)
        The run's frame ``(rows, cols)`` and dtype name (e.g. ``"uint16"``).
    bench_config : Mapping
        The resuming bench's configuration (JSON dump; empty if it has none).
    frame : (shape, dtype)
        What the camera delivers now, as ``stored_frame``.
    software_version : str
        The running diffuserlab version.

    Returns
    -------
    list of Difference
        Empty when the set-ups match.
    """
    out = bench_differences(attrs.get("bench_config") or {}, bench_config)
    for i, name in enumerate(("frame_shape", "frame_dtype")):
        a, b = stored_frame[i], frame[i]
        a, b = (list(map(int, a)), list(map(int, b))) if i == 0 else (str(a), str(b))
        if a != b:
            out.append(Difference(f"camera.{name}", a, b, "fatal"))
    if attrs.get("software_version") != software_version:
        out.append(Difference("software_version", attrs.get("software_version"),
                              software_version, "acceptable"))
    return out


def format_differences(differences: Sequence[Difference], limit: int = 6) -> str:
    """One line listing ``differences`` (the first ``limit``, then how many more)."""
    shown = "; ".join(str(d) for d in differences[:limit])
    more = len(differences) - limit
    return shown + (f"; and {more} more" if more > 0 else "")

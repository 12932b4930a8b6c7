"""Units and dimension names of a run's per-frame coordinates, from one source.

A run stores one row of coordinates per frame (:class:`instrument.runs.runstore.RunStore`,
``coords``); each coordinate's unit and dimension name are written into the store's
metadata when it is created and read back with it
(:meth:`~instrument.runs.runstore.RunStore.coord_info`, ``diffuserlab runs show``).
They come from:

- the device declarations (:class:`drivers.settings.Setting`): a camera setting
  stored per frame (``exposure_s`` in s, ``gain`` in dB) takes the unit of the
  bench camera's declaration (of the camera kind's when no camera is given); a
  setting of another device (``led_array.brightness``) that device's declaration;
- a stage's axes: ``source_stage.z`` takes the unit its stage declares for axis
  ``z`` (the per-axis unit of its ``limits`` setting, mm; rad for a rotation);
- :data:`FRAME_COORDS` for what is no setting (timestamps, counts, indices).

The dimension name is what a coordinate measures along: the axis of a stage
coordinate (``z``), the setting's name for a setting (``gain``), else the entry of
:data:`FRAME_COORDS` (``time``, ``count``, ``index``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from diffuserlab.errors import DiffuserLabError

__all__ = ["FRAME_COORDS", "CoordError", "coord_specs"]

#: Coordinates that are no device setting: ``{name: (unit, dimension name)}``; for a
#: device coordinate (``<device id>.<name>``) the key is the part after the dot.
FRAME_COORDS: dict[str, tuple[str, str]] = {
    "device_timestamp_s": ("s", "time"),
    "host_time_unix_s": ("s", "time"),
    "host_timestamp_s": ("s", "time"),
    "saturated_pixels": ("px", "count"),
    "frame_index": ("", "index"),
    "n_lit": ("", "count"),
    "first_lit": ("", "index"),
    "pattern_id": ("", "index"),
    "running": ("", "state"),
}


class CoordError(DiffuserLabError, ValueError):
    """A coordinate whose unit nothing declares (a device or recorder that names a
    coordinate without declaring it: a bug in the driver or the plan, not an input)."""


def _declaration(cls: type, name: str):
    specs = getattr(cls, "_SPECS", {})
    return specs.get(name)


def coord_specs(names: Iterable[str], devices: Mapping[str, Any] | None = None
                ) -> dict[str, dict[str, str]]:
    """The unit and dimension name of each coordinate in ``names``.

    Parameters
    ----------
    names : iterable of str
        Coordinate names as a run stores them: a camera's (``"exposure_s"``,
        ``"gain"``, ``"frame_index"``) or a device's (``"source_stage.z"``,
        ``"led_array.brightness"``).
    devices : Mapping, optional
        ``{device id: open device}`` of the bench (its camera's and stages'
        declarations give the units); without it a bare name takes the camera
        kind's declaration.

    Returns
    -------
    dict
        ``{name: {"unit": str, "dim": str}}`` (``""``: dimensionless) in the order of
        ``names``.

    Raises
    ------
    CoordError
        A name that is no declared setting, no axis of its stage and not in
        :data:`FRAME_COORDS` (declare it there or in its device's settings).
    """
    from drivers.camera import Camera

    devices = dict(devices or {})
    camera = next((type(d) for d in devices.values() if d.kind == "camera"), Camera)
    out: dict[str, dict[str, str]] = {}
    for name in names:
        dev_id, _, key = name.rpartition(".")
        device = devices.get(dev_id) if dev_id else None
        cls = type(device) if device is not None else camera
        if dev_id and device is None:
            raise CoordError(f"coordinate {name!r}: the bench has no device {dev_id!r}")
        if device is not None and device.kind == "stage" and key in device.axes:
            unit = type(device).setting("limits").unit_of(key)
            out[name] = {"unit": unit, "dim": key}
        elif (spec := _declaration(cls, key)) is not None:
            out[name] = {"unit": spec.unit_of(), "dim": key}
        elif key in FRAME_COORDS:
            unit, dim = FRAME_COORDS[key]
            out[name] = {"unit": unit, "dim": dim}
        else:
            raise CoordError(f"coordinate {name!r} has no declared unit: declare it as a "
                             "setting of its device or in instrument.runs.coords.FRAME_COORDS")
    return out

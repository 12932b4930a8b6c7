"""TIFF files Fiji and the OME tools open with axes, spacing and units.

:func:`write_tiff` writes one array of a run (its frames or a product) as

- an ImageJ hyperstack (``format="imagej"``, what Fiji opens as a stack with its
  pixel size, z spacing and origin (``zorigin``, in slices: the first plane at its
  depth) or frame interval and unit; the run's metadata as JSON in the ``Info``
  property, one slice label per plane), or
- an OME-TIFF (``format="ome"``: OME-XML with ``PhysicalSizeX/Y/Z`` in µm and
  ``TimeIncrement`` in s, each plane's depth as its ``PositionZ`` in µm where the
  array records ``depths_mm``, each plane's time as its ``DeltaT`` in s where the
  frames' timestamps are recorded; the run's metadata as JSON in the image's
  ``Description``),

with the axes of the run's OME-Zarr description (:mod:`instrument.runs.ome`): ``t`` (time)
becomes T with its interval, ``z`` with a unit Z with its spacing (the mean spacing
for unevenly spaced depths, each depth in the metadata), any other first axis (a
sweep's frames, a ``c`` or unitless ``z`` axis, a run's names from before) a Z (a
product) or a T (frames) without spacing, its values in the metadata. An array that is no image (a
table, a 1-D LUT) is written as a plain TIFF with tifffile's JSON metadata.
:func:`read_tiff_metadata` reads the JSON back from any of the three.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .ome import OmeAxis

__all__ = ["TIFF_FORMATS", "read_tiff_metadata", "tiff_format", "write_tiff"]

#: Formats of :func:`write_tiff`; "auto" is OME-TIFF for a ``.ome.tif(f)`` name, else
#: an ImageJ hyperstack.
TIFF_FORMATS = ("auto", "imagej", "ome")
#: Data types an ImageJ hyperstack holds; others are stored as float32.
_IMAGEJ_DTYPES = (np.uint8, np.uint16, np.float32)


def tiff_format(path: str | Path, fmt: str = "auto") -> str:
    """``"imagej"`` or ``"ome"``: ``fmt``, or for ``"auto"`` by the name of ``path``."""
    if fmt not in TIFF_FORMATS:
        raise ValueError(f"format {fmt!r}: use one of {list(TIFF_FORMATS)}")
    if fmt != "auto":
        return fmt
    return "ome" if Path(path).name.lower().endswith((".ome.tif", ".ome.tiff")) else "imagej"


def _first_letter(axis: OmeAxis, frames: bool) -> str:
    if axis.type == "time":
        return "T"
    if axis.type == "space":
        return "Z"
    return "T" if frames else "Z"


def write_tiff(path: str | Path, array: np.ndarray, axes: Sequence[OmeAxis] | None,
               meta: Mapping[str, Any], *, fmt: str = "imagej", frames: bool = False,
               labels: Sequence[str] | None = None,
               delta_t_s: Sequence[float] | None = None) -> None:
    """Write ``array`` as an ImageJ hyperstack or an OME-TIFF (module notes).

    Parameters
    ----------
    path : str or Path
        The file to write (the caller makes it atomic), written by
        :func:`instrument.writer.files.write_tiff_file`.
    array : ndarray, (planes, rows, cols) or (rows, cols)
    axes : sequence of OmeAxis or None
        The array's axes (:func:`instrument.runs.ome.product_axes`); None: no image, a
        plain TIFF with JSON metadata.
    meta : Mapping
        JSON-able metadata stored with it (read back by :func:`read_tiff_metadata`).
    fmt : {"imagej", "ome"}
    frames : bool
        The array is a run's frames (a custom first axis is then T, not Z).
    labels : sequence of str, optional
        One label per plane (ImageJ slice labels).
    delta_t_s : sequence of float, optional
        Each plane's time, s from the first (its recorded timestamp): an OME-TIFF's
        per-plane ``DeltaT`` (Bio-Formats reads it, bioio its standard metadata's
        ``timelapse_interval``), written for a time axis (``T``).

    Raises
    ------
    ValueError
        ``axes`` that do not match the array's rank, or an unknown format.
    """
    from ..writer.files import write_tiff_file
    from ..writer.products import tiff_resolution

    meta = dict(meta)
    if axes is None or array.ndim not in (2, 3):
        write_tiff_file(path, array, metadata=meta, photometric="minisblack")
        return
    if len(axes) != array.ndim:
        raise ValueError(f"{len(axes)} axes for a {array.ndim}-D array")
    letters = ("" if array.ndim == 2 else _first_letter(axes[0], frames)) + "YX"
    y = axes[-2]
    pitch = y.scale if y.unit == "micrometer" else None
    first = axes[0] if array.ndim == 3 else None
    if fmt == "imagej":
        if array.dtype.type not in _IMAGEJ_DTYPES:
            meta["stored_dtype"] = f"float32 (the array is {array.dtype})"
            array = array.astype(np.float32)
        ij: dict[str, Any] = {"axes": letters, "Info": json.dumps(meta)}
        if pitch is not None:
            ij["unit"] = "um"
        if first is not None and first.type == "time" and first.unit == "second":
            ij["finterval"] = first.scale
        if first is not None and first.type == "space" and first.unit == "micrometer":
            ij["spacing"] = first.scale
            if first.origin and first.scale:  # ImageJ: z = (slice - zorigin) * spacing
                ij["zorigin"] = -first.origin / first.scale
        if labels is not None and array.ndim == 3:
            ij["Labels"] = list(labels)
        res = None if pitch is None else (1.0 / pitch, 1.0 / pitch)
        write_tiff_file(path, array, imagej=True, resolution=res, metadata=ij)
        return
    if fmt != "ome":
        raise ValueError(f"format {fmt!r}: use 'imagej' or 'ome'")
    om: dict[str, Any] = {"axes": letters, "Name": str(meta.get("product", "frames")),
                          "Description": json.dumps(meta)}
    if pitch is not None:
        for a in "XY":
            om[f"PhysicalSize{a}"], om[f"PhysicalSize{a}Unit"] = pitch, "µm"
    if first is not None and first.type == "space" and first.unit == "micrometer":
        om["PhysicalSizeZ"], om["PhysicalSizeZUnit"] = first.scale, "µm"
        depths = meta.get("depths_mm")
        if isinstance(depths, list) and len(depths) == array.shape[0]:  # each plane's
            om["Plane"] = {"PositionZ": [float(z) * 1000.0 for z in depths],
                           "PositionZUnit": ["µm"] * len(depths)}
    if first is not None and first.type == "time" and first.unit == "second":
        om["TimeIncrement"], om["TimeIncrementUnit"] = first.scale, "s"
    if (first is not None and letters[0] == "T" and delta_t_s is not None
            and len(delta_t_s) == array.shape[0]):  # each plane's recorded time
        om["Plane"] = {"DeltaT": [round(float(t), 9) for t in delta_t_s],
                       "DeltaTUnit": ["s"] * array.shape[0]}
    write_tiff_file(path, array, ome=True, metadata=om, photometric="minisblack",
                    **tiff_resolution(pitch))


def read_tiff_metadata(tif) -> dict:
    """The JSON metadata of an open ``tifffile.TiffFile`` written by :func:`write_tiff`
    (ImageJ ``Info``, OME ``Description`` or tifffile's shaped metadata); empty when
    it has none."""
    try:
        if tif.is_imagej and tif.imagej_metadata and "Info" in tif.imagej_metadata:
            return dict(json.loads(tif.imagej_metadata["Info"]))
        if tif.is_ome and tif.ome_metadata:
            import tifffile

            image = tifffile.xml2dict(tif.ome_metadata)["OME"]["Image"]
            image = image[0] if isinstance(image, list) else image
            return dict(json.loads(image.get("Description") or "{}"))
    except (ValueError, TypeError, KeyError):  # not our JSON: no metadata
        return {}
    return dict(tif.shaped_metadata[0] or {}) if tif.shaped_metadata else {}

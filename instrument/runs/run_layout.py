"""A run store's arrays against the layout the run recorded when it wrote them.

Checksums (:mod:`instrument.runs.run_integrity`) are taken of the decoded values, so they
cannot see an array's ``zarr.json`` edited to describe its bytes otherwise: frames
of ``uint16`` relabelled ``float16`` decode to the same bytes (their checksums
hold) but mean other numbers, and a shape cut to fewer frames leaves the run's
bookkeeping pointing past the end. So a run records each array's *data-defining*
metadata when it creates it, and every open compares the files with that record:

* ``shape``, ``data_type``, ``chunk_grid`` (chunk shape), ``chunk_key_encoding``,
  ``codecs`` (compressors, sharding) and ``fill_value`` of each array, copied from its
  ``zarr.json`` (:data:`LAYOUT_KEYS`; attributes and ``dimension_names`` are not data
  and may change, e.g. when OME-Zarr metadata is added);
* the run's own arrays in the root attribute ``arrays`` (written by
  :meth:`RunStore.create <instrument.runs.runstore.RunStore.create>`, again when a video
  is cut to the frames it holds), products in the ``arrays`` attribute of
  ``products/`` (written with each product), keyed by the array's path there:
  ``NAME/0`` for an image product's group, ``NAME`` for a table, a LUT, a per-frame
  product's hidden arrays and every product of a run written before the image
  groups (``runs upgrade`` renames the key when it moves the array,
  :func:`instrument.runs.product_nodes.regroup`).

A run written before the record was kept is checked for what can be known without
it (:func:`unrecorded_problems`): the per-frame arrays agree on the number of frames
and with the plan, the bookkeeping arrays have their fixed dtypes, a frame chunk
holds whole frames. The frames' dtype cannot be checked there, and
:func:`layout_note` says so.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

__all__ = ["FRAME_ARRAYS", "LAYOUT_KEYS", "RUN_ARRAYS", "array_layout", "layout_note",
           "layout_problems", "node_metadata", "record_layout", "unrecorded_problems"]

#: The fields of an array's ``zarr.json`` that define how its bytes are read.
LAYOUT_KEYS = ("shape", "data_type", "chunk_grid", "chunk_key_encoding", "codecs",
               "fill_value")
#: The run's own arrays (``point`` and ``tag`` are read when the run opens).
RUN_ARRAYS = ("frames", "coords", "crc32", "done", "point", "tag")
#: The arrays a frame's read needs.
FRAME_ARRAYS = ("frames", "coords", "crc32", "done")
#: The fixed dtypes of the bookkeeping arrays (checked on runs without a record).
_FIXED_DTYPES = {"coords": "float64", "crc32": "uint32", "done": "uint8", "point": "int32",
                 "tag": "int16"}
#: Attribute (of the root group and of ``products/``) holding the record.
ATTR = "arrays"


def node_metadata(path: str | Path) -> dict | None:
    """The ``zarr.json`` of the node (array or group) at ``path`` as a dict; None when
    missing, unreadable or not a JSON object."""
    try:
        meta = json.loads(Path(path, "zarr.json").read_text())
    except (OSError, ValueError):
        return None
    return meta if isinstance(meta, dict) else None


def array_layout(path: str | Path) -> dict[str, Any] | None:
    """The data-defining fields (:data:`LAYOUT_KEYS`) of the array stored at ``path``.

    Parameters
    ----------
    path : str or Path
        The array's folder (holding its ``zarr.json``).

    Returns
    -------
    dict or None
        ``{key: value}`` as the file holds them (JSON values); None when the file is
        missing or unreadable.
    """
    meta = node_metadata(path)
    return None if meta is None else {k: meta.get(k) for k in LAYOUT_KEYS}


def record_layout(group, root: Path, names: Iterable[str]) -> None:
    """Record (update) the layout of the arrays ``names`` under ``root`` in ``group``'s
    ``arrays`` attribute (``group`` is the zarr group whose folder is ``root``)."""
    record = dict(group.attrs.get(ATTR) or {})
    for name in names:
        layout = array_layout(Path(root) / name)
        if layout is not None:
            record[name] = layout
    group.attrs[ATTR] = record


def forget_layout(group, names: Iterable[str]) -> None:
    """Remove ``names`` from ``group``'s record (a product deleted on purpose)."""
    record = dict(group.attrs.get(ATTR) or {})
    if any(n in record for n in names):
        group.attrs[ATTR] = {k: v for k, v in record.items() if k not in set(names)}


def _short(value: Any) -> str:
    if isinstance(value, Mapping | list):
        text = json.dumps(value, separators=(",", ":"))
        return text if len(text) <= 60 else text[:57] + "..."
    return repr(value)


def _first_difference(have: Any, want: Any, where: str) -> tuple[str, Any, Any]:
    """The first place two metadata values differ: ``(path, have, want)``, the path
    written as ``codecs[1].configuration.level`` (a long value's head can hide it)."""
    if isinstance(have, Mapping) and isinstance(want, Mapping):
        for k in [*want, *(k for k in have if k not in want)]:
            if have.get(k) != want.get(k):
                return _first_difference(have.get(k), want.get(k), f"{where}.{k}")
    elif isinstance(have, list) and isinstance(want, list) and len(have) == len(want):
        for i, (a, b) in enumerate(zip(have, want, strict=True)):
            if a != b:
                return _first_difference(a, b, f"{where}[{i}]")
    return where, have, want


def _difference_text(key: str, have: Any, want: Any) -> tuple[str, str]:
    """``(what it says, what was recorded)`` for one metadata key: whole when short,
    else down to the first differing entry of the nested value."""
    if not (_short(have).endswith("...") or _short(want).endswith("...")):
        return f"{key} {_short(have)}", f"{key} {_short(want)}"
    where, a, b = _first_difference(have, want, key)
    return f"{where} {_short(a)}", f"{where} {_short(b)}"


def _recorded(path: Path) -> dict[str, dict]:
    """The record of the run at ``path``: ``{name: layout}`` for its own arrays and
    ``{"products/NAME": layout}`` for products (empty where none was kept)."""
    out: dict[str, dict] = {}
    for prefix, folder in (("", path), ("products/", path / "products")):
        meta = node_metadata(folder) or {}
        record = (meta.get("attributes") or {}).get(ATTR) or {}
        if isinstance(record, Mapping):
            out.update({prefix + k: v for k, v in record.items() if isinstance(v, Mapping)})
    return out


def layout_problems(path: str | Path, attrs: Mapping[str, Any]) -> dict[str, str]:
    """Every array of the run at ``path`` whose metadata differs from its record.

    Parameters
    ----------
    path : str or Path
        The run store.
    attrs : Mapping
        The run's attributes (its ``plan``'s ``frames_per_point``, its
        ``schema_version``: a schema-1 run has no ``crc32``).

    Returns
    -------
    dict
        ``{array name: problem line}`` (``"frames"``, ``"products/psf_stack"``, ...),
        each line naming the fields that differ, the recorded values and the repair;
        empty when every array matches. A product whose folder is gone is not listed
        here (:func:`instrument.runs.runstore_records.record_problems` reports it).
    """
    path = Path(path)
    record = _recorded(path)
    problems: dict[str, str] = {}
    for name, want in record.items():
        have = array_layout(path / name)
        if have is None:
            # the open names a missing array it needs, record_problems a missing product;
            # without crc32 a run would read as one that carries no checksums
            if name == "crc32" and attrs.get("schema_version") != 1:
                problems[name] = (f"{path}/crc32/zarr.json is missing or unreadable, so no "
                                  "frame can be verified: restore crc32/ from a backup copy "
                                  "of the run")
            continue
        differ = [k for k in LAYOUT_KEYS if k in want and have.get(k) != want[k]]
        if differ:
            pairs = [_difference_text(k, have.get(k), want[k]) for k in differ]
            now = ", ".join(a for a, _ in pairs)
            then = ", ".join(b for _, b in pairs)
            problems[name] = (
                f"{path}/{name}/zarr.json is damaged: it says {now}, but the run recorded "
                f"{then} when it wrote the array, so its data cannot be read as stored; put "
                f"the recorded values back in {name}/zarr.json or restore it from a backup "
                "copy of the run")
    if not any(n in record for n in RUN_ARRAYS):
        problems.update(unrecorded_problems(path, attrs["plan"]))
    return problems


def unrecorded_problems(path: str | Path, plan: Mapping[str, Any]) -> dict[str, str]:
    """What can be checked of a run written before its layout was recorded (module
    notes): frame counts, the bookkeeping arrays' dtypes, whole frames per chunk."""
    path = Path(path)
    per_point = plan.get("frames_per_point") or []
    n = sum(int(v) for v in per_point if isinstance(v, int))
    problems: dict[str, str] = {}
    fix = "restore it from a backup copy of the run"
    for name in RUN_ARRAYS:
        have = array_layout(path / name)
        if have is None:
            continue  # opening the run reports an array that is missing
        shape = have.get("shape") or []
        dtype = _FIXED_DTYPES.get(name)
        if not shape or shape[0] != n:
            problems[name] = (f"{path}/{name}/zarr.json is damaged: it holds "
                              f"{shape[0] if shape else 'no'} frame slots but the plan "
                              f"records {n}; {fix}")
        elif dtype is not None and have.get("data_type") != dtype:
            problems[name] = (f"{path}/{name}/zarr.json is damaged: its data_type is "
                              f"{have.get('data_type')!r}, a run's {name} is always "
                              f"{dtype!r}; put {dtype!r} back or {fix}")
        elif name == "frames":
            chunk = _inner_chunk(have)
            if chunk is not None and list(chunk[1:]) != list(shape[1:]):
                problems[name] = (f"{path}/frames/zarr.json is damaged: its chunks are "
                                  f"{chunk}, not whole frames of {shape[1:]}; {fix}")
    return problems


def _inner_chunk(layout: Mapping[str, Any]) -> list | None:
    """The chunk shape of one frame: the sharding codec's inner chunk, or the grid's."""
    for codec in layout.get("codecs") or []:
        if isinstance(codec, Mapping) and codec.get("name") == "sharding_indexed":
            return (codec.get("configuration") or {}).get("chunk_shape")
    return ((layout.get("chunk_grid") or {}).get("configuration") or {}).get("chunk_shape")


def layout_note(path: str | Path) -> str | None:
    """A line for a run written before its layout was recorded (what its check
    cannot see), None when the run carries the record."""
    if any(n in _recorded(Path(path)) for n in RUN_ARRAYS):
        return None
    return (f"{path} was written before runs recorded their array layout: frame counts "
            "and the bookkeeping arrays are checked, the frames' dtype and compression "
            "cannot be")

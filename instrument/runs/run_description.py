"""What other tools read of a run, against what the run wrote (part of
:meth:`RunStore.verify <instrument.runs.runstore.RunStore.verify>`).

OME-Zarr readers (ome-zarr-py, napari, Fiji) and xarray read neither a run's checksums
nor its layout record (:mod:`instrument.runs.run_layout`): they read the ``ome`` block of the
root group (the frames) and of each image product's group, and each array's
``dimension_names`` (:mod:`instrument.runs.ome`). A block edited or deleted (a pixel size
times 10, axes reversed) leaves every checksum intact, yet those tools then show
other sizes or axes. So each time the run writes that metadata it records it, and
:func:`description_problems` compares the files with the record:

* the root's attribute ``described``: ``{".": {"ome": ...}}`` for the root group
  itself and ``{NAME: {"dimension_names": [...]}}`` for each of its arrays;
  ``products/``'s attribute ``described``: the same for ``products/`` itself
  (``"."``: the ``ome`` block of a run written before the image groups, or None),
  each image group ``NAME``, each product array (``NAME/0`` or ``NAME``) and the
  hidden arrays of a per-frame product (``NAME__crc32``, ``NAME__done``); an ``ome``
  of None records that the group had none;
* recorded by whoever writes the metadata: :meth:`RunStore.create
  <instrument.runs.runstore.RunStore.create>` (the run's arrays), the product writers (a
  product's arrays), :func:`instrument.runs.ome.describe_run` and
  :func:`instrument.runs.ome.describe_products` (the ``ome`` blocks, and the dimension
  names ``runs upgrade`` sets; a block derived from dimension names that differ from
  their record is written but not recorded, :func:`as_recorded`); a product replaced
  or deleted by the run drops its entries, an array ``runs upgrade`` moves into its
  group takes its entry along (:func:`instrument.runs.product_nodes.regroup`), and ``runs
  upgrade`` records what a run written before lacks, as it is then.

Only what was recorded is compared: a run written before the record (see
:func:`description_note`) verifies as it did.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from .run_layout import node_metadata

__all__ = ["ATTR", "SELF", "as_recorded", "description_note", "description_problems",
           "forget_description", "node_description", "record_description"]

#: Attribute (of the root group and of ``products/``) holding the record.
ATTR = "described"
#: The record's key of the group that holds it.
SELF = "."
#: Most characters of a value shown in a problem line.
_SHOWN = 60


def node_description(folder: str | Path) -> dict[str, Any] | None:
    """What other tools read of the Zarr node at ``folder``.

    Parameters
    ----------
    folder : str or Path
        The node's folder (holding its ``zarr.json``).

    Returns
    -------
    dict or None
        ``{"ome": block or None}`` for a group, ``{"dimension_names": list or None}``
        for an array (JSON values as the file holds them); None when the file is
        missing, unreadable or no Zarr node.
    """
    meta = node_metadata(folder)
    if meta is None:
        return None
    if meta.get("node_type") == "array":
        return {"dimension_names": meta.get("dimension_names")}
    attrs = meta.get("attributes")
    return {"ome": attrs.get("ome") if isinstance(attrs, Mapping) else None}


def _record(group) -> dict[str, Any]:
    record = group.attrs.get(ATTR)
    return dict(record) if isinstance(record, Mapping) else {}


def record_description(group, folder: str | Path, names: Iterable[str], *,
                       missing_only: bool = False) -> None:
    """Record (update) what other tools read of the nodes ``names`` in ``group``'s
    ``described`` attribute, as their files hold it now.

    Parameters
    ----------
    group : zarr.Group
        The group holding the record (the run's root or ``products/``), writable.
    folder : str or Path
        ``group``'s folder.
    names : iterable of str
        Paths of nodes under ``folder`` (``"."``: ``group`` itself); a node that is
        not there is skipped.
    missing_only : bool
        Record only nodes the record lacks (what ``runs upgrade`` adds to a run
        written before), never replacing an entry.
    """
    record = _record(group)
    new = dict(record)
    for name in names:
        if missing_only and name in new:
            continue
        found = node_description(Path(folder) if name == SELF else Path(folder, name))
        if found is not None:
            new[name] = found
    if new != record:
        group.attrs[ATTR] = new


def as_recorded(group, folder: str | Path, name: str) -> bool:
    """Whether node ``name`` under ``folder`` reads as ``group``'s record says (True
    where it records nothing of it): an ``ome`` block derived from an array's
    dimension names is recorded only then, so a block written from edited names
    never becomes the run's."""
    want = _record(group).get(name)
    return want is None or node_description(Path(folder, name)) == want


def forget_description(group, names: Iterable[str]) -> None:
    """Remove ``names`` from ``group``'s record (a product replaced or deleted)."""
    record = _record(group)
    names = set(names)
    if names & set(record):
        group.attrs[ATTR] = {k: v for k, v in record.items() if k not in names}


def _differences(have: Any, want: Any, where: tuple) -> Iterator[tuple[tuple, Any, Any]]:
    """Every place two JSON values differ, as ``(path, have, want)``; ``path`` a tuple
    of keys and list indices."""
    if have == want:
        return
    if isinstance(have, Mapping) and isinstance(want, Mapping):
        for k in [*want, *(k for k in have if k not in want)]:
            yield from _differences(have.get(k), want.get(k), (*where, k))
    elif isinstance(have, list) and isinstance(want, list) and len(have) == len(want):
        for i, (a, b) in enumerate(zip(have, want, strict=True)):
            yield from _differences(a, b, (*where, i))
    else:
        yield where, have, want


def _path_text(path: tuple) -> str:
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")


def _at(value: Any, path: tuple) -> Any:
    for p in path:
        value = value[p] if isinstance(p, int) else value.get(p)
    return value


def _short(value: Any) -> tuple[str, bool]:
    """``value`` as compact JSON, cut to ``_SHOWN`` characters; whether it was cut."""
    text = json.dumps(value, separators=(",", ":"))
    return (text, False) if len(text) <= _SHOWN else (text[:_SHOWN - 3] + "...", True)


def _change_text(have: Any, want: Any, where: str) -> str:
    now, cut_now = _short(have)
    then, cut_then = _short(want)
    if have is None:
        return f"{where} is gone (recorded {then})"
    if want is None:
        return f"{where} {now} was added (the run recorded none)"
    if cut_now or cut_then:
        return ""
    return f"{where} {now}, recorded {then}"


def _describe_change(have: Mapping[str, Any], want: Mapping[str, Any]) -> str:
    """What changed between a node's recorded description ``want`` and ``have``: the
    innermost place holding every difference (``ome.multiscales[0].axes``) with both
    values, or, where those are long, the first difference inside it."""
    found = [d for key in want for d in _differences(have.get(key), want[key], (key,))]
    common = found[0][0]
    for path, _, _ in found[1:]:
        n = next((i for i, (a, b) in enumerate(zip(common, path, strict=False)) if a != b),
                 min(len(common), len(path)))
        common = common[:n]
    # (an entry of a list: the whole list where it is short)
    for where in [common[:-1]] * isinstance(common[-1], int) + [common]:
        text = _change_text(_at(have, where), _at(want, where), _path_text(where))
        if text:
            return text
    first, a, b = found[0]
    return (f"{_path_text(common)} changed ({len(found)} value(s); first "
            f"{_change_text(a, b, _path_text(first)) or _path_text(first)})")


def _nodes(path: Path) -> Iterator[tuple[str, Path, str, Mapping]]:
    """``(shown name, folder, file holding the record, recorded description)`` of every
    node the run at ``path`` recorded."""
    for prefix, folder in (("", path), ("products/", path / "products")):
        for name, want in _group_record(folder).items():
            if not isinstance(want, Mapping) or not want:
                continue
            shown = prefix.rstrip("/") if name == SELF else prefix + name
            yield (shown, folder if name == SELF else folder / name,
                   f"{folder}/zarr.json", want)


def _group_record(folder: Path) -> Mapping:
    """The record held by the group at ``folder`` (empty where none)."""
    attrs = (node_metadata(folder) or {}).get("attributes")
    record = attrs.get(ATTR) if isinstance(attrs, Mapping) else None
    return record if isinstance(record, Mapping) else {}


def description_problems(path: str | Path) -> list[str]:
    """Every node of the run at ``path`` whose ``ome`` block or ``dimension_names``
    differ from what the run recorded when it wrote them.

    Parameters
    ----------
    path : str or Path
        The run store.

    Returns
    -------
    list of str
        One line per node: which (``'frames'``, the run's root group,
        ``'products/psf_stack'``), what changed with the recorded value, and the
        repair; empty when everything matches. A node whose ``zarr.json`` is gone is
        not listed here (a missing product is named by
        :func:`instrument.runs.runstore_records.record_problems`).
    """
    path = Path(path)
    problems = []
    for shown, folder, holder, want in _nodes(path):
        have = node_description(folder)
        if have is None or all(have.get(k) == v for k, v in want.items()):
            continue
        what = f"'{shown}'" if shown else "the run's root group (the frames' image)"
        fix = (f"put the recorded values back in {folder}/zarr.json (the attribute "
               f"{ATTR!r} of {holder} holds them) or restore it from a backup copy of the "
               "run")
        if set(want) == {"ome"} or have.get("dimension_names", 0) is None:
            # runs upgrade writes the ome blocks again from the run's attributes and
            # dimension names, and names the dimensions of arrays that lack them
            fix = f"write it again: diffuserlab runs upgrade {path} (or {fix})"
        problems.append(
            f"metadata of {what} changed since the run wrote it (OME-Zarr readers and "
            f"xarray read it): {_describe_change(have, want)}; {fix}")
    return problems


def description_note(path: str | Path) -> str | None:
    """A line for a run written before it recorded what other tools read (its ``ome``
    blocks and dimension names cannot be checked), None when it holds the record."""
    if _group_record(Path(path)):
        return None
    return (f"{path} was written before runs recorded the metadata other tools read: its "
            "ome blocks and dimension names are not checked (diffuserlab runs upgrade "
            "records them as they are)")

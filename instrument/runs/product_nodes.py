"""Where a run's products live in ``products/``: one read path for both layouts.

A run written now stores each *image* product (2-D or 3-D, no table) as its own
OME-Zarr 0.5 image group, as a ``recon3d`` volume is::

    products/NAME/zarr.json      group: the ``ome`` block of this one image
    products/NAME/0/             the product's array, with its attributes (checksums,
                                 depths, ...)

so every OME-Zarr reader shows each product as an image. A product that is no image
(a table with ``columns``, a 1-D LUT, 4-D and up) stays an array ``products/NAME``,
and the hidden arrays of a per-frame product (``NAME__crc32``, ``NAME__done``) stay
arrays of ``products/`` beside it. A run written before kept every product as an
array ``products/NAME``; ``runs upgrade`` moves its image products into their groups
(:func:`regroup`: directories renamed, no chunk rewritten).

Everything that reads a product finds its array here (:func:`array_key`,
:func:`product_array`, :func:`product_arrays`), whichever layout the run has; the run's
record of each array's layout (:mod:`instrument.runs.run_layout`) is kept under the same
key (``NAME/0`` or ``NAME``), so it follows the array.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

__all__ = ["HIDDEN_SUFFIXES", "IMAGE_ARRAY", "MOVING", "array_key", "array_keys",
           "product_array", "product_arrays", "regroup"]

#: The path of an image product's array inside its group (the one multiscale level).
IMAGE_ARRAY = "0"
#: Suffix of an image group being assembled by :func:`regroup` (never a product).
MOVING = "__moving"
#: Suffixes of the names in ``products/`` that are no product: a per-frame product's
#: checksums and done flags, a group :func:`regroup` is assembling.
HIDDEN_SUFFIXES = ("__done", "__crc32", MOVING)


def _is_array(node) -> bool:
    import zarr

    return isinstance(node, zarr.Array)


def _image_of(node):
    """The array ``0`` of an image group, None when ``node`` is no such group."""
    import zarr

    if not isinstance(node, zarr.Group) or IMAGE_ARRAY not in node:
        return None
    arr = node[IMAGE_ARRAY]
    return arr if _is_array(arr) else None


def array_key(products, name: str) -> str | None:
    """Where product ``name``'s array is, relative to ``products/``.

    Parameters
    ----------
    products : zarr.Group
        The run's ``products/`` group.
    name : str
        The product's name.

    Returns
    -------
    str or None
        ``"NAME/0"`` for an image group, ``"NAME"`` for an array (a table or LUT, or
        any product of a run written before the image groups), None when the run
        has no such product.
    """
    if not name or name.endswith(HIDDEN_SUFFIXES) or name not in products:
        return None
    node = products[name]
    if _is_array(node):
        return name
    return f"{name}/{IMAGE_ARRAY}" if _image_of(node) is not None else None


def product_array(products, name: str):
    """Product ``name``'s array (:func:`array_key`), None when the run has none."""
    key = array_key(products, name)
    return None if key is None else products[key]


def product_arrays(products) -> dict[str, tuple[str, object]]:
    """Every product of ``products/``, both layouts, hidden arrays left out.

    Parameters
    ----------
    products : zarr.Group
        The run's ``products/`` group.

    Returns
    -------
    dict
        ``{name: (key, array)}`` sorted by name, ``key`` as :func:`array_key` gives it.
    """
    out: dict[str, tuple[str, object]] = {}
    for name, node in sorted(products.members()):
        if name.endswith(HIDDEN_SUFFIXES):
            continue
        if _is_array(node):
            out[name] = (name, node)
        elif (arr := _image_of(node)) is not None:
            out[name] = (f"{name}/{IMAGE_ARRAY}", arr)
    return out


def array_keys(products) -> list[str]:
    """The keys of every array under ``products/`` (products and hidden arrays)."""
    keys = [key for key, _ in product_arrays(products).values()]
    return sorted(keys + [k for k in products.array_keys() if k.endswith(HIDDEN_SUFFIXES)])


def regroup(products, root: str | Path, names) -> list[str]:
    """Move the array products ``names`` into image groups: ``products/NAME`` becomes
    ``products/NAME/0`` inside a new group ``products/NAME``.

    Each move makes the group under a temporary name (``NAME__moving``, holding only
    its ``zarr.json``), renames the array's directory into it as ``0`` and renames the
    group into place: directories are renamed, no chunk file is read or rewritten, so
    every checksum still holds. Then the run's record of each moved array's layout
    (``products/``'s ``arrays`` attribute, :mod:`instrument.runs.run_layout`) is renamed
    from ``NAME`` to ``NAME/0``, and so is its record of the array's dimension names
    (:mod:`instrument.runs.run_description`). A move a crash cut short is
    finished (or undone) and its records renamed the next time. The groups' ``ome``
    blocks are written afterwards (:func:`instrument.runs.ome.describe_products`).

    Parameters
    ----------
    products : zarr.Group
        The run's ``products/`` group, writable.
    root : str or Path
        Its directory.
    names : iterable of str
        Products stored as arrays ``products/NAME`` to move (others are skipped).

    Returns
    -------
    list of str
        The names moved (or whose move was finished).

    Raises
    ------
    OSError
        A rename failed (the product stays where it was, or in its temporary group
        until the next call finishes the move).
    """
    root = Path(root)
    moved = _finish_moves(root)
    for name in names:
        if not (root / name / "zarr.json").is_file() or array_key(products, name) != name:
            continue
        tmp = root / (name + MOVING)
        if tmp.exists():
            shutil.rmtree(tmp)
        products.create_group(name + MOVING)
        os.replace(root / name, tmp / IMAGE_ARRAY)
        os.replace(tmp, root / name)
        moved.append(name)
    _fsync_dir(root)
    _follow_records(products)
    return sorted(set(moved))


def _finish_moves(root: Path) -> list[str]:
    """Finish the moves a crash cut short: a temporary group holding the array goes into
    place, one that does not (the array never moved) is removed."""
    done = []
    for tmp in sorted(root.glob("*" + MOVING)):
        name = tmp.name[:-len(MOVING)]
        if (tmp / IMAGE_ARRAY / "zarr.json").is_file() and not (root / name).exists():
            os.replace(tmp, root / name)
            done.append(name)
        elif not (tmp / IMAGE_ARRAY).exists():
            shutil.rmtree(tmp)
    return done


def _fsync_dir(path: Path) -> None:
    """Flush a directory's entries (the renames) to disk where the OS allows it."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _follow_records(products) -> None:
    """Rename each key of ``products/``'s records of an array that :func:`regroup`
    moved (``NAME``, now a group) to where the array is now (``NAME/0``): in the layout
    record (:mod:`instrument.runs.run_layout`) every key, in the record of what other tools
    read (:mod:`instrument.runs.run_description`) an array's dimension names (an entry
    ``NAME`` holding a group's ``ome`` block stays). The recorded values stay, as the
    array's metadata did."""
    from .run_description import ATTR as DESCRIBED
    from .run_layout import ATTR as LAYOUT

    for attr in (LAYOUT, DESCRIBED):
        record = dict(products.attrs.get(attr) or {})
        renamed = {}
        for key, value in record.items():
            array = attr == LAYOUT or (isinstance(value, dict) and "dimension_names" in value)
            where = array_key(products, key) if array and "/" not in key else None
            renamed[where if where is not None else key] = value
        if renamed != record:
            products.attrs[attr] = renamed

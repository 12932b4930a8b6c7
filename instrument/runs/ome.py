"""OME-Zarr 0.5 description of run stores and their products: axes, units, scales.

A run store (:mod:`instrument.runs.runstore`) is a Zarr v3 hierarchy; this module adds what
the field's tools (ome-zarr-py, napari, xarray, Fiji through OME-Zarr readers) need to
show it with named axes and physical units, without touching a data chunk:

- ``dimension_names`` on every array (Zarr v3 array metadata), the OME axes' names:
  one letter of ``t``, ``c``, ``z``, ``y``, ``x`` for every image axis (bioio refuses
  longer names, and OME-Zarr 0.5 wants the array's names to be the axes'). The frames
  are (``t``, ``y``, ``x``): ``t`` in seconds for a video, the frame's index in the
  order it was acquired for a sweep (its plan point is in ``point``/``coords``, its
  kind in ``tag``); the per-frame arrays (``coords``, ``crc32``, ``done``, ``point``,
  ``tag``) share that first axis; products name theirs by kind (:func:`product_dims`);
- an ``ome`` block (OME-Zarr 0.5 ``multiscales``, built and validated with
  `ome-zarr-models <https://ome-zarr-models-py.readthedocs.io>`_) on the run's root
  group (the frames) and on each image product's own group ``products/NAME`` (its
  array at ``products/NAME/0``, :mod:`instrument.runs.product_nodes`): axes with their
  types and standard unit names (``second``, ``micrometer``) and one scale per axis
  from the bench: the camera's pixel pitch times its binning (times a product's own
  ``bin_factor``), the frame interval ``1 / frame_rate_hz`` of a video, the plane
  spacing of a volume, and a ``translation`` giving the first plane's depth (the
  z origin). The micrometres of ``y``, ``x`` are the sensor's (its pixel grid), not
  the scene's: the multiscale's metadata says so
  (:data:`~instrument.writer.ome_axes.YX_SCALE`). (A run written before the image
  groups kept its products as arrays of ``products/``, described by one block there
  listing each; ``runs upgrade`` moves them into their groups.)

OME-Zarr 0.5 has one scale per axis, so a stack whose depths are not evenly spaced
(a PSF sweep on a 1/z grid) states a ``z`` axis whose scale is the mean spacing
(first to last depth over the planes between) and whose translation is the first
depth, so the first and last planes sit where they are, and lists every plane's
depth in the multiscale's ``metadata`` (``depths_mm``), as the product's attributes
do. Binning is a scale, not a name: a reconstruction binned by ``b`` has ``y``,
``x`` of ``b`` times the pitch and ``bin_factor`` in its metadata. A run written
before these names (``z_mm``, ``plane``, ``node``, ``y_bin2``, ``y_flat``) keeps
them: every reader takes the names from the stored arrays.

:func:`describe_run` writes all of it (what ``RunStore.create`` calls, and what
``runs upgrade`` runs on a store written before); :func:`describe_products` the
products' blocks (what the product writers call).

The vocabulary itself (:class:`OmeAxis`, :func:`volume_axes`, :func:`space_axes`,
:func:`image_attrs` and their constants) is :mod:`instrument.writer.ome_axes`'s, which
the writer's volumes use too; this module imports it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..writer.ome_axes import OmeAxis, image_attrs, space_axes, volume_axes
from .product_nodes import IMAGE_ARRAY, product_array, product_arrays
from .run_description import SELF, as_recorded, record_description

__all__ = ["FRAME_ARRAYS", "ROOT_ARRAYS", "SWEEP_T", "describe_products", "describe_run",
           "frame_axis", "frame_meta", "frame_pitch_um", "product_axes", "product_dims",
           "run_dims", "set_dimension_names", "stored_axes", "with_source"]

#: Arrays of the run's root group that hold one element (or row) per frame.
FRAME_ARRAYS = ("crc32", "done", "point", "tag")
#: What the ``t`` axis of a sweep's frames counts (multiscale metadata ``t``).
SWEEP_T = ("frame index in acquisition order, no unit (each frame's plan point is in "
           "the arrays point and coords, its kind, psf or dark, in tag)")


# ---------------------------------------------------------------------- what a run holds
def frame_pitch_um(attrs: Mapping[str, Any]) -> float | None:
    """The pitch of a stored frame's pixels, micrometres: the camera's pixel pitch
    (``attrs["camera"]["pixel_pitch_um"]``, written when the run started) times its
    binning (the camera's ``binning`` setting in ``device_settings``); None when the
    run does not record the pitch."""
    camera = attrs.get("camera") or {}
    pitch = camera.get("pixel_pitch_um")
    if not isinstance(pitch, int | float) or not pitch > 0:
        return None
    settings = (attrs.get("device_settings") or {}).get(camera.get("id"), {})
    binning = (settings.get("settings") or {}).get("binning", 1) if isinstance(
        settings, Mapping) else 1
    return float(pitch) * float(binning if isinstance(binning, int | float) else 1)


def frame_axis(attrs: Mapping[str, Any]) -> OmeAxis:
    """The first axis of a run's frames.

    Always ``t`` (time). A video (plan ``video``) has it in seconds, the frame
    interval ``1 / camera.frame_rate_hz`` (scale 1 without unit if the rate is not
    recorded). A sweep's (a calibration's) has no unit: its frames are several per
    plan point (a PSF and a dark frame), not evenly spaced in anything, so the axis
    counts frames in the order they were acquired (:data:`SWEEP_T`).
    """
    from .runstore_records import VIDEO_PLAN

    plan = attrs.get("plan") or {}
    if plan.get("name") == VIDEO_PLAN:
        rate = (attrs.get("camera") or {}).get("frame_rate_hz")
        if isinstance(rate, int | float) and rate > 0:
            return OmeAxis("t", "time", "second", 1.0 / float(rate))
    return OmeAxis("t", "time")


def frame_meta(attrs: Mapping[str, Any]) -> dict:
    """The multiscale metadata of a run's frames: what a sweep's ``t`` counts."""
    from .runstore_records import VIDEO_PLAN

    return {} if (attrs.get("plan") or {}).get("name") == VIDEO_PLAN else {"t": SWEEP_T}


def product_axes(name: str, shape: Sequence[int], attrs: Mapping[str, Any],
                 run_attrs: Mapping[str, Any]) -> tuple[list[OmeAxis], dict] | None:
    """The OME axes of an image product and its multiscale metadata, or None for a
    product that is no image (a table with ``columns``, a 1-D array, 4-D and up).

    2-D: (``y``, ``x``); 3-D: a per-frame product's first axis (or one with
    ``frame_indices``: ΔF/F) is the run's (:func:`frame_axis`, ``t``), a product with
    ``depths_mm`` has :func:`volume_axes` (``z``), a grid of PSFs (a name with
    ``grid``) ``c`` (channel: one PSF per grid node; bioio drops any axis not among
    t, c, z, y, x), anything else ``z`` without unit (planes). ``y``/``x`` are scaled
    by the frame pitch (:func:`frame_pitch_um`) times the product's ``bin_factor``
    ``b`` (its ``source``'s for a ΔF/F), which the metadata states when ``b > 1``.
    """
    shape = tuple(int(v) for v in shape)
    if "columns" in attrs or len(shape) not in (2, 3):
        return None
    pitch = frame_pitch_um(run_attrs)
    b = attrs.get("bin_factor", 1)
    b = int(b) if isinstance(b, int | float) and b >= 1 and b == int(b) else 1
    binned = {"bin_factor": b} if b > 1 else {}
    if len(shape) == 2:
        return space_axes(pitch, b), binned
    meta: dict = {}
    if attrs.get("per_frame") or "frame_indices" in attrs:
        first, meta = frame_axis(run_attrs), frame_meta(run_attrs)
    elif attrs.get("depths_mm") is not None:
        first, meta = volume_axes(attrs["depths_mm"], shape[0])
    elif "grid" in name:
        first = OmeAxis("c", "channel")
    else:
        first = OmeAxis("z", "space")
    return [first, *space_axes(pitch, b)], {**meta, **binned}


def product_dims(name: str, shape: Sequence[int], attrs: Mapping[str, Any],
                 run_attrs: Mapping[str, Any]) -> tuple[str, ...]:
    """Dimension names of a product array: its OME axes' names for an image
    (:func:`product_axes`), ``("row", "column")`` for a table, ``("entry",)`` for a
    1-D array, ``dim_0, ...`` otherwise."""
    axes = product_axes(name, shape, attrs, run_attrs)
    if axes is not None:
        return tuple(a.name for a in axes[0])
    if len(shape) == 2:
        return ("row", "column")
    if len(shape) == 1:
        return ("entry",)
    return tuple(f"dim_{k}" for k in range(len(shape)))


def with_source(attrs: Mapping[str, Any], products) -> dict:
    """A product's attributes with the ``bin_factor`` of the product it derives from
    (its ``source`` in the ``products/`` group ``products``, e.g. the reconstruction a
    ΔF/F was computed from) when it records none."""
    attrs = dict(attrs)
    source = attrs.get("source")
    if "bin_factor" not in attrs and isinstance(source, str):
        node = product_array(products, source)
        if node is not None and "bin_factor" in node.attrs:
            attrs["bin_factor"] = node.attrs["bin_factor"]
    return attrs


def set_dimension_names(array_dir: str | Path, names: Sequence[str]) -> bool:
    """Set the ``dimension_names`` of the Zarr v3 array at ``array_dir`` in its
    ``zarr.json`` (the array metadata document; its chunks are not touched).

    The document is rewritten under a temporary name and renamed into place.

    Returns
    -------
    bool
        True if the names changed.

    Raises
    ------
    ValueError
        ``array_dir`` is no Zarr v3 array, or ``names`` do not match its rank.
    """
    node = Path(array_dir) / "zarr.json"
    meta = json.loads(node.read_text())
    if meta.get("node_type") != "array" or meta.get("zarr_format") != 3:
        raise ValueError(f"{array_dir} is not a Zarr v3 array")
    names = [str(n) for n in names]
    if len(names) != len(meta["shape"]):
        raise ValueError(f"{array_dir} has {len(meta['shape'])} dimensions, not "
                         f"{len(names)} ({names})")
    if meta.get("dimension_names") == names:
        return False
    meta["dimension_names"] = names
    from ..atomic import write_json

    write_json(node, meta)  # whole or not at all (instrument.atomic.atomic_path)
    return True


# ---------------------------------------------------------------------- a run
def run_dims(attrs: Mapping[str, Any], frames_ndim: int = 3) -> dict[str, tuple[str, ...]]:
    """Dimension names of the run's root arrays: ``{array: names}``."""
    first = frame_axis(attrs).name
    return {"frames": (first, "y", "x")[:frames_ndim], "coords": (first, "coord"),
            **{name: (first,) for name in FRAME_ARRAYS}}


def describe_run(group, *, arrays: bool = False) -> list[str]:
    """Write the OME-Zarr description of an open run group: the ``ome`` blocks of the
    root (the frames) and of every image product (:func:`describe_products`), and with
    ``arrays=True`` the ``dimension_names`` of every array that lacks them (what a
    store written before needs; a new store's arrays get them when created).

    Parameters
    ----------
    group : zarr.Group
        The run's root group, writable.
    arrays : bool
        Also set missing dimension names (rewrites those arrays' ``zarr.json``; no
        chunk is touched). The group must be opened again afterwards to see them.

    Returns
    -------
    list of str
        The arrays whose dimension names were set (``frames``, ``products/NAME``).
    """
    attrs = dict(group.attrs)
    path = _folder(group)
    changed: list[str] = []
    if arrays and path is not None:
        changed += _set_missing(path, group, run_dims(attrs, group["frames"].ndim))
        # what it wrote is recorded, and what a run written before lacks as it is now
        record_description(group, path, changed)
        record_description(group, path, ROOT_ARRAYS, missing_only=True)
        products = group["products"]
        plan: dict[str, tuple[str, ...]] = {}
        for name, (key, arr) in product_arrays(products).items():
            dims = tuple(arr.metadata.dimension_names or ()) or product_dims(
                name, arr.shape, with_source(arr.attrs, products), attrs)
            plan[key] = dims
            for hidden in ("__done", "__crc32"):
                if name + hidden in products:
                    plan[name + hidden] = dims[:1]
        named = _set_missing(path / "products", products, plan)
        products = group["products"]
        record_description(products, path / "products", named)
        record_description(products, path / "products", plan, missing_only=True)
        changed += [f"products/{n}" for n in named]
    frames = group["frames"]
    dims = frames.metadata.dimension_names
    if dims is not None:  # (a store written before: runs upgrade names them first)
        found = [frame_axis(attrs), *space_axes(frame_pitch_um(attrs))][-frames.ndim:]
        axes = [replace(a, name=d) for d, a in zip(dims, found, strict=True)]
        group.attrs["ome"] = image_attrs([("frames", "frames", axes, frame_meta(attrs))])
        if path is not None and as_recorded(group, path, "frames"):
            record_description(group, path, [SELF])
    describe_products(group["products"], attrs)
    return changed


def _folder(group) -> Path | None:
    """The folder of a group of a local store (None for another store)."""
    root = getattr(group.store, "root", None)
    return None if root is None else Path(str(root)) / group.path


#: The arrays of a run's root group.
ROOT_ARRAYS = ("frames", "coords", *FRAME_ARRAYS)


#: Dimension names a run's ``coords`` had before the frames' axis was named.
_LEGACY_COORD_DIMS = ("frame", "coord")


def _set_missing(root: Path, group, dims: Mapping[str, Sequence[str]]) -> list[str]:
    out = []
    for name, names in dims.items():
        have = group[name].metadata.dimension_names if name in group else ()
        if (have is None or (name == "coords" and tuple(have) == _LEGACY_COORD_DIMS)) \
                and set_dimension_names(root / name, names):
            out.append(name)
    return out


def stored_axes(name: str, arr, products, run_attrs: Mapping[str, Any],
                ) -> tuple[list[OmeAxis], dict] | None:
    """The OME axes of a stored image product, named as its array's dimensions.

    Parameters
    ----------
    name : str
        The product's name.
    arr : zarr.Array
        Its array (:func:`instrument.runs.product_nodes.product_array`).
    products : zarr.Group
        The run's ``products/`` group (for the ``source`` of a ΔF/F).
    run_attrs : Mapping
        The run's attributes.

    Returns
    -------
    (list of OmeAxis, dict) or None
        :func:`product_axes` with each axis renamed to the array's dimension name
        (the names a run written before stored, such as ``plane`` or ``y_bin2``; the
        computed names for an array without dimension names), and the
        multiscale metadata; None for a product that is no image.
    """
    found = product_axes(name, arr.shape, with_source(arr.attrs, products), run_attrs)
    if found is None:
        return None
    dims = arr.metadata.dimension_names or [a.name for a in found[0]]
    return [replace(a, name=d) for d, a in zip(dims, found[0], strict=True)], found[1]


def describe_products(products, run_attrs: Mapping[str, Any],
                      names: Sequence[str] | None = None) -> None:
    """Write the ``ome`` blocks of a run's image products.

    An image group ``products/NAME`` gets its own block (one multiscale, its array
    ``0``); an image product of a run written before the image groups (an array of
    ``products/``) is listed in the block of ``products/`` as it was then, which is
    removed once no such product is left. A block that would not change is not
    written again.

    Parameters
    ----------
    products : zarr.Group
        The run's ``products/`` group, writable.
    run_attrs : Mapping
        The run's attributes (pitch, binning, frame interval).
    names : sequence of str, optional
        Only these products' groups (the one just written); None: all of them.
    """
    found = product_arrays(products)
    legacy, described = [], []
    for name, (key, arr) in found.items():
        # (an array without dimension names, of a run not upgraded yet: none)
        axes = None if arr.metadata.dimension_names is None else stored_axes(
            name, arr, products, run_attrs)
        if key == name:  # an array of products/: a table, or a run written before
            if axes is not None:
                legacy.append((name, name, *axes))
            continue
        if names is not None and name not in names:
            continue
        group = products[name]
        want = None if axes is None else image_attrs([(name, IMAGE_ARRAY, *axes)])
        if want is not None and group.attrs.get("ome") != want:
            group.attrs["ome"] = want
        if want is not None:
            described.append((name, key))
    if legacy:
        block = image_attrs(legacy)
        if products.attrs.get("ome") != block:
            products.attrs["ome"] = block
    elif "ome" in products.attrs:
        del products.attrs["ome"]
    folder = _folder(products)
    if folder is not None:  # what the run wrote, compared by runs verify
        record_description(products, folder, [SELF, *(
            name for name, key in described if as_recorded(products, folder, key))])

"""napari reader: a run store, one of its products or a recon3d volume as layers with
axes, scales and units.

A run gives one image layer for its frames (lazy: a frame is read, and its checksum
verified, when napari shows it; a frame not stored, or damaged, shows as zeros and is
named in the log) with each frame's tag, plan point and coordinates in the layer's
``metadata``, then one layer per image product (a per-frame product lazily, plane by
plane, like the frames). A product's own folder (``RUN.zarr/products/NAME``, an
OME-Zarr image group) gives that product's layer, read through its run (verified).
A recon3d volume (``recon3d --out V.zarr``) gives one layer. Axis names, units and
scales are those of the run's OME-Zarr description (:mod:`instrument.runs.ome`), computed
the same way for a run written before it; products are found in either layout of
``products/`` (:mod:`instrument.runs.product_nodes`). A colour product (``channels``
recorded, the last axis: a ``calibrate psf-from-scenes`` run's PSF) gives one layer
per channel in its colour. Every layer of planes ends in
``t`` (second), ``z`` (micrometer), ``y``, ``x`` (:func:`_layer`: a video gets a ``z``
of one plane, a sweep's frames, in acquisition order, are labelled ``frame`` and put
in front of a ``t`` of one frame and such a ``z``, as a grid's ``c`` is), so any mix of
runs and volumes in one viewer keeps its units and its time apart from its depth; an
empty array (the frames of a run made by ``runs import-psf``) gives no layer.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["get_reader", "read_product", "read_run", "read_volume"]


def get_reader(path: str | Sequence[str]) -> Callable | None:
    """npe2 reader hook: :func:`read_run` for a run store, :func:`read_product` for a
    product's folder in one, :func:`read_volume` for a recon3d volume, None for
    anything else (napari then asks another reader)."""
    if not isinstance(path, str | Path):
        return None
    from instrument.runs.runstore import is_run_store, product_location
    from instrument.writer.products import VOLUME_MARKER

    if is_run_store(path):
        return read_run
    if product_location(path) is not None:
        return read_product
    if _attrs(Path(path)).get("diffuserlab") == VOLUME_MARKER:
        return read_volume
    return None


def _attrs(path: Path) -> dict:
    import json

    try:
        return json.loads((path / "zarr.json").read_text()).get("attributes") or {}
    except (OSError, ValueError, AttributeError):
        return {}


#: The depth axis a layer with a time axis and none of depth gets after ``t``: one plane,
#: in the unit of a volume's ``z`` (:func:`instrument.runs.ome.volume_axes`). A camera frame
#: has no depth of its own; its plane is given 1 mm (1000 micrometer, the order of a PSF
#: sweep's spacing) because napari's z slider steps by the smallest z scale of its
#: layers: 1 micrometer would give a volume's 2 mm thousands of empty steps.
SINGLE_PLANE_Z = ("z", "space", "micrometer", 1000.0)
#: The time axis a layer whose first axis has no physical unit gets in front of its
#: ``z`` of one plane: one frame, in the unit of a video's ``t``; 1 s, as napari's t
#: slider steps by the smallest t scale (a video's frame interval is smaller).
SINGLE_FRAME_T = ("t", "time", "second", 1.0)
#: napari's label for a unitless first axis whose OME name is one of the physical
#: axes': a sweep's frames in acquisition order (OME ``t``) and planes of unknown
#: depth (OME ``z``), so they are not taken for a video's time or a volume's depth.
INDEX_LABELS = {"t": "frame", "z": "plane"}


def _has_unit(axis) -> bool:
    return axis.type in ("time", "space") and axis.unit not in (None, "pixel")


def _layer(data, name: str, axes, metadata: dict) -> tuple:
    """The napari layer-data tuple of ``data`` with ``axes`` (OME axes, old names or
    new). napari aligns layers by their last axes and drops every unit when two
    layers put units of different kinds on one axis ("Inconsistent units across
    layers"), so every layer of planes ends in ``t`` (second), ``z`` (micrometer),
    ``y``, ``x``: a ``t`` first axis with no ``z`` gets a ``z`` of one plane after it
    (:data:`SINGLE_PLANE_Z`), and a first axis without a physical unit (a sweep's
    frame order, a grid's ``c``, planes of unknown depth) is put in front of a ``t`` of
    one frame (:data:`SINGLE_FRAME_T`) and such a ``z``, labelled by
    :data:`INDEX_LABELS`. Any mix of sweeps, videos, grids and volumes then keeps
    its units."""
    from instrument.runs.ome import OmeAxis

    axes = list(axes)
    if len(axes) == data.ndim == 3 and not _has_unit(axes[0]):
        first = axes[0]
        index = OmeAxis(INDEX_LABELS.get(first.name, first.name), first.type, first.unit,
                        first.scale, float(getattr(first, "origin", 0.0)))
        data = data[:, None, None]
        axes = [index, OmeAxis(*SINGLE_FRAME_T), OmeAxis(*SINGLE_PLANE_Z), *axes[1:]]
    elif len(axes) == data.ndim >= 3 and axes[0].name == "t" and not any(
            a.name == "z" for a in axes):
        data = data[:, None]
        axes = [axes[0], OmeAxis(*SINGLE_PLANE_Z), *axes[1:]]
    kwargs = {"name": name, "scale": [a.scale for a in axes],
              "translate": [float(getattr(a, "origin", 0.0)) for a in axes],
              "axis_labels": [a.name for a in axes],
              "units": [a.unit or "pixel" for a in axes], "metadata": metadata}
    return data, kwargs, "image"


def _lazy(read: Callable[[int], np.ndarray], n: int, plane_shape, dtype):
    """A dask array of ``n`` planes, plane ``i`` read by ``read(i)`` when shown."""
    import dask
    import dask.array as da

    if n == 0:
        return np.zeros((0, *plane_shape), dtype)
    planes = [da.from_delayed(dask.delayed(read)(i), tuple(plane_shape), dtype=dtype)
              for i in range(n)]
    return da.stack(planes)


def read_run(path: str) -> list[tuple]:
    """The layers of a run store (module notes).

    Returns
    -------
    list of (data, kwargs, "image")
        napari layer-data tuples: the frames first, then each image product; none for
        an empty array (the frames of a run made by ``runs import-psf``).

    Raises
    ------
    instrument.runs.runstore.RunStoreError
        No readable run at ``path``.
    """
    from instrument.runs.ome import frame_axis, frame_pitch_um, space_axes
    from instrument.runs.run_integrity import DamagedFrameError
    from instrument.runs.runstore import RunStore

    store = RunStore.open(path)
    attrs, done = store.attrs, store.done()
    dtype, shape = store.frame_dtype, store.frame_shape

    def frame(i: int) -> np.ndarray:
        if not done[i]:
            return np.zeros(shape, dtype)
        try:
            return store.frame(i).image
        except DamagedFrameError as exc:
            log.warning("%s", exc)
            return np.zeros(shape, dtype)

    run = Path(store.path).name
    coords = {k: v.tolist() for k, v in store.coords_table().items()}
    meta = {"run": str(store.path), "tags": [store.tag_of(i) for i in range(store.n_frames)],
            "points": [store.point_of(i) for i in range(store.n_frames)],
            "done": done.tolist(), "coords": coords, "coord_units": store.coord_info(),
            "plan": attrs["plan"]["name"]}
    axes = [frame_axis(attrs), *space_axes(frame_pitch_um(attrs))]
    layers = [_layer(_lazy(frame, store.n_frames, shape, dtype), f"{run} frames", axes,
                     meta)]
    for name in store.products():
        layers.extend(_product_layers(store, name))
    # no layer for an empty array (a run of no frames: ``runs import-psf``'s holds
    # only its PSF stack), which napari cannot show (its contrast limits fail)
    return [layer for layer in layers if layer is not None and 0 not in layer[0].shape]


def read_product(path: str) -> list[tuple]:
    """The layer of one product, given its folder ``RUN.zarr/products/NAME``
    (:func:`instrument.runs.runstore.product_location`), read through its run as
    :func:`read_run` reads it.

    Returns
    -------
    list of (data, kwargs, "image")
        One layer; none for a table or LUT, an empty product, or a damaged product
        (named in the log).

    Raises
    ------
    instrument.runs.runstore.RunStoreError
        ``path`` is no product folder of a readable run.
    """
    from instrument.runs.runstore import RunStore, RunStoreError, product_location

    where = product_location(path)
    if where is None:
        raise RunStoreError(f"{path} is no product folder of a run (RUN.zarr/products/NAME)")
    store = RunStore.open(where[0])
    return [layer for layer in _product_layers(store, where[1]) if 0 not in layer[0].shape]


#: The colour map of each named channel of a colour product's layers.
CHANNEL_COLORMAPS = {"R": "red", "G": "green", "B": "blue"}


def _product_layers(store, name: str) -> list[tuple]:
    """The layers of product ``name`` of an open run: one image layer (a per-frame
    one lazily, plane by plane), one per channel of a colour product (``channels``
    recorded, the last axis: a ``calibrate psf-from-scenes`` run's ``psf_stack``,
    ``(planes, rows, cols, channels)``: each channel in its colour, blended
    additively), none for a table or LUT or a damaged product (logged)."""
    from instrument.runs.ome import product_axes
    from instrument.runs.runstore import RunStoreError

    pattrs = store.product_attrs(name)
    channels = pattrs.get("channels")
    info = store.product_info(name)
    if (isinstance(channels, list) and len(info["shape"]) == 4
            and info["shape"][-1] == len(channels)):
        found = product_axes(name, info["shape"][:3], pattrs, store.attrs)
        try:
            data = np.asarray(store.product(name)[0])
        except RunStoreError as exc:  # a damaged product: named, the others still shown
            log.warning("%s", exc)
            return []
        layers = []
        for k, channel in enumerate(channels):
            meta = {**{k2: v for k2, v in pattrs.items() if k2 != "crc32"}, **found[1],
                    "run": str(store.path), "product": name, "channel": channel}
            layer = _layer(data[..., k], f"{Path(store.path).name} {name} {channel}",
                           found[0], meta)
            layer[1].update(colormap=CHANNEL_COLORMAPS.get(str(channel), "gray"),
                            blending="additive")
            layers.append(layer)
        return layers
    layer = _product_layer(store, name)
    return [] if layer is None else [layer]


def _product_layer(store, name: str) -> tuple | None:
    """The image layer of product ``name`` of an open run (a per-frame one lazily,
    plane by plane); None for a table or LUT, or a damaged product (logged)."""
    from instrument.runs.runstore import RunStoreError

    found = store.product_axes(name)
    if found is None:  # a table or a LUT: no image
        return None
    p_axes, p_meta = found
    info = store.product_info(name)
    pattrs = store.product_attrs(name)
    meta = {**{k: v for k, v in pattrs.items() if k != "crc32"}, **p_meta,
            "run": str(store.path), "product": name}
    try:
        if pattrs.get("per_frame"):
            plane_done = store.product_frames_done(name)
            plane_shape, dtype = info["shape"][1:], np.dtype(info["dtype"])

            def plane(i):
                if not plane_done[i]:
                    return np.zeros(plane_shape, dtype)
                return store.product_frame(name, i)

            data = _lazy(plane, info["shape"][0], plane_shape, dtype)
        else:
            data = store.product(name)[0]
    except RunStoreError as exc:  # a damaged product: named, the others still shown
        log.warning("%s", exc)
        return None
    return _layer(data, f"{Path(store.path).name} {name}", p_axes, meta)


def read_volume(path: str) -> list[tuple]:
    """The layer of a recon3d volume (an OME-Zarr image written by
    :func:`instrument.writer.products.write_volume`), axes and units from its
    ``ome`` block.

    Returns
    -------
    list of (data, kwargs, "image")
        One layer: the volume (z, y, x) as stored.

    Raises
    ------
    diffuserlab.errors.InputError
        The ``ome`` block is missing or damaged: no multiscale image, axes and scales
        that do not match each other or the array, or a dataset that is not there
        (one line naming what is wrong and the fix).
    """
    import zarr

    group = zarr.open_group(str(path), mode="r")
    attrs = dict(group.attrs)
    key, axes = _volume_layout(Path(path), attrs, group)
    meta = {k: v for k, v in attrs.items() if k != "ome"}
    data = np.asarray(group[key][...])
    return [_layer(data, Path(path).name, axes, meta)]


def _volume_layout(path: Path, attrs: dict, group) -> tuple[str, list]:
    """The array key and the axes a volume's ``ome`` block describes (checked against
    the stored array); InputError as :func:`read_volume`."""
    from diffuserlab.errors import InputError
    from instrument.runs.ome import OmeAxis

    def refuse(what: str) -> InputError:
        return InputError(f"{path}: the volume's OME description {what}; write the volume "
                          "again (diffuserlab recon3d --out ... --overwrite)")

    try:
        ms = attrs["ome"]["multiscales"][0]
        dataset = ms["datasets"][0]
        key = str(dataset["path"])
        transforms = dataset["coordinateTransformations"]
        scale = [float(s) for s in next(t["scale"] for t in transforms
                                         if t.get("type") == "scale")]
        origin = [float(v) for v in next((t["translation"] for t in transforms
                                          if t.get("type") == "translation"), scale)]
        named = [(str(a["name"]), a.get("type"), a.get("unit")) for a in ms["axes"]]
    except (KeyError, IndexError, TypeError, ValueError, AttributeError, StopIteration) as exc:
        what = {KeyError: f"lacks {exc}", IndexError: "has an empty list",
                StopIteration: "has no scale"}.get(type(exc))
        raise refuse(what or f"is malformed ({' '.join(str(exc).split())})") from None
    if key not in group or not hasattr(group[key], "shape"):
        raise refuse(f"names dataset {key!r}, which the volume does not hold")
    ndim = group[key].ndim
    if not len(named) == len(scale) == ndim:
        raise refuse(f"has {len(named)} axes and {len(scale)} scales for an array of {ndim} "
                     "dimensions")
    if "translation" not in [t.get("type") for t in transforms]:
        origin = [0.0] * ndim
    if len(origin) != ndim:
        raise refuse(f"has {len(origin)} translations for an array of {ndim} dimensions")
    axes = [OmeAxis(*a, s) for a, s in zip(named, scale, strict=True)]
    # the first plane's position (OME translation), carried beside the axis
    return key, [SimpleNamespace(**vars(a), origin=o) if not hasattr(a, "origin")
                 else replace(a, origin=o) for a, o in zip(axes, origin, strict=True)]

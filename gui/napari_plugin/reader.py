"""napari reader: a run store or a recon3d volume as layers with axes, scales and units.

A run gives one image layer for its frames (lazy: a frame is read, and its checksum
verified, when napari shows it; a frame not stored, or damaged, shows as zeros and is
named in the log) with each frame's tag, plan point and coordinates in the layer's
``metadata``, then one layer per image product (a per-frame product lazily, plane by
plane, like the frames). A recon3d volume (``recon3d --out V.zarr``) gives one layer.
Axis names, units and scales are those of the run's OME-Zarr description
(:mod:`instrument.ome`), computed the same way for a run written before it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["get_reader", "read_run", "read_volume"]


def get_reader(path: str | Sequence[str]) -> Callable | None:
    """npe2 reader hook: :func:`read_path` for a run store or a recon3d volume, None
    for anything else (napari then asks another reader)."""
    if not isinstance(path, str | Path):
        return None
    from instrument.reconstruct_files import VOLUME_MARKER
    from instrument.runstore import is_run_store

    if is_run_store(path):
        return read_run
    if _attrs(Path(path)).get("diffuserlab") == VOLUME_MARKER:
        return read_volume
    return None


def _attrs(path: Path) -> dict:
    import json

    try:
        return json.loads((path / "zarr.json").read_text()).get("attributes") or {}
    except (OSError, ValueError, AttributeError):
        return {}


def _layer_kwargs(name: str, axes, metadata: dict) -> dict[str, Any]:
    return {"name": name, "scale": [a.scale for a in axes],
            "axis_labels": [a.name for a in axes],
            "units": [a.unit or "pixel" for a in axes], "metadata": metadata}


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
        napari layer-data tuples: the frames first, then each image product.

    Raises
    ------
    instrument.runstore.RunStoreError
        No readable run at ``path``.
    """
    from instrument.ome import (
        frame_axis,
        frame_pitch_um,
        product_axes,
        space_axes,
        with_source,
    )
    from instrument.run_integrity import DamagedFrameError
    from instrument.runstore import RunStore, RunStoreError

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
    layers = [(_lazy(frame, store.n_frames, shape, dtype),
               _layer_kwargs(f"{run} frames", axes, meta), "image")]
    products = store._group["products"]
    for name in store.products():
        arr = products[name]
        pattrs = dict(arr.attrs)
        found = product_axes(name, arr.shape, with_source(pattrs, products), attrs)
        if found is None:  # a table or a LUT: no image
            continue
        p_axes, p_meta = found
        dims = arr.metadata.dimension_names
        if dims is not None:
            p_axes = [type(a)(d, a.type, a.unit, a.scale) for d, a in zip(dims, p_axes,
                                                                           strict=True)]
        meta = {**{k: v for k, v in pattrs.items() if k != "crc32"}, **p_meta,
                "run": str(store.path), "product": name}
        try:
            if pattrs.get("per_frame"):
                plane_done = store.product_frames_done(name)

                def plane(i, name=name, plane_done=plane_done, arr=arr):
                    if not plane_done[i]:
                        return np.zeros(arr.shape[1:], arr.dtype)
                    return store.product_frame(name, i)

                data = _lazy(plane, arr.shape[0], arr.shape[1:], arr.dtype)
            else:
                data = store.product(name)[0]
        except RunStoreError as exc:  # a damaged product: named, the others still shown
            log.warning("%s", exc)
            continue
        layers.append((data, _layer_kwargs(f"{run} {name}", p_axes, meta), "image"))
    return layers


def read_volume(path: str) -> list[tuple]:
    """The layer of a recon3d volume (an OME-Zarr image written by
    :func:`instrument.reconstruct_files.write_volume`), axes and units from its
    ``ome`` block."""
    import zarr

    from instrument.ome import OmeAxis

    group = zarr.open_group(str(path), mode="r")
    attrs = dict(group.attrs)
    ms = attrs["ome"]["multiscales"][0]
    scale = ms["datasets"][0]["coordinateTransformations"][0]["scale"]
    axes = [OmeAxis(a["name"], a.get("type"), a.get("unit"), float(s))
            for a, s in zip(ms["axes"], scale, strict=True)]
    meta = {k: v for k, v in attrs.items() if k != "ome"}
    data = np.asarray(group[ms["datasets"][0]["path"]][...])
    return [(data, _layer_kwargs(Path(path).name, axes, meta), "image")]

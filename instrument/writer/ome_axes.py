"""The OME-Zarr 0.5 vocabulary of what DiffuserLab writes: axes with their units,
scales and origins, the ``z`` axis of a stack of planes, the ``y``, ``x`` axes of a
plane of pixels, and the ``ome`` block of a group of images.

Plain values, no store: the writer describes the volumes it writes with them
(:func:`instrument.writer.products.write_volume`) and the run stores their frames and
products (:mod:`instrument.runs.ome`, which builds the run's description on them). Kept
under the writer so that the writer needs nothing of the run stores.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["DEPTH_ATTRS", "OME_UNITS", "UNEVEN_Z", "YX_SCALE", "OmeAxis", "depth_coordinate",
           "image_attrs", "space_axes", "volume_axes", "write_depth_coordinate"]

#: Unit names of the OME-Zarr specification for the units the project stores.
OME_UNITS = {"s": "second", "ms": "millisecond", "us": "microsecond", "um": "micrometer",
             "mm": "millimeter", "nm": "nanometer", "m": "meter"}
#: Relative tolerance under which depths count as evenly spaced.
_EVEN_RTOL = 1e-6
#: What the micrometres of ``y``, ``x`` measure (the multiscale metadata ``yx_scale``).
YX_SCALE = ("sensor grid: the camera's pixel pitch times the binning, micrometres on "
            "the sensor, not in the scene")
#: What the ``z`` scale of unevenly spaced depths is (multiscale metadata ``z_scale``).
UNEVEN_Z = ("mean spacing of unevenly spaced depths (translation: the first depth); "
            "each plane's depth is in depths_mm")


#: The attributes of a stack's depth coordinate array (:func:`write_depth_coordinate`).
DEPTH_ATTRS = {"units": "mm", "long_name": "depth of each plane",
               "standard_name": "depth"}


@dataclass(frozen=True)
class OmeAxis:
    """One axis of an OME-Zarr image: ``name`` (also the array's dimension name),
    ``type`` (``"space"``, ``"time"``, ``"channel"`` or None for a custom axis),
    ``unit`` (an OME unit name or None), ``scale`` (the spacing of its samples in
    that unit; 1.0 where there is no unit) and ``origin`` (the position of the first
    sample in that unit: the OME ``translation``)."""

    name: str
    type: str | None = None
    unit: str | None = None
    scale: float = 1.0
    origin: float = 0.0


def volume_axes(depths_mm: Sequence[float] | None, n_planes: int) -> tuple[OmeAxis, dict]:
    """The first axis of a stack of planes at ``depths_mm`` and the multiscale
    metadata that goes with it.

    Always ``z`` (space). With one depth per plane it is in micrometer, its origin
    (the OME translation) the first depth and its scale the spacing: exact for
    evenly spaced depths, else the mean spacing ``(last - first) / (n - 1)`` (OME-Zarr
    0.5 has one scale per axis; :data:`UNEVEN_Z` in the metadata ``z_scale``), with
    every plane's depth in the metadata (``{"depths_mm": [...]}``). Without depths
    (or a stack whose depths all coincide) the axis has no unit.
    """
    depths = [] if depths_mm is None else [float(z) for z in np.atleast_1d(depths_mm)]
    meta: dict = {"depths_mm": depths} if depths else {}
    if len(depths) != n_planes or not depths:
        return OmeAxis("z", "space"), meta
    origin = depths[0] * 1000.0
    if n_planes == 1:
        return OmeAxis("z", "space", "micrometer", 1.0, origin), meta
    steps = np.diff(depths)
    step = abs(depths[-1] - depths[0]) / (n_planes - 1)
    if step == 0:
        return OmeAxis("z", "space"), meta
    if not np.allclose(steps, steps[0], rtol=_EVEN_RTOL, atol=0):
        meta["z_scale"] = UNEVEN_Z
    return OmeAxis("z", "space", "micrometer", step * 1000.0, origin), meta


def space_axes(pitch_um: float | None, bin_factor: int = 1) -> list[OmeAxis]:
    """The ``y``, ``x`` axes of a plane of pixels binned by ``bin_factor`` from a
    grid of pixels ``pitch_um`` apart: the scale of every image and volume DiffuserLab
    writes or shows (a run's frames and products, ``recon3d`` volumes, the napari
    plugin's layers).

    Parameters
    ----------
    pitch_um : float or None
        The unbinned grid's pitch, micrometres on the sensor (the camera's pixel
        pitch times its own binning); None when not known.
    bin_factor : int
        The plane's binning of that grid (a reconstruction's ``bin_factor``).

    Returns
    -------
    list of OmeAxis
        ``y``, ``x`` (the names whatever the binning: it is a scale, not a name), in
        micrometer at ``pitch_um * bin_factor``; without a pitch, no unit and a scale
        of ``bin_factor`` (one per unbinned sensor pixel), so a binned plane lines up
        with the frames it came from.
    """
    if pitch_um is None:
        return [OmeAxis(a, "space", None, float(bin_factor)) for a in ("y", "x")]
    return [OmeAxis(a, "space", "micrometer", float(pitch_um) * bin_factor)
            for a in ("y", "x")]


def image_attrs(images: Sequence[tuple[str, str, Sequence[OmeAxis], Mapping]]) -> dict:
    """The ``ome`` attribute (OME-Zarr 0.5) of a group holding the given images.

    Parameters
    ----------
    images : sequence of (name, path, axes, metadata)
        One multiscale entry per image: its name, the path of its array in the
        group, its axes and free metadata (each plane's depth, the binning, ...);
        the metadata ``yx_scale`` (:data:`YX_SCALE`) is added where ``y``, ``x``
        have a unit. Each dataset has a scale and a translation (the axes'
        ``origin``).

    Returns
    -------
    dict
        ``{"version": "0.5", "multiscales": [...]}``, built and checked by
        ``ome_zarr_models.v05`` (axis order and types, unique names, scale
        lengths), as JSON.

    Raises
    ------
    ValueError
        Axes that OME-Zarr 0.5 cannot express (ome-zarr-models' message).
    """
    from ome_zarr_models.v05.axes import Axis
    from ome_zarr_models.v05.image import ImageAttrs
    from ome_zarr_models.v05.multiscales import Dataset, Multiscale

    multiscales = []
    for name, path, axes, meta in images:
        meta = dict(meta)
        if any(a.type == "space" and a.unit is not None for a in axes[-2:]):
            meta["yx_scale"] = YX_SCALE
        multiscales.append(Multiscale(
            name=name, metadata=meta or None,
            axes=[Axis(name=a.name, type=a.type, unit=a.unit) for a in axes],
            datasets=[Dataset.build(path=path, scale=[a.scale for a in axes],
                                    translation=[a.origin for a in axes])]))
    attrs = ImageAttrs(version="0.5", multiscales=multiscales)
    return attrs.model_dump(mode="json", exclude_none=True)


def depth_coordinate(depths_mm: Sequence[float] | None, n_planes: int) -> np.ndarray | None:
    """The depths of a stack's planes as a coordinate array: float64, mm, one per plane;
    None without one finite depth per plane (no coordinate is written then)."""
    if depths_mm is None:
        return None
    depths = np.asarray(np.atleast_1d(depths_mm), np.float64)
    if depths.ndim != 1 or depths.size != n_planes or not np.isfinite(depths).all():
        return None
    return depths


def write_depth_coordinate(group, axis: str, depths_mm: Sequence[float] | None,
                           n_planes: int) -> str | None:
    """Write the true depths of a stack beside its image array: the 1-D array ``axis``
    (the stack's first dimension name, ``z``) in ``group``, its ``dimension_names``
    ``[axis]``, float64 in mm with :data:`DEPTH_ATTRS`.

    OME-Zarr 0.5 gives an axis one scale, so unevenly spaced depths are written at
    their mean spacing (:func:`volume_axes`); xarray takes an array named as its one
    dimension for that dimension's coordinate, so ``xr.open_dataset(...,
    group=GROUP)`` gives ``z`` holding every plane's true depth. OME-Zarr readers
    read only the multiscale's datasets (the array ``0``) and leave it alone.

    Parameters
    ----------
    group : zarr.Group
        The image group (Zarr v3), writable.
    axis : str
        The stack's first dimension name.
    depths_mm : sequence of float or None
        One depth per plane, mm.
    n_planes : int

    Returns
    -------
    str or None
        The array's name, None when no coordinate was written (no depth per plane).
    """
    depths = depth_coordinate(depths_mm, n_planes)
    if depths is None:
        return None
    arr = group.create_array(axis, shape=depths.shape, dtype="float64",
                             chunks=depths.shape, dimension_names=[axis])
    arr[:] = depths
    arr.update_attributes(dict(DEPTH_ATTRS))
    return axis

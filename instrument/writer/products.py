"""The products of a reconstruction: their names, and the files written from its arrays.

``recon`` writes ``OUT.png`` (the view, turned upright) and ``OUT.tif`` (the float32
data product, the model grid: an OME-TIFF with axes y, x (and c), its pixel size and
its record, :func:`write_recon_tiff`) with its metrics JSON (:func:`write_image_products`);
``recon3d`` and the PSF-grid solve write the volume (a float32 TIFF or an OME-Zarr
image, :func:`write_volume`) and its three maximum-intensity projections
(:func:`write_volume_products`). Each command's outputs are one
:func:`~instrument.atomic.output_group`: all of them or none. The arrays come
from :func:`recon.reconstruct`, which writes nothing.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from diffuserlab.errors import InputError
from recon.io import scene_view

from ..atomic import atomic_dir, atomic_path, output_group, write_json
from .files import save_image

__all__ = ["DEFAULT_STEM", "IMAGE_SUFFIXES", "VOLUME_MARKER", "output_paths", "projections",
           "volume_output_paths", "write_image_products", "write_recon_tiff",
           "write_volume", "write_volume_products"]

_VOLUME_SUFFIXES = (".tif", ".tiff", ".zarr")

#: The image extensions ``--out`` of ``recon`` may end with (any other dot is part of
#: the name: ``take.2`` writes ``take.2.png`` and ``take.2.tif``).
IMAGE_SUFFIXES = (".png", ".tif", ".tiff")
#: The file name ``recon`` writes inside a folder given as ``--out FOLDER/``.
DEFAULT_STEM = "recon"


def output_paths(out: str) -> tuple[Path, Path]:
    """(png, tif) paths for ``--out``: a known image extension picks the stem, anything
    else is the stem itself; a folder (a trailing ``/`` or an existing directory) gets
    ``recon.png`` and ``recon.tif`` inside.

    Only :data:`IMAGE_SUFFIXES` are extensions: ``take.2`` is a name, not ``take`` with
    the extension ``.2`` (which would write ``take.png`` and replace another take).

    Parameters
    ----------
    out : str
        ``OUT``, ``OUT.png``, ``OUT.tif``, ``OUT.tiff`` or ``FOLDER/``.

    Returns
    -------
    (Path, Path)
        ``OUT.png`` and ``OUT.tif``.
    """
    text = os.fspath(out)
    p = Path(text)
    if text.endswith(("/", os.sep)) or p.is_dir():
        p = p / DEFAULT_STEM
    name = p.stem if p.suffix.lower() in IMAGE_SUFFIXES else p.name
    return p.with_name(name + ".png"), p.with_name(name + ".tif")


def write_recon_tiff(path: Path, image: np.ndarray, pitch_um: float | None = None,
                     record: dict | None = None) -> None:
    """Write a 2D reconstruction as a float32 OME-TIFF (tifffile), under a temporary
    name renamed into place.

    Parameters
    ----------
    path : pathlib.Path
        The ``.tif`` to write.
    image : numpy.ndarray
        Shape (H, W) or (H, W, C): axes ``YX`` or ``YXS`` (OME ``SizeC`` = C, the
        channels interleaved), values unchanged as float32.
    pitch_um : float, optional
        The reconstruction grid's pitch, micrometres on the sensor (pixel pitch times
        binning): ``PhysicalSizeX``/``PhysicalSizeY`` in µm; none without it.
    record : dict, optional
        JSON-able record (the reconstruction's parameters and metrics) stored as the
        image's OME ``Description`` (read back by
        :func:`instrument.runs.tiff_export.read_tiff_metadata`).

    Raises
    ------
    recon.errors.ReconInputError
        An array that is not (H, W) or (H, W, C) of real numbers.
    """
    import tifffile

    from recon.errors import ReconInputError

    data = np.asarray(image)
    if data.ndim not in (2, 3) or data.size == 0 or data.dtype.kind not in "biuf":
        raise ReconInputError(f"{path}: cannot write an image of shape {data.shape} and "
                              f"dtype {data.dtype}; pass a 2D (H, W) or (H, W, C) image")
    data = np.ascontiguousarray(data, dtype=np.float32)
    meta: dict = {"axes": "YX" if data.ndim == 2 else "YXS", "Name": "reconstruction",
                  "Description": json.dumps(record or {}, default=str)}
    if pitch_um:
        for a in "XY":
            meta[f"PhysicalSize{a}"], meta[f"PhysicalSize{a}Unit"] = float(pitch_um), "µm"
    rgb = data.ndim == 3 and data.shape[2] in (3, 4)
    with atomic_path(path) as tmp:
        tifffile.imwrite(tmp, data, ome=True, metadata=meta,
                         photometric="rgb" if rgb else "minisblack",
                         planarconfig="contig" if data.ndim == 3 else None,
                         **tiff_resolution(pitch_um))


def tiff_resolution(pitch_um: float | None) -> dict:
    """The TIFF resolution tags of a pixel size, for an OME-TIFF's readers that read
    no OME-XML (ImageJ 1.x without Bio-Formats: it shows ``0.0013 cm`` for 13 µm).

    Parameters
    ----------
    pitch_um : float or None
        The pixel size in micrometres (``None`` or 0: no tags).

    Returns
    -------
    dict
        ``resolution`` (pixels per centimetre, y and x alike) and ``resolutionunit``
        for :func:`tifffile.imwrite`; empty without a pitch.
    """
    if not pitch_um:
        return {}
    per_cm = 1e4 / float(pitch_um)
    return {"resolution": (per_cm, per_cm), "resolutionunit": "CENTIMETER"}


def write_image_products(image: np.ndarray, png: Path, tif: Path,
                         metrics_json: str | os.PathLike | None = None,
                         metrics: dict | None = None,
                         pitch_um: float | None = None) -> None:
    """Write a 2D reconstruction's view, data product and metrics: all of them or none.

    Parameters
    ----------
    image : numpy.ndarray
        The reconstruction, shape (H, W) or (H, W, C), in the model grid
        (:data:`recon.io.DATA_ORIENTATION`).
    png, tif : pathlib.Path
        The 8-bit view, turned upright (:func:`recon.io.scene_view`), and the float32
        OME-TIFF of ``image`` as it is (:func:`output_paths`, :func:`write_recon_tiff`).
    metrics_json : path, optional
        Where ``metrics`` go (:func:`~instrument.atomic.write_json`).
    metrics : dict, optional
        The record written to ``metrics_json`` and into the TIFF's description.
    pitch_um : float, optional
        The reconstruction grid's pitch, micrometres on the sensor (the TIFF's pixel
        size; none without it).

    Raises
    ------
    recon.errors.ReconInputError
        An image :func:`~instrument.writer.files.save_image` cannot write.
    OSError
        A write failed (a full disk named with its free space); nothing is in place.
    """
    with output_group():  # the PNG, the TIFF and the JSON: all of them or none
        save_image(png, scene_view(image))
        write_recon_tiff(tif, image, pitch_um, metrics)
        if metrics_json:
            write_json(metrics_json, metrics)


def volume_output_paths(out: str) -> tuple[Path, dict[str, Path]]:
    """The volume path and the three projection PNG paths of ``--out``.

    Raises
    ------
    ValueError
        ``out`` does not end in ``.tif``, ``.tiff`` or ``.zarr``.
    """
    path = Path(out)
    if path.suffix.lower() not in _VOLUME_SUFFIXES:
        raise InputError(f"--out {out}: use a .tif/.tiff or .zarr name for the volume")
    stem = path.with_suffix("")
    return path, {v: stem.parent / f"{stem.name}_mip_{v}.png" for v in ("xy", "xz", "yz")}


def projections(volume: np.ndarray) -> dict[str, np.ndarray]:
    """Maximum-intensity projections, each plane repeated so z is visible.

    Parameters
    ----------
    volume : ndarray, shape (n_z, rows, cols)

    Returns
    -------
    dict
        ``xy`` is the maximum over z (rows, cols); ``xz`` over y (z, cols); ``yz``
        over x (rows, z). Along z every plane is repeated
        ``max(1, min(rows, cols) // (2 n_z))`` times (nearest neighbour, for viewing
        only).
    """
    n_z, rows, cols = volume.shape
    rep = max(1, min(rows, cols) // (2 * n_z))
    return {"xy": volume.max(axis=0),
            "xz": np.repeat(volume.max(axis=1), rep, axis=0),
            "yz": np.repeat(volume.max(axis=2).T, rep, axis=1)}


#: Marker in the ``zarr.json`` of a volume :func:`write_volume` wrote (the group's
#: ``diffuserlab`` attribute): such a folder may be replaced by the next one.
VOLUME_MARKER = "recon3d-volume"


def write_volume(path: Path, volume: np.ndarray, attrs: dict,
                 pitch_um: float | None = None) -> None:
    """A float32 TIFF (JSON metadata, axes ZYX) or an OME-Zarr 0.5 image (Zarr v3).

    The Zarr volume is a group holding the volume as its array ``0`` (z, y, x) with
    ``attrs`` and an ``ome`` block (:func:`instrument.runs.ome.image_attrs`): ``z`` in
    micrometer from ``attrs["depths_mm"]``, its translation the first depth (the mean
    spacing for uneven depths, each in the metadata: :func:`instrument.runs.ome.volume_axes`),
    and every plane's true depth as the coordinate array ``z`` beside it (mm,
    :func:`~instrument.writer.ome_axes.write_depth_coordinate`: xarray's ``z``);
    ``y``/``x`` in micrometer with ``pitch_um`` (the reconstruction grid's pitch:
    sensor pitch times binning), without it unitless at ``attrs["bin_factor"]`` per
    pixel (one per sensor pixel, :func:`instrument.runs.ome.space_axes`, as the napari
    plugin scales a reconstruction).

    Both are written under a temporary name in the same directory and renamed into
    place (the TIFF with :func:`~instrument.atomic.atomic_path`, a Zarr array, a
    directory, with :func:`~instrument.atomic.atomic_dir`: the old one moved aside
    and then removed; inside an :func:`~instrument.atomic.output_group` when the
    group ends), so a failure never leaves a
    partial volume under ``path``, nor its temporary folder, nor a folder made for it.

    Raises
    ------
    InputError
        ``path`` is an existing Zarr node that is no volume written here (e.g. a run
        store).
    """
    import tifffile
    import zarr

    if path.suffix.lower() != ".zarr":
        with atomic_path(path) as tmp:
            tifffile.imwrite(tmp, volume.astype(np.float32), photometric="minisblack",
                             metadata={**attrs, "axes": "ZYX"})
        return
    from .ome_axes import image_attrs, space_axes, volume_axes, write_depth_coordinate

    node = path / "zarr.json"
    if path.exists():
        meta = json.loads(node.read_text()) if node.is_file() else {}
        ours = meta.get("node_type") == "array" or (  # an array: written before OME-Zarr
            meta.get("attributes", {}).get("diffuserlab") == VOLUME_MARKER)
        if not ours:
            raise InputError(f"--out {path} exists and is not a volume written by recon3d "
                             "(a run store?); choose another name")
    first, meta = volume_axes(attrs.get("depths_mm"), volume.shape[0])
    b = attrs.get("bin_factor", 1)
    axes = [first, *(space_axes(float(pitch_um), 1) if pitch_um else space_axes(
        None, int(b) if isinstance(b, int) and b >= 1 else 1))]
    with atomic_dir(path) as tmp:  # never half a volume under the final name
        group = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        arr = group.create_array("0", shape=volume.shape, dtype="float32",
                                 chunks=(1, *volume.shape[1:]),
                                 dimension_names=[a.name for a in axes])
        arr[:] = volume
        write_depth_coordinate(group, first.name, attrs.get("depths_mm"), volume.shape[0])
        group.update_attributes({**attrs, "diffuserlab": VOLUME_MARKER,
                                 "ome": image_attrs([("volume", "0", axes, meta)])})


def write_volume_products(volume: np.ndarray, path: Path, mip_paths: dict[str, Path],
                          attrs: dict, pitch_um: float | None = None, *,
                          replace: bool = True) -> None:
    """Write a volume (:func:`write_volume`) and its three projection views, all or none.

    Parameters
    ----------
    volume : numpy.ndarray
        Shape (n_z, rows, cols), the model grid (:data:`recon.io.DATA_ORIENTATION`).
    path : pathlib.Path
        ``OUT.tif``/``OUT.tiff`` or ``OUT.zarr``.
    mip_paths : dict of str to pathlib.Path
        The ``xy``, ``xz`` and ``yz`` PNGs (:func:`volume_output_paths`): maximum
        projections (:func:`projections`) of the volume turned upright (rows and
        columns flipped, :func:`recon.io.scene_view`).
    attrs : dict
        The volume's metadata (:func:`write_volume`).
    pitch_um : float, optional
        The grid's lateral pitch, um.
    replace : bool
        Replace existing outputs; False: an output another process wrote meanwhile is
        kept and this call refused (:func:`~instrument.atomic.output_group`).

    Raises
    ------
    recon.errors.ReconInputError
        ``replace`` is False and an output's name was taken meanwhile.
    diffuserlab.errors.InputError
        ``path`` is an existing Zarr node that is no volume written here.
    OSError
        A write failed; nothing is in place.
    """
    with output_group(replace=replace):  # the volume and its projections: all or none
        write_volume(path, volume, attrs, pitch_um=pitch_um)
        for view, image in projections(scene_view(volume, axes=(1, 2))).items():
            save_image(mip_paths[view], image)

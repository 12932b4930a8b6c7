"""Image files written whole or not at all: the project's image products.

:func:`save_image` writes the 32-bit float TIFF data product, the 8-bit PNG view or a
NumPy ``.npy`` file; :func:`write_planes_zarr` a stack too large to hold, one plane at a
time, as a Zarr array; :func:`write_snapshot` the GUI's snapshot of an image view (the
data shown, its metadata as the TIFF's JSON description). JSON files are written by
:func:`instrument.atomic.write_json`. All write through
:func:`instrument.atomic.atomic_path`, so they join an
:func:`instrument.atomic.output_group`. Loading stays in :mod:`recon.io`.
"""

from __future__ import annotations

import errno
import json
import logging
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import tifffile

from diffuserlab.errors import InputError
from diffuserlab.jsonio import jsonable
from recon.errors import ReconInputError
from recon.validate import as_array

from ..atomic import atomic_dir, atomic_path

logger = logging.getLogger(__name__)

__all__ = ["SAVE_EXTENSIONS", "save_image", "write_planes_zarr", "write_snapshot",
           "write_tiff_file"]

_TIFF_EXTENSIONS = (".tif", ".tiff")

#: File extensions :func:`save_image` accepts (lower case; matching is case-insensitive).
SAVE_EXTENSIONS: tuple[str, ...] = _TIFF_EXTENSIONS + (".png", ".npy")


def _viewing_image(image: np.ndarray) -> np.ndarray:
    """Scale to 8 bits: 0 -> 0, 99.9th percentile -> 255, negatives and non-finite -> 0."""
    data = np.nan_to_num(image.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    np.clip(data, 0.0, None, out=data)
    top = float(np.percentile(data, 99.9)) if data.size else 0.0
    if top <= 0.0:
        top = float(data.max()) if data.size else 0.0
    if top <= 0.0:
        return np.zeros(data.shape, dtype=np.uint8)
    data *= 255.0 / top
    np.clip(data, 0.0, 255.0, out=data)
    return np.rint(data).astype(np.uint8)



def save_image(path: str | os.PathLike, image: np.ndarray) -> None:
    """Save an image as a float32 TIFF data product, an 8-bit PNG view, or ``.npy``.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; the format follows the (case-insensitive) extension.
        Missing parent directories are created. The file is written under a
        temporary name and renamed into place
        (:func:`~instrument.atomic.atomic_path`): a failure
        never leaves a partial file under ``path``.

        * ``.tif``/``.tiff``: the 32-bit data product. The image is written as
          float32 (values unchanged, no scaling) with :func:`tifffile.imwrite`;
          3/4-channel images as contiguous RGB(A), others as min-is-black.
        * ``.png``: a viewing image, not data. Values are scaled linearly so
          that 0 maps to 0 and the 99.9th percentile (over all channels) maps to
          255, clipped; negatives and NaN/inf become 0. RGB(A) is converted to
          OpenCV's BGR(A) order before ``cv2.imwrite``.
        * ``.npy``: :func:`numpy.save` of the array in its own dtype.
    image : numpy.ndarray
        Shape (H, W) or (H, W, C), channels last, any real numeric dtype.
        PNG output needs C in {1, 3, 4}.

    Raises
    ------
    ReconInputError
        If the extension is not supported, the array is not 2D/3D or not
        numeric, a PNG is asked for with an unsupported channel count, or the
        file cannot be written.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SAVE_EXTENSIONS:
        raise ReconInputError(
            f"{path}: cannot save with extension {suffix or '(none)'!r}; "
            f"use one of {', '.join(SAVE_EXTENSIONS)}"
        )
    image = as_array(image, f"{path}: image")
    if image.ndim not in (2, 3) or image.size == 0:
        raise ReconInputError(
            f"{path}: cannot save an array of shape {image.shape}; "
            "pass a non-empty 2D (H, W) or 3D (H, W, C) image"
        )
    if image.dtype.kind not in "biuf":
        raise ReconInputError(
            f"{path}: cannot save dtype {image.dtype} as an image; pass real numeric data"
        )
    channels = 1 if image.ndim == 2 else image.shape[2]
    if suffix == ".png" and channels not in (1, 3, 4):
        raise ReconInputError(
            f"{path}: a PNG needs 1, 3 or 4 channels, the image has {channels}; "
            "save it as .tif or .npy instead"
        )
    try:
        with atomic_path(path) as tmp:
            if suffix in _TIFF_EXTENSIONS:
                data = np.ascontiguousarray(image, dtype=np.float32)
                photometric = "rgb" if channels in (3, 4) and image.ndim == 3 else "minisblack"
                planar = "contig" if image.ndim == 3 else None
                tifffile.imwrite(tmp, data, photometric=photometric, planarconfig=planar)
            elif suffix == ".png":
                view = _viewing_image(image)
                if view.ndim == 3 and channels == 1:
                    view = view[:, :, 0]
                elif channels == 3:
                    view = cv2.cvtColor(view, cv2.COLOR_RGB2BGR)
                elif channels == 4:
                    view = cv2.cvtColor(view, cv2.COLOR_RGBA2BGRA)
                if not cv2.imwrite(str(tmp), view):
                    raise ReconInputError(
                        f"{path}: OpenCV failed to write the PNG; check the directory is "
                        "writable")
            else:
                with open(tmp, "wb") as fh:  # np.save(name) would append .npy to the name
                    np.save(fh, image, allow_pickle=False)
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO):
            raise  # the disk's problem, named with its path (and free space) already
        raise ReconInputError(
            f"{path}: cannot write file ({exc}); check the directory exists and is writable"
        ) from exc
    logger.debug("saved %s: shape %s, dtype %s", path, image.shape, image.dtype)


def write_snapshot(path: str | Path, image: np.ndarray, metadata: dict[str, Any]) -> Path:
    """Write ``image`` as a TIFF with ``metadata`` as its JSON description.

    Parameters
    ----------
    path : str or Path
        ``.tif``/``.tiff`` file to create (an existing file is refused).
    image : ndarray, (rows, cols)
        Written in its own dtype (the data, not the colours shown).
    metadata : dict
        JSON-able; read back with ``tifffile.TiffFile(path).shaped_metadata[0]``.

    Returns
    -------
    Path

    Raises
    ------
    FileExistsError
        ``path`` exists (a snapshot never replaces a file).
    diffuserlab.errors.InputError
        Not a TIFF name.
    OSError
        The file cannot be written (a full disk named with its free space); nothing is
        left under ``path``.
    """
    path = Path(path)
    if path.suffix.lower() not in (".tif", ".tiff"):
        raise InputError(f"snapshot {path}: give a .tif or .tiff file name")
    if path.exists():
        raise FileExistsError(17, "a snapshot never replaces a file; choose another name",
                              str(path))
    meta = json.loads(json.dumps(jsonable(metadata), default=str))
    with atomic_path(path) as tmp:  # its folder is made; never half a file under path
        tifffile.imwrite(tmp, np.ascontiguousarray(image), metadata=meta)
    return path


def write_tiff_file(path: str | os.PathLike, array: np.ndarray, **tags: Any) -> Path:
    """Write ``array`` as a TIFF with the tags another module built
    (:func:`instrument.runs.tiff_export.write_tiff`'s ImageJ hyperstack or OME-TIFF): the
    one place outside the products above where a TIFF is written.

    Parameters
    ----------
    path : str or os.PathLike
        The file: an :func:`instrument.atomic.atomic_path` temporary (the caller makes
        the output whole or not at all).
    array : numpy.ndarray
        Any shape and dtype ``tifffile`` writes.
    **tags
        Passed to :func:`tifffile.imwrite` (``imagej``, ``ome``, ``metadata``,
        ``resolution``, ``photometric``).

    Returns
    -------
    pathlib.Path
        ``path`` (an ``OSError`` when it cannot be written).
    """
    tifffile.imwrite(path, array, **tags)
    return Path(path)


def write_planes_zarr(path: str | os.PathLike, planes: Iterable[np.ndarray],
                      shape: tuple[int, int, int], dtype: str = "float32") -> Path:
    """Write a stack one plane at a time as a Zarr v3 array (chunks of one plane), so
    only one plane is held in memory; whole or not at all
    (:func:`~instrument.atomic.atomic_dir`).

    Parameters
    ----------
    path : str or os.PathLike
        The new Zarr store (a folder; replaced if it exists).
    planes : iterable of numpy.ndarray
        ``shape[0]`` planes of shape ``shape[1:]``, in order (a generator: each is
        computed when it is written).
    shape : tuple of int
        ``(planes, height, width)``.
    dtype : str
        The array's dtype (default float32); each plane is cast to it.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        ``planes`` gives more or fewer than ``shape[0]`` planes (nothing is left under
        ``path``).
    OSError
        The store cannot be written (nothing is left under ``path``).
    """
    import zarr

    n = int(shape[0])
    with atomic_dir(path) as tmp:
        store = zarr.create_array(str(tmp), shape=tuple(shape), chunks=(1, *shape[1:]),
                                  dtype=dtype, zarr_format=3)
        k = -1
        for k, plane in enumerate(planes):
            if k >= n:
                raise ValueError(f"more than the {n} planes of {path}")
            store[k] = np.asarray(plane, dtype=dtype)
        if k + 1 != n:
            raise ValueError(f"{k + 1} planes given for the {n} of {path}")
    return Path(path)

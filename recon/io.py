"""Image file input and Bayer demosaicing for the reconstruction layer.

Readers return arrays in the file's native dtype with channels last, so the
preprocessing step (:mod:`recon.preprocess`) sees exactly what the sensor
recorded. The reconstruction layer writes no files: its arrays and records are
written by :mod:`instrument.writer` (the float TIFF data product, the PNG view, JSON).

Every refusal raises :class:`recon.errors.ReconInputError` with a one-line
message that names the file, the problem and the fix.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import cv2
import numpy as np
import tifffile

from recon.errors import ReconInputError
from recon.validate import as_array

logger = logging.getLogger(__name__)

__all__ = [
    "BAYER_PATTERNS",
    "LOAD_EXTENSIONS",
    "demosaic_bayer",
    "DATA_ORIENTATION",
    "load_image",
    "scene_view",
]

_TIFF_EXTENSIONS = (".tif", ".tiff")
_CV2_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp")
_NPY_EXTENSIONS = (".npy",)

#: File extensions :func:`load_image` accepts (lower case; matching is case-insensitive).
LOAD_EXTENSIONS: tuple[str, ...] = _TIFF_EXTENSIONS + _CV2_EXTENSIONS + _NPY_EXTENSIONS

#: Orientation of reconstructions in data files (TIFF, ``.npy``, Zarr) and in the
#: arrays the solvers return: the object grid of the convolution model (Kuo 2020,
#: Eq. 3.3: a point at object position x lands at u = -m x on the sensor), i.e. the
#: scene rotated by 180 degrees. PNG views are turned upright with :func:`scene_view`.
DATA_ORIENTATION = "model grid (Eq. 3.3, u = -m x): the scene rotated by 180 degrees"

# Sensor colour-filter layout (top-left 2x2 block, row by row) -> OpenCV code.
# OpenCV's historical Bayer names describe the 2nd and 3rd pixels of the 2nd
# row, so an RGGB sensor (R at (0, 0), B at (1, 1)) is OpenCV's "BG" pattern.
# tests/recon/test_io.py pins this mapping with a synthetic mosaic.
_BAYER_CODES: dict[str, int] = {
    "RGGB": cv2.COLOR_BayerBG2RGB,
    "BGGR": cv2.COLOR_BayerRG2RGB,
    "GRBG": cv2.COLOR_BayerGB2RGB,
    "GBRG": cv2.COLOR_BayerGR2RGB,
}
#: Bayer patterns :func:`demosaic_bayer` accepts, named by the sensor's top-left 2x2 block.
BAYER_PATTERNS: tuple[str, ...] = tuple(_BAYER_CODES)

# Largest channel count treated as colour channels (gray, gray+alpha, RGB, RGBA).
_MAX_CHANNELS = 4


def _suffix(path: Path) -> str:
    return path.suffix.lower()


def _shape_str(shape: tuple[int, ...]) -> str:
    return "x".join(str(s) for s in shape) if shape else "scalar"


def _read_tiff(path: Path) -> np.ndarray:
    """One image of a TIFF file, channels last; colour only from the file's samples.

    A TIFF says what its axes are: ``S`` (samples per pixel, set with an RGB/RGBA
    photometric tag or extra samples) is colour; any other axis (pages ``Q``/``I``,
    ``Z``, ``T``, ``C`` of a grey stack) is a stack of frames. So a 3-page TIFF of
    three frames is refused as a stack, not read as R, G, B.
    """
    try:
        with tifffile.TiffFile(path) as tif:
            series = tif.series[0]
            image = np.asarray(series.asarray())
            axes = str(series.axes)
    except Exception as exc:  # tifffile raises TiffFileError, ValueError, OSError, ...
        raise ReconInputError(
            f"{path}: cannot read as TIFF ({type(exc).__name__}: {exc}); "
            "check that the file is a complete, uncorrupted TIFF or re-export it"
        ) from exc
    if len(axes) != image.ndim:  # an unusual series: keep tifffile's own shape
        return image
    keep = [i for i, a in enumerate(axes) if a in "YXS" or image.shape[i] != 1]
    image = image.reshape([image.shape[i] for i in keep])
    axes = "".join(axes[i] for i in keep)
    frames = [(a, image.shape[i]) for i, a in enumerate(axes) if a not in "YXS"]
    if frames:
        count = int(np.prod([n for _, n in frames]))
        rows, cols = (image.shape[axes.index(a)] for a in "YX")
        raise ReconInputError(
            f"{path}: file holds a stack of {count} images of {rows}x{cols} (grey frames, "
            f"TIFF axes {axes}) where one image was expected; colour comes from an "
            "RGB photometric tag (samples per pixel), never from a page count: pass one "
            "frame (tifffile.imwrite('one.tif', tifffile.imread(FILE, key=0))), save a colour "
            "image as RGB (photometric='rgb'), or load a PSF stack with the stack reader "
            "(recon3d --psf-stack, recon --psf STACK --depth MM)")
    if "S" in axes:
        image = np.moveaxis(image, axes.index("S"), -1)
    return image


def _read_cv2(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ReconInputError(
            f"{path}: OpenCV could not decode the image (corrupt, truncated or not really "
            f"a {_suffix(path)} file); re-export it, or save it as TIFF"
        )
    if image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA)
    return image


def _read_npy(path: Path) -> np.ndarray:
    try:
        data = np.load(path, allow_pickle=False)
    except Exception as exc:  # ValueError (pickled/corrupt), OSError, EOFError, ...
        raise ReconInputError(
            f"{path}: cannot read as .npy ({type(exc).__name__}: {exc}); "
            "save the image with numpy.save from a plain numeric array"
        ) from exc
    if not isinstance(data, np.ndarray):
        # np.load returns an NpzFile for .npz content behind a .npy name.
        if hasattr(data, "close"):
            data.close()
        raise ReconInputError(
            f"{path}: file holds an .npz archive, not a single array; "
            "save one image per file with numpy.save"
        )
    return data


def _to_channels_last(path: Path, image: np.ndarray, is_tiff: bool) -> np.ndarray:
    """Check the dimensionality and return (H, W) or (H, W, C) with C <= 4."""
    shape = image.shape
    if image.ndim == 4:
        raise ReconInputError(
            f"{path}: file holds a stack of {shape[0]} images ({_shape_str(shape)}) where "
            "one image was expected; pass a single frame (e.g. export one plane) "
            "or load the stack with the stack reader"
        )
    if image.ndim not in (2, 3):
        raise ReconInputError(
            f"{path}: array has {image.ndim} dimension(s) ({_shape_str(shape)}), an image "
            "must be 2D (H, W) or 3D (H, W, C); save the image itself, not a slice or a stack"
        )
    if image.ndim == 2:
        return image
    first, _, last = shape
    if is_tiff or last in (1, 3, 4):  # a TIFF's axes were read from its tags
        pass
    elif first == 1:
        image = image[0]
    elif last <= _MAX_CHANNELS:
        raise ReconInputError(
            f"{path}: an array of shape {_shape_str(shape)} has {last} values per pixel; "
            "colour is a last axis of 3 (RGB) or 4 (RGBA) samples: pass one grey image "
            "(H, W) or an RGB(A) one (H, W, 3 or 4)")
    else:
        raise ReconInputError(
            f"{path}: file holds a stack of {first} images of {shape[1]}x{shape[2]} where one "
            "image was expected; pass a single frame (e.g. export one plane) or load the "
            "stack with the stack reader"
        )
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    return image


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Load one image from a TIFF, PNG, JPEG, BMP or ``.npy`` file.

    Parameters
    ----------
    path : str or os.PathLike
        File to read. The reader is chosen by the (case-insensitive) extension:
        ``.tif``/``.tiff`` via :func:`tifffile.imread`; ``.png``, ``.jpg``,
        ``.jpeg``, ``.bmp`` via ``cv2.imread(..., cv2.IMREAD_UNCHANGED)``;
        ``.npy`` via ``numpy.load(allow_pickle=False)``.

    Returns
    -------
    numpy.ndarray
        The image in the file's native dtype (e.g. uint8, uint16 sensor counts,
        float32), shape (H, W) or (H, W, C) with channels last and C <= 4.
        Colour comes from the file, never from a count of frames: a TIFF's samples
        per pixel (its photometric RGB tag; planar RGB, stored (C, H, W), is returned
        as (H, W, C)), the colour of a PNG/JPEG/BMP, or a last axis of 3 or 4 of a
        ``.npy`` array. Colour images read through OpenCV are returned in RGB(A)
        order (OpenCV reads BGR(A)). A singleton axis, (H, W, 1) or (1, H, W), is
        dropped to give (H, W).

    Raises
    ------
    ReconInputError
        If the file does not exist, the extension is not supported, the file
        cannot be decoded (corrupt or truncated), the array is not 2D/3D, or the
        file holds a stack of images where one image was expected (a TIFF of
        several grey pages, whatever their count; a ``.npy`` array whose last
        axis is not 1, 3 or 4 values per pixel).

    Notes
    -----
    The DiffuserCam tutorial data (``psf_sample.tif``, ``rawdata_hand_sample.tif``)
    are 1200 x 1600 uint16 TIFFs and load as such.
    """
    path = Path(path)
    suffix = _suffix(path)
    if suffix not in LOAD_EXTENSIONS:
        raise ReconInputError(
            f"{path}: unsupported file extension {suffix or '(none)'!r}; "
            f"convert the image to one of {', '.join(LOAD_EXTENSIONS)}"
        )
    if not path.exists():
        raise ReconInputError(f"{path}: file not found; check the path and the working directory")
    if not path.is_file():
        raise ReconInputError(f"{path}: is not a regular file (a directory?); pass an image file")

    if suffix in _TIFF_EXTENSIONS:
        image = _read_tiff(path)
    elif suffix in _CV2_EXTENSIONS:
        image = _read_cv2(path)
    else:
        image = _read_npy(path)

    if image.dtype.kind not in "biuf":
        raise ReconInputError(
            f"{path}: array dtype {image.dtype} is not a numeric image type; "
            "save the image as integer or float data"
        )
    image = _to_channels_last(path, image, is_tiff=suffix in _TIFF_EXTENSIONS)
    logger.debug("loaded %s: shape %s, dtype %s", path, image.shape, image.dtype)
    return image


def scene_view(image: np.ndarray, axes: tuple[int, int] = (0, 1)) -> np.ndarray:
    """A reconstruction turned from the model grid to scene orientation, for viewing.

    The lensless camera images a plane inverted (Kuo 2020, Eq. 3.3: u = -m x), so a
    reconstruction on the model grid (:data:`DATA_ORIENTATION`) shows the scene
    rotated by 180 degrees; flipping both lateral axes shows it upright, as a
    person in front of the camera sees it. Data files keep the model grid.

    Parameters
    ----------
    image : numpy.ndarray
        Any dtype; (H, W), (H, W, C) channels last, or a volume (Z, H, W) with
        ``axes=(1, 2)``.
    axes : tuple of int
        The (row, column) axes to flip.

    Returns
    -------
    numpy.ndarray
        A flipped view (no copy), same shape and dtype.

    Raises
    ------
    ReconInputError
        ``image`` is not an array, or ``axes`` are not two of its axes.
    """
    arr = as_array(image, "image")
    try:
        return np.flip(arr, axis=axes)
    except (TypeError, ValueError, np.exceptions.AxisError):
        raise ReconInputError(f"cannot flip axes {axes!r} of an image of shape {arr.shape}; "
                              "pass an (H, W) or (H, W, C) image, or a volume with "
                              "axes=(1, 2)") from None


def demosaic_bayer(raw: np.ndarray, pattern: str) -> np.ndarray:
    """Demosaic a raw Bayer sensor image to RGB with OpenCV's bilinear method.

    Parameters
    ----------
    raw : numpy.ndarray
        Raw colour-filter-array image, shape (H, W), dtype uint8 or uint16
        (sensor counts), H, W >= 3.
    pattern : str
        Colour-filter layout of the sensor's top-left 2x2 block, read row by
        row: one of ``"RGGB"``, ``"BGGR"``, ``"GRBG"``, ``"GBRG"`` (case-insensitive).
        For example ``"RGGB"`` means R at (0, 0), G at (0, 1) and (1, 0), B at (1, 1).

    Returns
    -------
    numpy.ndarray
        Shape (H, W, 3), channels in R, G, B order, same dtype as `raw`.

    Raises
    ------
    ReconInputError
        If `pattern` is not one of the four patterns, `raw` is not 2D, is
        smaller than 3x3 (OpenCV then returns zeros), or its dtype is not uint8/uint16.

    Notes
    -----
    OpenCV names its Bayer conversion codes after the 2nd and 3rd pixels of the
    2nd row, so the sensor pattern ``"RGGB"`` uses ``cv2.COLOR_BayerBG2RGB``,
    ``"BGGR"`` uses ``COLOR_BayerRG2RGB``, ``"GRBG"`` uses ``COLOR_BayerGB2RGB``
    and ``"GBRG"`` uses ``COLOR_BayerGR2RGB``.
    """
    key = pattern.upper() if isinstance(pattern, str) else pattern
    if key not in _BAYER_CODES:
        raise ReconInputError(
            f"unknown Bayer pattern {pattern!r}; use one of {', '.join(BAYER_PATTERNS)} "
            "(the sensor's top-left 2x2 block read row by row)"
        )
    raw = as_array(raw, "raw mosaic")
    if raw.ndim != 2:
        raise ReconInputError(
            f"Bayer demosaicing needs a 2D raw mosaic, got shape {raw.shape}; "
            "pass the undemosaiced sensor image (or skip demosaicing for RGB input)"
        )
    if raw.shape[0] < 3 or raw.shape[1] < 3:
        # OpenCV's bilinear demosaicing returns all zeros below 3 rows or columns
        raise ReconInputError(
            f"Bayer mosaic of shape {raw.shape} is smaller than 3x3 pixels (one 2x2 block "
            "and its neighbours); pass the full sensor image"
        )
    if raw.dtype not in (np.uint8, np.uint16):
        raise ReconInputError(
            f"Bayer demosaicing needs uint8 or uint16 sensor counts, got {raw.dtype}; "
            "demosaic before converting to float"
        )
    return cv2.cvtColor(np.ascontiguousarray(raw), _BAYER_CODES[key])

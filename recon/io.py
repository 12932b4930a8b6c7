"""Image file input/output and Bayer demosaicing for the reconstruction layer.

Readers return arrays in the file's native dtype with channels last, so the
preprocessing step (:mod:`recon.preprocess`) sees exactly what the sensor
recorded. Writers produce either the 32-bit float data product (TIFF), a
viewing image (8-bit PNG) or a NumPy ``.npy`` file.

Every refusal raises :class:`recon.errors.ReconInputError` with a one-line
message that names the file, the problem and the fix.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import tempfile
import threading
from collections.abc import Iterator
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
    "atomic_dir",
    "atomic_path",
    "free_space_text",
    "missing_dirs",
    "output_group",
    "remove_empty_dirs",
    "remove_tree",
    "write_json",
    "SAVE_EXTENSIONS",
    "demosaic_bayer",
    "DATA_ORIENTATION",
    "load_image",
    "save_image",
    "scene_view",
]

_TIFF_EXTENSIONS = (".tif", ".tiff")
_CV2_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp")
_NPY_EXTENSIONS = (".npy",)

#: File extensions :func:`load_image` accepts (lower case; matching is case-insensitive).
LOAD_EXTENSIONS: tuple[str, ...] = _TIFF_EXTENSIONS + _CV2_EXTENSIONS + _NPY_EXTENSIONS
#: File extensions :func:`save_image` accepts (lower case; matching is case-insensitive).
SAVE_EXTENSIONS: tuple[str, ...] = _TIFF_EXTENSIONS + (".png",) + _NPY_EXTENSIONS

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


def _size_text(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if abs(n) < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} TB"  # pragma: no cover


def free_space_text(path: str | os.PathLike) -> str:
    """``"23.0 GB free of 80.0 GB on /data"`` for the file system holding ``path`` (its
    nearest existing ancestor); ``"free space unknown"`` when it cannot be read."""
    import shutil

    p = Path(os.path.abspath(os.fspath(path)))
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        usage = shutil.disk_usage(p)
    except OSError:
        return "free space unknown"
    return f"{_size_text(usage.free)} free of {_size_text(usage.total)} on {p}"


def _disk_full(path: Path, exc: OSError) -> OSError | None:
    """An ENOSPC OSError naming ``path`` and the free space for a write that failed
    because the disk (or quota) is full, including numpy's short write ("N requested
    and M written", no errno); None for any other error."""
    import errno
    import re
    import shutil

    text = str(exc)
    short = exc.errno is None and "requested and" in text and "written" in text
    if exc.errno not in (errno.ENOSPC, errno.EDQUOT) and not short:
        return None
    if short:  # numpy says how much it wanted, not why it got less
        wanted = re.search(r"(\d+) requested", text)
        where = Path(os.path.abspath(path)).parent
        while not where.exists() and where != where.parent:
            where = where.parent
        try:
            free = shutil.disk_usage(where).free
        except OSError:
            free = 0
        if wanted and free > int(wanted.group(1)):
            return OSError(errno.EIO, f"the write stopped short ({text}; "
                           f"{free_space_text(path)}: a file-size limit or a failing "
                           "disk); write elsewhere", str(path))
    detail = f"; {text}" if short else ""
    return OSError(errno.ENOSPC, f"No space left on device ({free_space_text(path)}"
                   f"{detail}); free space or write elsewhere", str(path))


#: The open :func:`output_group`'s pending ``(temporary, final)`` renames and the
#: folders its writers created, per thread.
_GROUP = threading.local()


def missing_dirs(path: str | os.PathLike) -> list[Path]:
    """The ancestors of ``path`` (``path`` itself excluded) that do not exist yet, deepest
    first: what writing ``path`` creates, and a failed write removes again
    (:func:`remove_empty_dirs`)."""
    out = []
    p = Path(os.path.abspath(os.fspath(path))).parent
    while not p.exists() and p != p.parent:
        out.append(p)
        p = p.parent
    return out


def _make_parent(path: str | os.PathLike) -> tuple[Path, list[Path]]:
    """Create ``path``'s folder; returns ``(Path(path), the folders made)``, the latter
    also noted in the current :func:`output_group`."""
    path = Path(path)
    made = missing_dirs(path)
    group = getattr(_GROUP, "made", None)
    if group is not None:
        group.extend(made)
    path.parent.mkdir(parents=True, exist_ok=True)
    return path, made


def remove_empty_dirs(dirs) -> None:
    """Remove the folders of :func:`missing_dirs` that are still empty, deepest first."""
    for d in dirs:
        with contextlib.suppress(OSError):
            d.rmdir()


@contextlib.contextmanager
def output_group() -> Iterator[None]:
    """Several outputs written whole or not at all, together.

    Inside the block, every :func:`atomic_path` (so :func:`save_image` too) keeps its
    finished temporary file instead of renaming it; when the block ends normally all
    of them are renamed into place, when it raises all of them are removed. So a
    command that writes ``OUT.png``, ``OUT.tif`` and a JSON never leaves the PNG alone
    when the TIFF fails (a full disk), which would block its retry ("exists").
    Groups do not nest (an inner one joins the outer).
    """
    if getattr(_GROUP, "pending", None) is not None:
        yield
        return
    _GROUP.pending, _GROUP.made = pending, made = [], []
    try:
        yield
    except BaseException:
        for tmp, _ in pending:
            _discard(tmp)
        remove_empty_dirs(made)
        raise
    else:
        for tmp, final in pending:
            _put_in_place(tmp, final)
    finally:
        _GROUP.pending = _GROUP.made = None


def _discard(tmp: Path) -> None:
    """Remove a temporary output: a file, or a folder (:func:`remove_tree`)."""
    if tmp.is_dir():
        remove_tree(tmp)
    else:
        with contextlib.suppress(OSError):
            tmp.unlink()


def _put_in_place(tmp: Path, final: Path) -> None:
    """Rename a finished temporary output over ``final``; a folder replacing a folder
    moves the old one aside first (a rename cannot replace a non-empty folder) and
    removes it after."""
    if not (tmp.is_dir() and final.is_dir()):
        os.replace(tmp, final)
        return
    old = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{final.name}.", suffix=".old"))
    os.replace(final, old)
    os.replace(tmp, final)
    remove_tree(old)


def wait_for_zarr_writes(timeout_s: float = 5.0) -> bool:
    """Wait until zarr's event loop has no task left running (its chunk writes).

    zarr (3.x) runs an array's chunk writes as tasks on one event loop in its own
    thread and gathers them; when one write fails the error reaches the caller while
    the other writes still run and may create folders after the caller cleaned up. This
    waits, on that loop, for every other task to end (each write's thread included).

    Parameters
    ----------
    timeout_s : float
        The longest wait (s).

    Returns
    -------
    bool
        True when no write was left running; False when zarr is not loaded, its loop
        is not running (nothing to wait for) or the wait timed out.
    """
    import asyncio
    import sys

    sync = sys.modules.get("zarr.core.sync")
    loop = getattr(sync, "loop", [None])
    loop = loop[0] if isinstance(loop, list) and loop else None
    if loop is None or not loop.is_running():
        return False

    async def drain() -> None:
        me = asyncio.current_task()
        while others := [t for t in asyncio.all_tasks() if t is not me and not t.done()]:
            await asyncio.wait(others)

    future = asyncio.run_coroutine_threadsafe(drain(), loop)
    try:
        future.result(timeout_s)
    except Exception:  # timed out (or the loop stopped): the settle loop still runs
        future.cancel()
        return False
    return True


def remove_tree(path: str | os.PathLike, settle_s: float = 0.1,
                timeout_s: float = 5.0) -> None:
    """Remove a folder a failed write left, until it stays gone.

    zarr writes chunks on a pool of threads: when one write fails (a full disk), the
    others still finish after the error has reached the caller and may create their
    folders again. So zarr's writes still in flight are waited for first
    (``wait_for_zarr_writes``), then the folder is removed until it stays gone for
    ``settle_s`` (at most ``timeout_s`` in all).
    """
    import shutil
    import time

    path = Path(path)
    deadline = time.monotonic() + timeout_s
    wait_for_zarr_writes(timeout_s)
    while True:
        shutil.rmtree(path, ignore_errors=True)
        time.sleep(settle_s)
        if not path.exists() or time.monotonic() > deadline:
            break


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary folder next to ``path`` to write a directory output to (a Zarr
    array); put in place on success, as :func:`atomic_path` does for a file.

    On success the folder replaces ``path`` (an existing folder is moved aside and
    removed after), or, inside an :func:`output_group`, when the group ends; when the
    block raises, the folder (:func:`remove_tree`: also what zarr's writer threads
    add after the error) and any parent folder it had to create are removed, and a
    full disk is named with its free space.

    Yields
    ------
    pathlib.Path
        The temporary folder (hidden, ``.NAME.XXXX.tmp``, created empty).
    """
    path, made = _make_parent(path)
    tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp"))
    try:
        yield tmp
        pending = getattr(_GROUP, "pending", None)
        if pending is None:
            _put_in_place(tmp, path)
        else:
            pending.append((tmp, path))
    except BaseException as exc:
        remove_tree(tmp)
        remove_empty_dirs(made)
        full = _disk_full(path, exc) if isinstance(exc, OSError) else None
        if full is not None:
            raise full from exc
        raise


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary name next to ``path`` to write to; renamed into place on success.

    The writer inside the ``with`` block writes the temporary file (same directory,
    so the rename is atomic: :func:`os.replace`; same suffix, so writers that choose
    the format by extension still do). When the block succeeds the file replaces
    ``path``; when it raises, the temporary file (and any folder it had to create,
    if still empty) is removed and ``path`` is left as it was: a crash never leaves
    half a file under the final name. A write that
    fails because the disk is full (ENOSPC, a quota, numpy's short write) is raised
    as an ENOSPC OSError naming ``path`` and the free space left.

    Parameters
    ----------
    path : str or os.PathLike
        The final file name. Missing parent directories are created.

    Yields
    ------
    pathlib.Path
        The temporary file name (a hidden file ``.NAME.XXXX.tmpSUFFIX``, created empty).

    Examples
    --------
    >>> with atomic_path("out/metrics.json") as tmp:  # doctest: +SKIP
    ...     tmp.write_text("{}")
    """
    path, made = _make_parent(path)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.",
                                suffix=f".tmp{path.suffix}")
    os.close(fd)
    tmp = Path(name)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; the final file gets the usual mode
    try:
        yield tmp
        group = getattr(_GROUP, "pending", None)
        if group is None:
            os.replace(tmp, path)
        else:  # renamed with the rest of its output_group
            group.append((tmp, path))
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        remove_empty_dirs(made)
        full = _disk_full(path, exc) if isinstance(exc, OSError) else None
        if full is not None:
            raise full from exc
        raise


def write_json(path: str | os.PathLike, data, *, default=None) -> Path:
    """Write ``data`` as indented, standard JSON (:func:`diffuserlab.jsonio.json_text`)
    through :func:`atomic_path`: whole or not at all, and with the other outputs of an
    :func:`output_group`.

    Parameters
    ----------
    path : str or os.PathLike
        The JSON file (replaced if it exists: callers check for overwriting first).
    data : object
        Anything :func:`diffuserlab.jsonio.jsonable` converts; NaN and infinity
        become null.
    default : callable, optional
        What to write for an object JSON has no type for (``str``); None (default)
        raises TypeError.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    TypeError
        ``data`` holds an object JSON cannot represent (nothing is written).
    OSError
        The file cannot be written (a full disk is named with its free space); an
        existing file is left as it was.

    Examples
    --------
    >>> import json, tempfile, pathlib
    >>> p = write_json(pathlib.Path(tempfile.mkdtemp()) / "m.json", {"x": float("inf")})
    >>> json.loads(p.read_text())
    {'x': None}
    """
    from diffuserlab.jsonio import json_text

    text = json_text(data, default=default)  # before the file: a TypeError leaves no trace
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def save_image(path: str | os.PathLike, image: np.ndarray) -> None:
    """Save an image as a float32 TIFF data product, an 8-bit PNG view, or ``.npy``.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; the format follows the (case-insensitive) extension.
        Missing parent directories are created. The file is written under a
        temporary name and renamed into place (:func:`atomic_path`): a failure
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

    Returns
    -------
    None

    Raises
    ------
    ReconInputError
        If the extension is not supported, the array is not 2D/3D or not
        numeric, a PNG is asked for with an unsupported channel count, or the
        file cannot be written.
    """
    path = Path(path)
    suffix = _suffix(path)
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

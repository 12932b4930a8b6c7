"""Dark level: estimate it from a dark image region and subtract it.

The DiffuserCam tutorial (Waller Lab) takes the mean of ``psf[5:15, 5:15]``
(:data:`DEFAULT_DARK_REGION`) as the dark level of both the PSF and the measurement;
a scalar, a per-channel vector or a dark frame can be given instead
(:func:`resolve_dark`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from recon.errors import ReconInputError
from recon.io import demosaic_bayer

from .validation import as_array, require_image

__all__ = [
    "DEFAULT_DARK_REGION",
    "dark_argument",
    "dark_level",
    "level_for_info",
    "resolve_dark",
    "subtract_dark",
]

#: Dark-corner region of the DiffuserCam tutorial: ``psf[5:15, 5:15]``.
DEFAULT_DARK_REGION: tuple[slice, slice] = (slice(5, 15), slice(5, 15))


def dark_level(
    image: np.ndarray, region: tuple[slice, slice] = DEFAULT_DARK_REGION
) -> float | np.ndarray:
    """Estimate the dark (black) level as the mean of a dark image region.

    Parameters
    ----------
    image : numpy.ndarray
        Shape (H, W) or (H, W, C), any real numeric dtype, in sensor counts.
    region : tuple of slice, optional
        (rows, cols) region that sees no light. The default ``(slice(5, 15),
        slice(5, 15))`` is the DiffuserCam tutorial's ``psf[5:15, 5:15]``.

    Returns
    -------
    float or numpy.ndarray
        The mean in the image's units: a Python float for a 2D image, a float32
        array of shape (C,) (one level per channel) for a 3D image.

    Raises
    ------
    ReconInputError
        If the image is empty, non-numeric or not 2D/3D, if `region` is not a
        pair of slices, or if the region selects no pixels (image too small).

    Notes
    -----
    Source: DiffuserCam tutorial preprocessing, ``bg = np.mean(psf[5:15, 5:15])``.
    """
    image = as_array(image, "image")
    require_image(image, "image")
    if (
        not isinstance(region, tuple)
        or len(region) != 2
        or not all(isinstance(s, slice) for s in region)
    ):
        raise ReconInputError(
            f"dark region must be a (rows, cols) pair of slices, got {region!r}; "
            "e.g. (slice(5, 15), slice(5, 15))"
        )
    patch = image[region]
    if patch.shape[0] == 0 or patch.shape[1] == 0:
        rows, cols = (f"{s.start or 0}:{'' if s.stop is None else s.stop}" for s in region)
        raise ReconInputError(
            f"the image is {image.shape[0]}x{image.shape[1]} pixels, too small for its dark "
            f"corner (rows {rows}, cols {cols}, which hold no pixel of it): give the dark "
            "level yourself (--dark LEVEL, or --dark none for dark-subtracted data), or use "
            "the full-size image"
        )
    if image.ndim == 2:
        return float(patch.mean(dtype=np.float64))
    return patch.mean(axis=(0, 1), dtype=np.float64).astype(np.float32)


def subtract_dark(
    image: np.ndarray, dark: float | np.ndarray, *, clip_negative: bool = False
) -> np.ndarray:
    """Subtract a dark level or dark frame, returning float32.

    Parameters
    ----------
    image : numpy.ndarray
        Shape (H, W) or (H, W, C), real numeric dtype, in sensor counts.
    dark : float or numpy.ndarray
        A scalar dark level; a per-channel vector of shape (C,) for a 3D image;
        or a dark frame of exactly ``image.shape``. Same units as `image`.
    clip_negative : bool, optional
        If True, set negative results to 0. Default False: negatives are noise
        around the dark level and clipping them would bias the data upwards.

    Returns
    -------
    numpy.ndarray
        float32, shape ``image.shape``: ``image - dark``.

    Raises
    ------
    ReconInputError
        If `image` is not a non-empty numeric 2D/3D array, `dark` is not
        finite or not numeric, or its shape matches neither a scalar, the
        channel vector nor the image (the message names both shapes).

    Notes
    -----
    Source: DiffuserCam tutorial preprocessing (``psf -= bg; data -= bg``).
    """
    image = as_array(image, "image")
    require_image(image, "image")
    dark_arr = as_array(dark, "dark")
    if dark_arr.dtype.kind not in "uif" or dark_arr.size == 0:
        raise ReconInputError(
            f"dark must be a number, a per-channel vector or a dark frame, got dtype "
            f"{dark_arr.dtype} with shape {dark_arr.shape}; pass numeric dark data"
        )
    n_bad = int(np.count_nonzero(~np.isfinite(dark_arr)))
    if n_bad:
        raise ReconInputError(
            f"dark contains {n_bad} NaN/inf value(s); recapture or repair the dark frame"
        )
    dark32 = dark_arr.astype(np.float32)
    if dark_arr.ndim == 0:
        pass
    elif dark_arr.ndim == 1 and image.ndim == 3 and dark_arr.shape[0] == image.shape[2]:
        pass  # broadcasts over the last (channel) axis
    elif dark_arr.shape != image.shape:
        raise ReconInputError(
            f"dark of shape {dark_arr.shape} does not match image of shape {image.shape}; "
            "pass a scalar, one value per channel, or a dark frame captured with the "
            "same sensor settings and size"
        )
    out = image.astype(np.float32)
    out -= dark32
    if clip_negative:
        np.clip(out, 0.0, None, out=out)
    return out


def front_door_dark(dark: Any) -> Any:
    """The dark argument of :func:`resolve_dark` for the front door's vocabulary.

    :func:`recon.reconstruct` and :class:`recon.live.LiveReconstructor` take ``"auto"``
    (estimate the level from the PSF's dark corner), ``"none"`` or None (subtract
    nothing: the inputs are dark-subtracted already), a level in DN, one level per
    channel or a dark frame; :func:`resolve_dark` spells the estimate None.

    Parameters
    ----------
    dark : str, None, float, array-like
        The front door's form.

    Returns
    -------
    None, "none", float or ndarray
        None for ``"auto"`` (estimate), ``"none"`` for None or ``"none"``, anything
        else unchanged (:func:`resolve_dark` checks it).

    Raises
    ------
    ReconInputError
        A string other than ``"auto"`` or ``"none"``.
    """
    if dark is None:
        return "none"
    if isinstance(dark, str):
        key = dark.strip().lower()
        if key in ("auto", "none"):
            return None if key == "auto" else "none"
        raise ReconInputError(f"dark {dark!r}: give 'auto', 'none' (or None), a level in DN, "
                              "one level per channel or a dark frame")
    return dark


def resolve_dark(
    dark: Any,
    psf: np.ndarray,
    region: tuple[slice, slice],
    bayer: str | None,
) -> tuple[str, float | np.ndarray | None]:
    """Return (mode, dark value) with mode in psf_region, none, scalar, vector, frame."""
    if dark is None:
        return "psf_region", dark_level(psf, region)
    if isinstance(dark, str):
        if dark.lower() == "none":
            return "none", None
        raise ReconInputError(
            f"dark={dark!r} is not understood; use None (estimate from the PSF corner), "
            "'none' (skip), a number, or a dark-frame array"
        )
    if isinstance(dark, bool):
        raise ReconInputError(
            "dark must be None, 'none', a number or an array, not a bool; "
            "use dark='none' to skip dark subtraction"
        )
    dark_arr = as_array(dark, "dark")
    if dark_arr.dtype.kind not in "uif" or dark_arr.size == 0:
        raise ReconInputError(
            f"dark must be None, 'none', a number or a numeric array, got dtype "
            f"{dark_arr.dtype} with shape {dark_arr.shape}; pass numeric dark data"
        )
    if dark_arr.ndim == 0:
        return "scalar", float(dark_arr)
    if dark_arr.ndim == 1:
        return "vector", dark_arr.astype(np.float32)
    if bayer is not None and dark_arr.ndim == 2:
        # The dark frame comes from the same mosaic sensor: demosaic it the same way.
        dark_arr = demosaic_bayer(dark_arr, bayer)
    return "frame", dark_arr


def level_for_info(level: float | np.ndarray | None) -> float | list[float] | None:
    """A dark level as a JSON-friendly float or list of floats (None stays None)."""
    if level is None:
        return None
    arr = np.asarray(level, dtype=np.float64)
    return float(arr) if arr.ndim == 0 else [float(v) for v in arr.ravel()]


def dark_argument(dark, shape: tuple[int, int]) -> tuple[str, float | np.ndarray | None]:
    """``(mode, level)`` of a one-level dark argument: ``"auto"``, ``"none"``/None, DN or a frame.

    The volume and grid reconstructions take one level for the frame (a number or
    a frame); the 2D path also takes one level per channel (:func:`resolve_dark`).

    Parameters
    ----------
    dark : "auto", "none", None, float or ndarray
        As :func:`recon.reconstruct`'s ``dark`` (docs/cli.md's ``--dark``).
    shape : (rows, cols)
        The raw frame's shape, which a dark frame must have.

    Returns
    -------
    mode : {"auto", "none", "value", "frame"}
    level : float, ndarray (rows, cols) float32 or None
        None for ``"auto"`` (estimated by the caller) and ``"none"``.

    Raises
    ------
    ReconInputError
        Anything else, a non-finite number or a frame of another shape.
    """
    if dark is None or (isinstance(dark, str) and dark.strip().lower() == "none"):
        return "none", None
    if isinstance(dark, str) and dark.strip().lower() == "auto":
        return "auto", None
    if isinstance(dark, np.ndarray) and dark.ndim == 2:
        if dark.shape != tuple(shape):
            raise ReconInputError(f"the dark frame is {dark.shape[0]}x{dark.shape[1]} but the "
                                  f"raw image is {shape[0]}x{shape[1]}; give the dark frame "
                                  "of the same camera region")
        frame = np.asarray(dark, np.float32)
        if not np.all(np.isfinite(frame)):
            raise ReconInputError("the dark frame holds NaN or inf values; recapture it")
        return "frame", frame
    if np.ndim(dark) == 0 and not isinstance(dark, (bool, np.bool_, str)):
        try:
            value = float(dark)
        except (TypeError, ValueError):
            value = math.nan
        if math.isfinite(value):
            return "value", value
    raise ReconInputError(f"dark must be 'auto', 'none' (or None), a finite level in DN or a "
                          f"dark frame (rows, cols), got {dark!r}")

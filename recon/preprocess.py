"""Preprocessing of a PSF and a raw measurement before reconstruction.

Plain functions on arrays (scikit-image style) with explicit float32 output.
They follow the preprocessing of the DiffuserCam tutorial (Waller Lab) and of
Sec. 3.3 of N. Antipa/G. Kuo et al. as summarised in G. Kuo, *Exploiting
Randomness in Computational Cameras and Displays* (PhD dissertation, UC
Berkeley, 2020): estimate the dark level from a dark corner of the PSF
(mean of ``psf[5:15, 5:15]``), subtract it from both the PSF and the
measurement, and downsample both by box-averaging. Normalisation is left to
the solver layer (:func:`normalize` is provided for it).

Every refusal raises :class:`recon.errors.ReconInputError` whose message says
what is wrong and how to fix it.
"""

from __future__ import annotations

import logging
import numbers
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recon.errors import ReconInputError
from recon.io import demosaic_bayer

logger = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_DARK_REGION",
    "Prepared",
    "SaturationWarning",
    "box_bin",
    "dark_level",
    "normalize",
    "prepare_pair",
    "saturation_fraction",
    "subtract_dark",
    "validate_measurement",
    "validate_psf",
]

#: Dark-corner region of the DiffuserCam tutorial: ``psf[5:15, 5:15]``.
DEFAULT_DARK_REGION: tuple[slice, slice] = (slice(5, 15), slice(5, 15))

_NORMALIZE_MODES = ("l2", "max", "sum")


class SaturationWarning(UserWarning):
    """More pixels than allowed sit at the sensor's full scale (clipped highlights).

    Saturated pixels break the linear convolution model, so a reconstruction
    from them shows artefacts; lower the exposure or the source power.
    """


@dataclass(frozen=True)
class Prepared:
    """A PSF and measurement ready for a forward model and solver.

    Attributes
    ----------
    psf : numpy.ndarray
        float32, shape (h, w) (one PSF shared by every channel of `raw`) or
        (h, w, C); dark-subtracted, binned, clipped at 0, with positive sum.
    raw : numpy.ndarray
        float32, shape (h, w) or (h, w, C); dark-subtracted and binned.
        Negative values (noise around the dark level) are kept.
    info : dict
        What was done: input shapes and dtypes, dark mode and levels,
        bin factor, saturated fractions, channels; see :func:`prepare_pair`.
    """

    psf: np.ndarray
    raw: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)


# ----------------------------------------------------------------------------- helpers


def _as_array(image: Any, name: str) -> np.ndarray:
    try:
        return np.asarray(image)
    except Exception as exc:  # ragged sequences and the like
        raise ReconInputError(
            f"{name} cannot be converted to an array ({exc}); pass a numpy array"
        ) from exc


def _require_image(image: np.ndarray, name: str) -> None:
    """Refuse arrays that are not non-empty 2D/3D real numeric images."""
    if image.dtype.kind not in "uif":
        raise ReconInputError(
            f"{name} has non-numeric dtype {image.dtype}; pass integer sensor counts or "
            "float intensities"
        )
    if image.size == 0:
        raise ReconInputError(
            f"{name} is empty (shape {image.shape}); check the file and any cropping"
        )
    if image.ndim not in (2, 3):
        raise ReconInputError(
            f"{name} must be 2D (H, W) or 3D (H, W, C), got shape {image.shape}; "
            "pass one image, channels last"
        )


def _channels(image: np.ndarray) -> int:
    return 1 if image.ndim == 2 else image.shape[2]


def _full_scale_of(dtype: np.dtype) -> float | None:
    if dtype.kind in "ui":
        return float(np.iinfo(dtype).max)
    return None


def _check_bin_factor(factor: Any) -> int:
    if isinstance(factor, bool) or not isinstance(factor, numbers.Integral) or factor < 1:
        raise ReconInputError(
            f"bin factor must be an integer >= 1, got {factor!r}; e.g. 1 (no binning), 2 or 4"
        )
    return int(factor)


def _level_for_info(level: float | np.ndarray | None) -> float | list[float] | None:
    if level is None:
        return None
    arr = np.asarray(level, dtype=np.float64)
    return float(arr) if arr.ndim == 0 else [float(v) for v in arr.ravel()]


# ----------------------------------------------------------------------------- functions


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
    image = _as_array(image, "image")
    _require_image(image, "image")
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
        raise ReconInputError(
            f"dark region {region!r} selects no pixels of an image of shape {image.shape}; "
            "choose a region inside the image"
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
    image = _as_array(image, "image")
    _require_image(image, "image")
    dark_arr = _as_array(dark, "dark")
    if dark_arr.dtype.kind not in "uif" or dark_arr.size == 0:
        raise ReconInputError(
            f"dark must be a number, a per-channel vector or a dark frame, got {dark!r:.80}; "
            "pass numeric dark data"
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


def box_bin(image: np.ndarray, factor: int) -> np.ndarray:
    """Downsample by averaging non-overlapping ``factor x factor`` blocks.

    Parameters
    ----------
    image : numpy.ndarray
        Shape (H, W) or (H, W, C), real numeric dtype. Channels are binned
        independently.
    factor : int
        Block size, an integer >= 1 and <= min(H, W). If H or W is not a
        multiple of `factor`, the remainder rows (bottom) and columns (right)
        are cropped and a warning is logged.

    Returns
    -------
    numpy.ndarray
        float32, shape (H // factor, W // factor[, C]); block means
        (accumulated in float64). ``factor=1`` returns a float32 copy.

    Raises
    ------
    ReconInputError
        If `factor` is not an integer >= 1 (floats such as 2.0 and bools are
        refused), is larger than the image, or the image is not a non-empty
        numeric 2D/3D array.

    Notes
    -----
    Source: DiffuserCam tutorial ``resize``, which averages 2x2 blocks
    repeatedly (factor 1/4 per axis: 1200 x 1600 -> 300 x 400, i.e.
    ``box_bin(image, 4)``).
    """
    image = _as_array(image, "image")
    _require_image(image, "image")
    factor = _check_bin_factor(factor)
    height, width = image.shape[:2]
    if factor > height or factor > width:
        raise ReconInputError(
            f"bin factor {factor} is larger than the image ({height}x{width}); "
            "use a smaller bin factor"
        )
    if factor == 1:
        return image.astype(np.float32, copy=True)
    out_h, out_w = height // factor, width // factor
    if out_h * factor != height or out_w * factor != width:
        logger.warning(
            "box_bin: image %dx%d is not divisible by bin factor %d; cropping %d row(s) at "
            "the bottom and %d column(s) at the right",
            height,
            width,
            factor,
            height - out_h * factor,
            width - out_w * factor,
        )
    cropped = image[: out_h * factor, : out_w * factor]
    blocks = cropped.reshape((out_h, factor, out_w, factor) + image.shape[2:])
    return blocks.mean(axis=(1, 3), dtype=np.float64).astype(np.float32)


def saturation_fraction(image: np.ndarray, full_scale: float | None = None) -> float:
    """Fraction of samples at (or above) the sensor's full scale.

    Parameters
    ----------
    image : numpy.ndarray
        Shape (H, W) or (H, W, C), real numeric dtype, in sensor counts.
        For a 3D image every channel sample counts separately.
    full_scale : float, optional
        Value that counts as saturated. Default: the dtype maximum for integer
        images (e.g. 65535 for uint16). Pass it explicitly for sensors whose
        range is smaller than the container (e.g. 12-bit data in uint16).

    Returns
    -------
    float
        Fraction in [0, 1] of samples ``>= full_scale``. For float images
        without `full_scale` the saturation level is unknown and 0.0 is
        returned.

    Raises
    ------
    ReconInputError
        If the image is not a non-empty numeric 2D/3D array, or `full_scale`
        is not a finite number.
    """
    image = _as_array(image, "image")
    _require_image(image, "image")
    if full_scale is None:
        full_scale = _full_scale_of(image.dtype)
        if full_scale is None:
            logger.debug("saturation_fraction: float image without full_scale; returning 0.0")
            return 0.0
    elif (
        isinstance(full_scale, bool)
        or not isinstance(full_scale, numbers.Real)
        or not np.isfinite(full_scale)
    ):
        raise ReconInputError(
            f"full_scale must be a finite number, got {full_scale!r}; e.g. 4095 for 12-bit data"
        )
    return float(np.count_nonzero(image >= full_scale)) / image.size


def _validate_common(image: Any, name: str, fix: str) -> np.ndarray:
    image = _as_array(image, name)
    _require_image(image, name)
    if image.dtype.kind == "f":
        n_bad = int(np.count_nonzero(~np.isfinite(image)))
        if n_bad:
            raise ReconInputError(
                f"{name} contains {n_bad} NaN/inf value(s) out of {image.size}; {fix}"
            )
    return image


def validate_psf(psf: np.ndarray) -> None:
    """Check that a PSF can be used for reconstruction.

    Parameters
    ----------
    psf : numpy.ndarray
        Point-spread function (image of a point source through the diffuser),
        shape (H, W) or (H, W, C), integer or float dtype, in sensor counts or
        arbitrary intensity units.

    Returns
    -------
    None

    Raises
    ------
    ReconInputError
        If the PSF is empty, not 2D/3D, of a non-numeric dtype (including bool
        and complex), contains NaN/inf (the message gives the count), is all
        zero, or has no positive value.
    """
    psf = _validate_common(psf, "PSF", "recapture the PSF or repair the file")
    if not np.any(psf):
        raise ReconInputError(
            "PSF is all zero; check the capture (light source on, exposure, lens cap) "
            "and recapture the PSF"
        )
    if not np.any(psf > 0):
        raise ReconInputError(
            "PSF has no positive values (an intensity must be >= 0 with some signal); "
            "check the sign convention or the dark subtraction and recapture the PSF"
        )


def validate_measurement(raw: np.ndarray) -> None:
    """Check that a raw measurement can be used for reconstruction.

    Parameters
    ----------
    raw : numpy.ndarray
        Raw sensor image of the scene, shape (H, W) or (H, W, C), integer or
        float dtype, in sensor counts.

    Returns
    -------
    None

    Raises
    ------
    ReconInputError
        If the measurement is empty, not 2D/3D, of a non-numeric dtype
        (including bool and complex) or contains NaN/inf (the message gives the
        count). An all-zero measurement is only logged as a warning.
    """
    raw = _validate_common(raw, "measurement", "recapture the measurement or repair the file")
    if not np.any(raw):
        logger.warning("measurement is all zero; the reconstruction will be zero")


def _check_saturation(
    image: np.ndarray, name: str, threshold: float | None, full_scale: float | None = None
) -> float:
    fraction = saturation_fraction(image, full_scale)
    if threshold is not None and fraction > threshold:
        full = full_scale if full_scale is not None else _full_scale_of(image.dtype)
        message = (
            f"{name}: {fraction:.4%} of samples are at full scale ({full:g}), above the "
            f"{threshold:.4%} limit; saturation breaks the linear model, "
            "lower the exposure or source power and recapture"
        )
        logger.warning(message)
        warnings.warn(message, SaturationWarning, stacklevel=3)
    return fraction


def _resolve_dark(
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
    dark_arr = _as_array(dark, "dark")
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


def prepare_pair(
    psf: np.ndarray,
    raw: np.ndarray,
    *,
    bin_factor: int = 1,
    dark: None | str | float | np.ndarray = None,
    dark_region: tuple[slice, slice] = DEFAULT_DARK_REGION,
    bayer: str | None = None,
    warn_saturation: float | None = 0.001,
    full_scale: float | None = None,
) -> Prepared:
    """Validate and preprocess a PSF and a raw measurement for reconstruction.

    Steps, in order: validate both inputs; check saturation at the input
    dtype's full scale; demosaic 2D inputs if `bayer` is given; check channel
    and spatial shapes; subtract the dark level from both images; bin both by
    `bin_factor`; clip the PSF at 0; check the PSF still has signal.
    No normalisation is done here (the solver layer scales; see :func:`normalize`).

    Parameters
    ----------
    psf : numpy.ndarray
        Point-spread function, shape (H, W) or (H, W, C), integer (sensor
        counts) or float dtype.
    raw : numpy.ndarray
        Raw measurement, shape (H, W) or (H, W, C), same H, W as `psf`.
    bin_factor : int, optional
        Box-average ``bin_factor x bin_factor`` blocks (see :func:`box_bin`).
        Default 1 (no binning); the DiffuserCam tutorial uses 4.
    dark : None, "none", float, or numpy.ndarray, optional
        ``None`` (default): estimate the dark level from `dark_region` of the
        PSF (:func:`dark_level`; per channel for colour) and subtract it from
        BOTH images, as the DiffuserCam tutorial does. ``"none"``: skip dark
        subtraction. A number: subtract it from both. An array: a per-channel
        vector (C,) or a dark frame (same shape as the images, or the 2D mosaic
        when `bayer` is given, which is then demosaiced too) subtracted from both.
    dark_region : tuple of slice, optional
        (rows, cols) dark corner of the PSF, in input pixels. Default
        ``(slice(5, 15), slice(5, 15))`` as in the tutorial.
    bayer : str, optional
        Bayer pattern (``"RGGB"``, ``"BGGR"``, ``"GRBG"``, ``"GBRG"``) to demosaic
        2D uint8/uint16 inputs to RGB (:func:`recon.io.demosaic_bayer`); 3D
        inputs are left as they are. Default None (no demosaicing).
    warn_saturation : float or None, optional
        Warn (``logging.warning`` and :class:`SaturationWarning`) when the
        fraction of samples of `psf` or `raw` at the input dtype's full scale
        exceeds this value. Default 0.001 (0.1 %). None disables the check.
        Float inputs have no known full scale and never warn.
    full_scale : float or None, optional
        The sensor's saturation level in input units when it is not the dtype's
        maximum, e.g. 65520 for 12-bit data shifted into uint16 (the tutorial
        sample) or 4095 for unshifted 12-bit data. Default: the dtype maximum.

    Returns
    -------
    Prepared
        ``psf``: float32, (h, w) or (h, w, C), clipped at 0, positive sum;
        a 2D PSF with a 3D `raw` stays 2D and is used for every channel.
        ``raw``: float32, (h, w) or (h, w, C), negatives kept.
        ``info``: dict with keys ``psf_shape_in``, ``raw_shape_in``,
        ``psf_dtype_in``, ``raw_dtype_in`` (str), ``bayer``, ``dark_mode``
        (``"psf_region"``, ``"none"``, ``"scalar"``, ``"vector"``, ``"frame"``),
        ``dark_level`` (float, per-channel list, None, or for a frame its
        mean), ``dark_region`` (``((start, stop), (start, stop))`` or None),
        ``bin_factor``, ``saturated_fraction_psf``, ``saturated_fraction_raw``,
        ``channels`` (of `raw`; 1 for 2D), ``psf_shared_across_channels``,
        ``psf_clipped_fraction`` (fraction of PSF samples set to 0 by the
        clip), ``psf_shape``, ``raw_shape`` (outputs).

    Raises
    ------
    ReconInputError
        From :func:`validate_psf` / :func:`validate_measurement`; if a 3D PSF
        comes with a 2D measurement or the channel counts differ; if the
        spatial shapes differ (message names both shapes); for an invalid
        `dark`, `dark_region`, `bayer` or `bin_factor`; and if the PSF has no
        signal above the dark level after preprocessing.

    Warns
    -----
    SaturationWarning
        When a saturated fraction exceeds `warn_saturation`.

    Notes
    -----
    Sources: DiffuserCam tutorial preprocessing (dark level from
    ``psf[5:15, 5:15]`` subtracted from both images, 2x2 box averaging applied
    twice, i.e. ``bin_factor=4``), and the measurement model of Sec. 3.3 of
    Kuo 2020 (non-negative PSF intensity, linear sensor without saturation).
    """
    psf = _as_array(psf, "PSF")
    raw = _as_array(raw, "measurement")
    validate_psf(psf)
    validate_measurement(raw)
    if warn_saturation is not None and (
        isinstance(warn_saturation, bool)
        or not isinstance(warn_saturation, numbers.Real)
        or not 0 <= warn_saturation <= 1
    ):
        raise ReconInputError(
            f"warn_saturation must be a fraction in [0, 1] or None, got {warn_saturation!r}; "
            "e.g. 0.001"
        )

    bin_factor = _check_bin_factor(bin_factor)

    info: dict[str, Any] = {
        "psf_shape_in": tuple(psf.shape),
        "raw_shape_in": tuple(raw.shape),
        "psf_dtype_in": str(psf.dtype),
        "raw_dtype_in": str(raw.dtype),
        "bayer": bayer,
    }
    info["saturated_fraction_psf"] = _check_saturation(psf, "PSF", warn_saturation, full_scale)
    info["saturated_fraction_raw"] = _check_saturation(
        raw, "measurement", warn_saturation, full_scale
    )

    if psf.shape[:2] != raw.shape[:2]:
        raise ReconInputError(
            f"PSF shape {psf.shape} and measurement shape {raw.shape} differ in height/width; "
            "capture both with the same sensor size and binning, or crop them to the same "
            "region"
        )

    if bayer is not None:
        if psf.ndim == 2:
            psf = demosaic_bayer(psf, bayer)
        if raw.ndim == 2:
            raw = demosaic_bayer(raw, bayer)

    if psf.ndim == 3 and raw.ndim == 2:
        raise ReconInputError(
            f"PSF has {psf.shape[2]} channels (shape {psf.shape}) but the measurement is 2D "
            f"(shape {raw.shape}); pass a 2D PSF, or a colour measurement with the same channels"
        )
    if psf.ndim == 3 and psf.shape[2] != raw.shape[2]:
        raise ReconInputError(
            f"PSF has {psf.shape[2]} channels and the measurement {raw.shape[2]} "
            f"(shapes {psf.shape} and {raw.shape}); pass matching channels or a 2D PSF "
            "to share across channels"
        )

    mode, level = _resolve_dark(dark, psf, dark_region, bayer)
    info["dark_mode"] = mode
    info["dark_region"] = (
        tuple((s.start, s.stop) for s in dark_region) if mode == "psf_region" else None
    )
    if mode == "none":
        psf_d = psf.astype(np.float32)
        raw_d = raw.astype(np.float32)
        info["dark_level"] = None
    else:
        psf_d = subtract_dark(psf, level)
        raw_d = subtract_dark(raw, level)
        if mode == "frame":
            info["dark_level"] = float(np.mean(level, dtype=np.float64))
        else:
            info["dark_level"] = _level_for_info(level)
    logger.info("dark subtraction: mode %s, level %s", mode, info["dark_level"])

    psf_b = box_bin(psf_d, bin_factor)
    raw_b = box_bin(raw_d, bin_factor)
    del psf_d, raw_d

    negative = psf_b < 0
    info["psf_clipped_fraction"] = float(np.count_nonzero(negative)) / psf_b.size
    psf_b[negative] = 0.0

    energies = psf_b.reshape(-1, _channels(psf_b)).sum(axis=0, dtype=np.float64)
    empty = [i for i, e in enumerate(energies) if not e > 0]
    if empty:
        where = "" if psf_b.ndim == 2 else f" in channel(s) {empty}"
        raise ReconInputError(
            f"PSF has no signal above the dark level{where} after dark subtraction "
            f"(dark mode {mode}, level {info['dark_level']}); check the dark setting "
            "(try dark='none' or a smaller value) or recapture a brighter PSF"
        )

    info["bin_factor"] = int(bin_factor)
    info["channels"] = _channels(raw_b)
    info["psf_shared_across_channels"] = psf_b.ndim == 2 and raw_b.ndim == 3
    info["psf_shape"] = tuple(psf_b.shape)
    info["raw_shape"] = tuple(raw_b.shape)
    logger.debug("prepare_pair: %s", info)
    return Prepared(psf=psf_b, raw=raw_b, info=info)


def normalize(image: np.ndarray, mode: str = "l2") -> tuple[np.ndarray, float]:
    """Scale an image by its L2 norm, maximum or sum.

    Parameters
    ----------
    image : numpy.ndarray
        Any shape, real numeric dtype, finite.
    mode : {"l2", "max", "sum"}, optional
        ``"l2"``: divide by the Euclidean norm of all samples (DiffuserCam
        tutorial: ``psf /= np.linalg.norm(psf.ravel())``). ``"max"``: divide by
        the largest absolute value. ``"sum"``: divide by the sum (must be
        positive), e.g. to give a PSF unit energy. Default ``"l2"``.

    Returns
    -------
    scaled : numpy.ndarray
        float32, same shape: ``image / scale``.
    scale : float
        The divisor; multiply `scaled` by it to recover the original values.

    Raises
    ------
    ReconInputError
        If `mode` is unknown, the image is empty, non-numeric, contains
        NaN/inf, is all zero, or (mode ``"sum"``) has a non-positive sum.
    """
    if mode not in _NORMALIZE_MODES:
        raise ReconInputError(
            f"unknown normalization mode {mode!r}; use one of {', '.join(_NORMALIZE_MODES)}"
        )
    image = _as_array(image, "image")
    if image.dtype.kind not in "uif" or image.size == 0:
        raise ReconInputError(
            f"cannot normalize an array of dtype {image.dtype} and shape {image.shape}; "
            "pass a non-empty numeric image"
        )
    data = image.astype(np.float64)
    n_bad = int(np.count_nonzero(~np.isfinite(data)))
    if n_bad:
        raise ReconInputError(
            f"cannot normalize: image contains {n_bad} NaN/inf value(s); validate the input first"
        )
    if not np.any(data):
        raise ReconInputError(
            "cannot normalize an all-zero image (scale would be 0); check the input data"
        )
    if mode == "l2":
        scale = float(np.linalg.norm(data.ravel()))
    elif mode == "max":
        scale = float(np.max(np.abs(data)))
    else:
        scale = float(data.sum())
        if not scale > 0:
            raise ReconInputError(
                f"cannot normalize by sum: the image sums to {scale:g} (<= 0); "
                "use mode 'l2' or 'max' for signed data"
            )
    return (data / scale).astype(np.float32), scale

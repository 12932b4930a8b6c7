"""Input checks shared by the preprocessing steps: array conversion, image shape and
dtype, NaN/inf, saturation at the sensor's full scale.

Every refusal raises :class:`recon.errors.ReconInputError` whose message says what is
wrong and how to fix it.
"""

from __future__ import annotations

import logging
import numbers
import warnings
from typing import Any

import numpy as np

from recon.errors import ReconInputError
from recon.validate import as_array

logger = logging.getLogger(__name__)

__all__ = [
    "SaturationWarning",
    "as_array",
    "channel_count",
    "check_bin_factor",
    "check_saturation",
    "full_scale_of",
    "require_image",
    "saturation_fraction",
    "validate_common",
    "validate_measurement",
    "validate_psf",
]


class SaturationWarning(UserWarning):
    """More pixels than allowed sit at the sensor's full scale (clipped highlights).

    Saturated pixels break the linear convolution model, so a reconstruction
    from them shows artefacts; lower the exposure or the source power.
    """


def require_image(image: np.ndarray, name: str) -> None:
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


def channel_count(image: np.ndarray) -> int:
    """Number of channels of an (H, W) or (H, W, C) image."""
    return 1 if image.ndim == 2 else image.shape[2]


def full_scale_of(dtype: np.dtype) -> float | None:
    """Full-scale value of an integer dtype (its maximum); None for floats."""
    if dtype.kind in "ui":
        return float(np.iinfo(dtype).max)
    return None


def check_bin_factor(factor: Any) -> int:
    """``factor`` as an int >= 1; ReconInputError otherwise (bools refused)."""
    if isinstance(factor, bool) or not isinstance(factor, numbers.Integral) or factor < 1:
        raise ReconInputError(
            f"bin factor must be an integer >= 1, got {factor!r}; e.g. 1 (no binning), 2 or 4"
        )
    return int(factor)


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
        is not a positive finite number.
    """
    image = as_array(image, "image")
    require_image(image, "image")
    if full_scale is None:
        full_scale = full_scale_of(image.dtype)
        if full_scale is None:
            logger.debug("saturation_fraction: float image without full_scale; returning 0.0")
            return 0.0
    elif (
        isinstance(full_scale, bool)
        or not isinstance(full_scale, numbers.Real)
        or not np.isfinite(full_scale)
        or not full_scale > 0
    ):
        raise ReconInputError(
            f"full_scale must be a positive finite number, got {full_scale!r}; e.g. 4095 for "
            "12-bit data"
        )
    return float(np.count_nonzero(image >= full_scale)) / image.size


def validate_common(image: Any, name: str, fix: str) -> np.ndarray:
    """``image`` as an array checked by :func:`require_image`, refusing NaN/inf
    (the message ends with ``fix``)."""
    image = as_array(image, name)
    require_image(image, name)
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

    Raises
    ------
    ReconInputError
        If the PSF is empty, not 2D/3D, of a non-numeric dtype (including bool
        and complex), contains NaN/inf (the message gives the count), is all
        zero, or has no positive value.
    """
    psf = validate_common(psf, "PSF", "recapture the PSF or repair the file")
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

    Raises
    ------
    ReconInputError
        If the measurement is empty, not 2D/3D, of a non-numeric dtype
        (including bool and complex) or contains NaN/inf (the message gives the
        count). An all-zero measurement is only logged as a warning.
    """
    raw = validate_common(raw, "measurement", "recapture the measurement or repair the file")
    if not np.any(raw):
        logger.warning("measurement is all zero; the reconstruction will be zero")


def check_saturation(
    image: np.ndarray, name: str, threshold: float | None, full_scale: float | None = None
) -> float:
    """:func:`saturation_fraction` of ``image``; above ``threshold`` it logs a warning
    and emits :class:`SaturationWarning` at the caller of the caller."""
    fraction = saturation_fraction(image, full_scale)
    if threshold is not None and fraction > threshold:
        full = full_scale if full_scale is not None else full_scale_of(image.dtype)
        message = (
            f"{name}: {fraction:.4%} of samples are at full scale ({full:g}), above the "
            f"{threshold:.4%} limit; saturation breaks the linear model, "
            "lower the exposure or source power and recapture"
        )
        logger.warning(message)
        warnings.warn(message, SaturationWarning, stacklevel=3)
    return fraction

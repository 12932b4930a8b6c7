"""A PSF and a raw measurement prepared together for reconstruction, and the
normalisation left to the solver layer.

:func:`prepare_pair` validates, demosaics, subtracts the dark level (:mod:`.dark`),
bins (:mod:`.binning`) and clips; :func:`check_psf_signal` is its check of the PSF
alone (a PSF with signal above its dark level); :func:`normalize` scales an image by its L2 norm,
maximum or sum.
"""

from __future__ import annotations

import logging
import numbers
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recon.errors import ReconInputError
from recon.io import demosaic_bayer

from .binning import box_bin
from .dark import DEFAULT_DARK_REGION, level_for_info, resolve_dark, subtract_dark
from .signal import check_pair_ranges, check_raw_signal
from .validation import (
    as_array,
    channel_count,
    check_bin_factor,
    check_saturation,
    validate_measurement,
    validate_psf,
)

logger = logging.getLogger(__name__)

__all__ = ["Prepared", "check_psf_signal", "normalize", "prepare_pair"]

_NORMALIZE_MODES = ("l2", "max", "sum")


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
    allow_mixed_ranges: bool = False,
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
        PSF (:func:`~recon.preprocess.dark_level`; per channel for colour) and subtract it from
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
        Warn (``logging.warning`` and :class:`~recon.preprocess.SaturationWarning`) when the
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
        clip), ``psf_shape``, ``raw_shape`` (outputs), ``raw_levels`` (the raw's
        floor, median, top and noise sigma, input units).

    Raises
    ------
    ReconInputError
        From :func:`validate_psf` / :func:`validate_measurement`; if a 3D PSF
        comes with a 2D measurement or the channel counts differ; if the
        spatial shapes differ (message names both shapes); for an invalid
        `dark`, `dark_region`, `bayer` or `bin_factor`; and if the PSF has no
        signal above the dark level after preprocessing.
    RawSignalError
        The raw holds nothing to reconstruct after its dark level, or cannot belong
        with the PSF (:mod:`recon.preprocess.signal`: constant, mostly saturated, a
        lone extreme value, below its dark level, no light left, mixed bit depths).

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
    psf = as_array(psf, "PSF")
    raw = as_array(raw, "measurement")
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

    bin_factor = check_bin_factor(bin_factor)

    info: dict[str, Any] = {
        "psf_shape_in": tuple(psf.shape),
        "raw_shape_in": tuple(raw.shape),
        "psf_dtype_in": str(psf.dtype),
        "raw_dtype_in": str(raw.dtype),
        "bayer": bayer,
    }
    info["saturated_fraction_psf"] = check_saturation(psf, "PSF", warn_saturation, full_scale)
    info["saturated_fraction_raw"] = check_saturation(
        raw, "measurement", warn_saturation, full_scale
    )

    check_pair_ranges(psf, raw, allow_mixed_ranges=allow_mixed_ranges)
    raw_in = raw
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

    mode, level = resolve_dark(dark, psf, dark_region, bayer)
    info["dark_mode"] = mode
    info["dark_region"] = (
        tuple((s.start, s.stop) for s in dark_region) if mode == "psf_region" else None
    )
    info["dark_level"] = _level_info(mode, level)
    logger.debug("dark subtraction: mode %s, level %s", mode, info["dark_level"])
    psf_b, info["psf_clipped_fraction"] = _psf_above_dark(psf, mode, level, bin_factor)
    raw_d = raw.astype(np.float32) if mode == "none" else subtract_dark(raw, level)
    raw_b = box_bin(raw_d, bin_factor)

    info["raw_levels"] = check_raw_signal(
        raw_in, raw_d, dark_level=level, dark_source=_dark_source(mode, dark_region),
        full_scale=full_scale)
    del raw_d
    info["bin_factor"] = int(bin_factor)
    info["channels"] = channel_count(raw_b)
    info["psf_shared_across_channels"] = psf_b.ndim == 2 and raw_b.ndim == 3
    info["psf_shape"] = tuple(psf_b.shape)
    info["raw_shape"] = tuple(raw_b.shape)
    logger.debug("prepare_pair: %s", info)
    return Prepared(psf=psf_b, raw=raw_b, info=info)


def check_psf_signal(
    psf: np.ndarray,
    *,
    bin_factor: int,
    dark: None | str | float | np.ndarray = None,
    dark_region: tuple[slice, slice] = DEFAULT_DARK_REGION,
    bayer: str | None = None,
) -> None:
    """Refuse a dark level that leaves the PSF without signal: :func:`prepare_pair`'s
    check of the PSF alone, for a caller that pairs one PSF with many frames (a batch
    checks it once, before any frame is reconstructed).

    Parameters
    ----------
    psf : numpy.ndarray
        (H, W) or (H, W, C), any real dtype.
    bin_factor, dark, dark_region, bayer
        As :func:`prepare_pair`.

    Raises
    ------
    ReconInputError
        As :func:`prepare_pair` for the PSF: an invalid PSF, `dark`, `dark_region`,
        `bayer` or `bin_factor`, or no signal above the dark level (the message names
        the dark mode and level and the fix).
    """
    psf = as_array(psf, "PSF")
    validate_psf(psf)
    bin_factor = check_bin_factor(bin_factor)
    if bayer is not None and psf.ndim == 2:
        psf = demosaic_bayer(psf, bayer)
    mode, level = resolve_dark(dark, psf, dark_region, bayer)
    _psf_above_dark(psf, mode, level, bin_factor)


def _level_info(mode: str, level) -> float | list[float] | None:
    """The dark level of :func:`prepare_pair`'s ``info`` (a frame: its mean)."""
    if mode == "none":
        return None
    if mode == "frame":
        return float(np.mean(level, dtype=np.float64))
    return level_for_info(level)


def _psf_above_dark(psf: np.ndarray, mode: str, level, bin_factor: int
                    ) -> tuple[np.ndarray, float]:
    """The PSF after its dark level, binned and clipped at 0, and the fraction clipped.

    Raises
    ------
    ReconInputError
        No signal left (in some channel).
    """
    psf_d = psf.astype(np.float32) if mode == "none" else subtract_dark(psf, level)
    psf_b = box_bin(psf_d, bin_factor)
    del psf_d
    negative = psf_b < 0
    clipped = float(np.count_nonzero(negative)) / psf_b.size
    psf_b[negative] = 0.0
    energies = psf_b.reshape(-1, channel_count(psf_b)).sum(axis=0, dtype=np.float64)
    empty = [i for i, e in enumerate(energies) if not e > 0]
    if empty:
        where = "" if psf_b.ndim == 2 else f" in channel(s) {empty}"
        raise ReconInputError(
            f"PSF has no signal above the dark level{where} after dark subtraction "
            f"(dark mode {mode}, level {_level_info(mode, level)}); check the dark setting "
            "(try dark='none' or a smaller value) or recapture a brighter PSF"
        )
    return psf_b, clipped


def _dark_source(mode: str, region: tuple[slice, slice]) -> str:
    """Where a dark level of :func:`resolve_dark`'s ``mode`` came from, for messages."""
    if mode == "psf_region":
        (r0, r1), (c0, c1) = ((s.start, s.stop) for s in region)
        return f"the PSF's dark corner, rows {r0}:{r1}, cols {c0}:{c1}"
    return {"none": "dark='none': nothing subtracted", "scalar": "the dark value given",
            "vector": "the per-channel dark values given",
            "frame": "the dark frame given"}[mode]


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
    image = as_array(image, "image")
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

"""The raw measurement checked after its dark level: is anything left to reconstruct?

A reconstruction solves for a non-negative scene whose light, through the PSF, gives
the dark-subtracted raw image (Kuo 2020, Eq. 3.4, non-negativity of Sec. 2.3). A raw
image that sits below the dark level it is given cannot be such light, and the
non-negative solvers answer it with an all-zero image, silently. So every method, in
2D and in 3D, checks the raw after its dark level (:func:`check_raw_signal`) and the
PSF/raw pair before it (:func:`check_pair_ranges`), and refuses:

* a **constant** raw (every pixel equal): no structure, no image;
* a raw **saturated** over at least :data:`MAX_SATURATED` of its samples: the
  linear model of Eq. 3.4 fails on most of the frame;
* a **lone extreme value**: a pixel more than :data:`OUTLIER_RATIO` times the 99.9th
  percentile of the dark-subtracted magnitudes (a corrupt value such as 1e38 or a
  hot pixel in a dark frame) would set the solver's scale on its own;
* a raw **below its dark level**: at least :data:`BELOW_DARK_FRACTION` of the pixels
  lie below the dark level by more than :data:`NOISE_MARGIN` noise standard deviations
  (at least :data:`RANGE_TOLERANCE` of the raw's range); more than
  :data:`WARN_BELOW_FRACTION` is logged as a warning (a PSF "dark" corner that catches
  light gives a level somewhat too high).
  A pixel cannot read below its dark level by more than its noise, so that dark
  level does not belong to this raw (an 8-bit export beside a 16-bit PSF, a
  background-subtracted frame, another camera);
* a raw with **no light left**: the mean of the dark-subtracted raw (its total light)
  is not above :data:`NOISE_MARGIN` standard errors of that mean, in every channel
  (one dark channel is a colour);
* a PSF and a raw whose **bit depths or value ranges cannot belong to one camera**
  (two integer dtypes of different widths; a raw above the full scale of an integer
  PSF's dtype) unless the caller says they do (``allow_mixed_ranges``, the command
  line's ``--allow-mixed-ranges``).

Where the dark level comes from. The raw of a lensless camera has no dark region:
the diffuser spreads every scene point over the whole sensor (Sec. 3.1), so the
raw's darkest pixels only bound its dark level from above. The level therefore comes
from the PSF's dark corner (the DiffuserCam tutorial's ``psf[5:15, 5:15]``), a dark
frame or a number, and the raw's own floor (its 0.1th percentile,
:func:`raw_levels`) is what it is checked against. Every refusal names both levels
and where each came from.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from recon.errors import ReconInputError

log = logging.getLogger(__name__)

__all__ = ["BELOW_DARK_FRACTION", "MAX_SATURATED", "MIN_MEASURED_FRACTION", "NOISE_MARGIN",
           "OUTLIER_RATIO", "RANGE_TOLERANCE", "RawBelowDarkError", "RawSignalError",
           "WARN_BELOW_FRACTION", "check_measured_fraction", "check_pair_ranges",
           "check_raw_signal", "noise_sigma", "raw_levels"]

#: A raw saturated over this fraction of its samples (or more) is refused.
MAX_SATURATED = 0.5
#: A pixel above this multiple of the 99.9th percentile of |raw - dark| is refused.
OUTLIER_RATIO = 1e4
#: Noise standard deviations that count as "beyond the noise".
NOISE_MARGIN = 5.0
#: Below the dark level, a tolerance of this fraction of the raw's range (0.1th to
#: 99.9th percentile) is added to the noise margin (a dark level drifting by a few DN
#: between the PSF's capture and the raw's is not refused).
RANGE_TOLERANCE = 0.02
#: Fraction of pixels beyond the noise below the dark level that refuses the pair (the
#: dark level then sits above the raw's median: most of the frame would be lost).
BELOW_DARK_FRACTION = 0.5
#: Fraction of pixels beyond the noise below the dark level that is logged as a warning
#: (a PSF whose "dark" corner catches light: its level is too high for the raw).
WARN_BELOW_FRACTION = 0.01
#: Fewest measured pixels an erasure mask may keep (Kuo 2020, Fig. 3.7 keeps 20 %;
#: the failure maps of ``benchmark recon`` go to 5 %).
MIN_MEASURED_FRACTION = 0.01


class RawSignalError(ReconInputError):
    """The raw measurement holds nothing to reconstruct after its dark level, or does not
    belong with its PSF; the message names both levels and their sources."""


class RawBelowDarkError(RawSignalError):
    """The raw lies below the dark level it is given by more than its noise: that level
    does not belong to the raw's camera (a pixel cannot read below its dark level),
    whatever the scene, so no frame of that camera can be reconstructed with it."""


def noise_sigma(image: np.ndarray) -> float:
    """Noise standard deviation of a frame from its finest diagonal Haar detail.

    ``d = (a - b - c + e) / 2`` over each 2 x 2 block cancels a constant and a linear
    ramp (the image's own structure, to first order) and keeps the variance of the
    noise; ``sigma = 1.4826 median |d|`` (the normal-consistent median absolute
    deviation) ignores the few blocks on edges.

    Parameters
    ----------
    image : ndarray, (H, W), real
        One channel, H, W >= 2.

    Returns
    -------
    float
        Standard deviation, in the image's units (0 for a noiseless frame).
    """
    x = np.asarray(image, np.float64)
    h, w = (x.shape[0] // 2) * 2, (x.shape[1] // 2) * 2
    if h == 0 or w == 0:
        return 0.0
    x = x[:h, :w]
    d = (x[0::2, 0::2] - x[0::2, 1::2] - x[1::2, 0::2] + x[1::2, 1::2]) / 2.0
    return float(1.4826 * np.median(np.abs(d)))


def raw_levels(raw: np.ndarray) -> dict[str, float]:
    """The raw's own levels: floor (0.1th percentile), median and top (99.9th), input units.

    The floor bounds the raw's dark level from above (see the module notes).
    """
    lo, mid, hi = np.percentile(np.asarray(raw, np.float64), [0.1, 50.0, 99.9])
    return {"floor": float(lo), "median": float(mid), "top": float(hi)}


def _fmt(value: float) -> str:
    return f"{value:.6g}"


def _dark_text(level, source: str) -> str:
    arr = np.atleast_1d(np.asarray(level, np.float64)) if level is not None else None
    if arr is None:
        what = "dark level 0"
    elif arr.size == 1:
        what = f"dark level {_fmt(float(arr[0]))}"
    elif arr.ndim == 1 and arr.size <= 4:
        what = f"dark levels {', '.join(_fmt(v) for v in arr)}"
    else:
        what = f"dark frame (mean {_fmt(float(arr.mean()))})"
    return f"{what} (from {source})"


def check_pair_ranges(psf: np.ndarray, raw: np.ndarray, *, allow_mixed_ranges: bool = False
                      ) -> None:
    """Refuse a PSF and a raw image whose bit depths or ranges cannot be one camera's.

    Parameters
    ----------
    psf, raw : ndarray
        As loaded (input dtype), any shape.
    allow_mixed_ranges : bool
        The caller knows they belong together (e.g. a raw summed from several frames,
        a PSF exported at another bit depth); nothing is checked.

    Raises
    ------
    RawSignalError
        Both integer and of different widths (uint8 beside uint16), or a raw whose
        maximum exceeds the full scale of an integer PSF's dtype.
    """
    if allow_mixed_ranges:
        return
    fix = ("use a PSF and a raw image from one camera at one bit depth, or pass "
           "--allow-mixed-ranges (allow_mixed_ranges=True) if they do belong together")
    pk, rk = psf.dtype.kind, raw.dtype.kind
    if pk in "ui" and rk in "ui" and psf.dtype.itemsize != raw.dtype.itemsize:
        raise RawSignalError(
            f"the PSF is {psf.dtype} ({8 * psf.dtype.itemsize}-bit, values "
            f"{_fmt(psf.min())}..{_fmt(psf.max())}) but the raw is {raw.dtype} "
            f"({8 * raw.dtype.itemsize}-bit, values {_fmt(raw.min())}..{_fmt(raw.max())}): "
            f"one camera gives one bit depth, and the PSF's dark level would not fit the "
            f"raw; {fix}")
    if pk in "ui" and raw.size:
        full = float(np.iinfo(psf.dtype).max)
        top = float(np.max(raw))
        if top > full:
            raise RawSignalError(
                f"the raw reaches {_fmt(top)}, above the full scale {_fmt(full)} of the "
                f"PSF's {psf.dtype} camera: they cannot come from one camera; {fix}")


def check_raw_signal(raw_in: np.ndarray, raw_dark: np.ndarray, *, dark_level,
                     dark_source: str, full_scale: float | None = None) -> dict:
    """Refuse a raw image with nothing left to reconstruct after its dark level.

    Parameters
    ----------
    raw_in : ndarray, (H, W) or (H, W, C), real
        The raw image as loaded (input units and dtype): constancy and saturation.
    raw_dark : ndarray, same spatial shape, float
        The raw image after its dark level (not binned).
    dark_level : float, ndarray or None
        The level subtracted (a number, one per channel, a frame; None for none).
    dark_source : str
        Where it came from, for the messages (e.g. ``"the PSF's dark corner rows
        5-15, cols 5-15"``).
    full_scale : float, optional
        Saturation level of ``raw_in`` (default: its integer dtype's maximum; a float
        raw without it has no known saturation).

    Returns
    -------
    dict
        The raw's levels (:func:`raw_levels` of ``raw_in``), its noise ``sigma``
        (first channel) and ``below_dark_fraction`` (the largest over the channels),
        for the preprocessing record.

    Raises
    ------
    RawSignalError
        One of the refusals of the module notes; the message names the raw's levels,
        the dark level and their sources, and the fix; :class:`RawBelowDarkError` for
        a raw below its dark level.
    """
    raw_in = np.asarray(raw_in)
    levels = raw_levels(raw_in)
    dark = _dark_text(dark_level, dark_source)
    raw_text = (f"the raw's levels: floor {_fmt(levels['floor'])} (0.1th percentile), "
                f"median {_fmt(levels['median'])}, top {_fmt(levels['top'])} (99.9th), "
                "from the raw itself")
    lo, hi = float(np.min(raw_in)), float(np.max(raw_in))
    if lo == hi:
        raise RawSignalError(
            f"the raw is constant (every sample {_fmt(lo)}): a frame without structure "
            "carries no image; check the exposure, the light source, the lens cap and "
            "that the file holds the camera's frame")
    if full_scale is None and raw_in.dtype.kind in "ui":
        full_scale = float(np.iinfo(raw_in.dtype).max)
    if full_scale is not None:
        saturated = float(np.count_nonzero(raw_in >= full_scale)) / raw_in.size
        if saturated >= MAX_SATURATED:
            raise RawSignalError(
                f"{saturated:.1%} of the raw is at full scale ({_fmt(full_scale)}): the "
                "linear model fails on most of the frame; lower the exposure or the "
                "source power and recapture (or give the sensor's --full-scale)")
    mag = np.abs(np.asarray(raw_dark, np.float64))
    p999 = float(np.percentile(mag, 99.9))
    peak = float(mag.max())
    if peak > OUTLIER_RATIO * p999:
        where = np.unravel_index(int(np.argmax(mag)), mag.shape)
        ratio = "infinitely many" if p999 == 0 else f"{peak / p999:.3g}"
        value = float(np.asarray(raw_dark)[where])
        raise RawSignalError(
            f"raw sample {tuple(int(i) for i in where)} is {_fmt(value)} after the {dark}, "
            f"{ratio} times the 99.9th percentile of the frame's magnitudes "
            f"({_fmt(p999)}): one corrupt value or hot pixel would set the solver's scale "
            "and leave the rest of the frame at zero; repair or replace that pixel")
    chans = raw_dark[..., None] if raw_dark.ndim == 2 else raw_dark
    sigma0, dark_channels, warned, worst = None, [], [], 0.0
    for c in range(chans.shape[-1]):
        r = np.asarray(chans[..., c], np.float64)
        sigma = noise_sigma(r)
        if raw_in.dtype.kind in "ui":
            sigma = max(sigma, 1.0 / math.sqrt(12.0))  # one quantisation step
        else:
            sigma = max(sigma, 1e-6 * float(np.max(np.abs(r))))
        sigma0 = sigma if sigma0 is None else sigma0
        lo_r, hi_r = np.percentile(r, [0.1, 99.9])
        margin = max(NOISE_MARGIN * sigma, RANGE_TOLERANCE * float(hi_r - lo_r))
        label = "the raw" if chans.shape[-1] == 1 else f"channel {c} of the raw"
        below = float(np.count_nonzero(r < -margin)) / r.size
        worst = max(worst, below)
        fact = (f"{below:.1%} of {label} lies more than its noise ({_fmt(margin)}) below "
                f"the {dark}; {raw_text}: a pixel cannot read below its dark level by more "
                "than its noise, so this dark level does not belong to this raw")
        if below >= BELOW_DARK_FRACTION:
            raise RawBelowDarkError(
                f"{fact} (an 8-bit export beside a 16-bit PSF, a background-subtracted "
                "frame, another camera); give the raw's own dark level with --dark LEVEL "
                "(--dark none for a raw already dark-subtracted), or use a PSF and raw of "
                "one camera")
        if below > WARN_BELOW_FRACTION:
            warned.append(f"{fact} (a PSF corner that catches light?); those pixels count "
                          "as negative light: give the dark level with --dark LEVEL")
        mean = float(r.mean())
        if not mean > NOISE_MARGIN * sigma / math.sqrt(r.size):
            dark_channels.append((mean, sigma))
    if len(dark_channels) == chans.shape[-1]:  # one dark channel is a colour, not a fault
        mean, sigma = dark_channels[0]
        raise RawSignalError(
            f"the raw carries no signal above the {dark}: its mean after the dark level is "
            f"{_fmt(mean)}, within the noise ({_fmt(sigma)} per pixel); {raw_text}; check "
            "the exposure, the light source and the lens cap, or the dark level (--dark)")
    if warned:
        log.warning("%s", warned[0])
    return {**levels, "sigma": sigma0, "below_dark_fraction": worst}


def check_measured_fraction(mask_or_erased) -> None:
    """Refuse an erasure that keeps fewer than :data:`MIN_MEASURED_FRACTION` of the
    sensor's pixels (Eq. 3.10: the data would be the prior alone).

    Parameters
    ----------
    mask_or_erased : ndarray (rows, cols) or float
        An erasure mask (1 measured, 0 erased), or the fraction to erase at random.

    Raises
    ------
    RawSignalError
        Too few measured pixels (the fraction and the limit named).
    """
    if np.ndim(mask_or_erased) == 0:
        kept_fraction = 1.0 - float(mask_or_erased)
        what = f"an erased fraction of {mask_or_erased:g}"
    else:
        mask = np.asarray(mask_or_erased)
        kept_fraction = np.count_nonzero(mask) / max(mask.size, 1)
        what = f"the erasure mask ({np.count_nonzero(mask)} of {mask.size} pixels)"
    if kept_fraction < MIN_MEASURED_FRACTION:
        raise RawSignalError(
            f"{what} keeps {kept_fraction:.2%} of the sensor's pixels: fewer than "
            f"{MIN_MEASURED_FRACTION:.0%} measured leaves the reconstruction to the prior "
            "alone; erase at most 99 % of the pixels (0.99)")

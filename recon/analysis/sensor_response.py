"""A scene calibration's sensor response: the sensor's shading, fitted with the PSF.

The convolution model (Kuo 2020, Eq. 3.4) gives every sensor pixel the same
response. A real sensor's does not: its pixels' angular acceptance (their microlenses
are aimed for a lens, not a diffuser), the cover glass and the housing's vignetting
shade it smoothly, and that shading moves with the pixel, not with the object point,
so no PSF can hold it (the PSF of every object point is shaded alike). The model with
it is

    b_i = V (C (h * P x_i)),

``V`` a smooth gain over the sensor. It is fitted on the calibration pairs by
alternating least squares (:func:`fit_sensor_response`): the PSF from the
measurements divided by ``V`` (:func:`recon.analysis.psf_from_scenes.estimate_psf_from_scenes`,
``V = 1`` at first), then ``V`` as each point's least-squares gain between the
predicted and the measured light of every pair and channel, smoothed by a Gaussian of
:data:`SIGMA_PX` pixels: ``V = G*(sum p b) / G*(sum p^2)``, normalised to a median of
1 (the PSF keeps the scale). :data:`ROUNDS` rounds, on the pairs binned to
:data:`SENSOR_BIN` pixels a sample (the response is smooth; its PSF estimates cost a
sixteenth of full size's).

It is a nuisance of the PSF's estimate, not part of the reconstruction: a
calibration's PSFs (the one it ships and each held-out one its recipe is fitted with,
:func:`recon.analysis.early_stop.fit_recipe`) are estimated from the measurements
divided by the response of their own pairs (:func:`estimate_with_sensor_response`),
and every reconstruction takes the measurement as captured (dividing it there too did
not pay once the recipe's field response, :mod:`recon.field_response`, was fitted). On
the five shared real pairs (docs/real-data.md) the fit residual fell from 0.069 to
0.055 with two rounds; the response is brighter at the bottom centre of the sensor and
darker at its top right (0.87 to 1.17; the same pattern, correlation 0.89 to 0.99, from
any four of the pairs); and in the strictly nested leave-one-out the PSFs estimated
with it bought LenslessPiCam and the point-source default +0.35 dB each and the
scene-calibrated default more (docs/real-data.md).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from ..errors import ReconInputError
from ..field_response import STEP_PX, apply_field_response, resample_evenly
from ..validate import as_int
from .psf_from_scenes import (
    binned_psf_options,
    check_pairs,
    estimate_psf_from_scenes,
    predict_measurements,
)

__all__ = ["MIN_GAIN", "MIN_SIDE_PX", "ROUNDS", "SENSOR_BIN", "SIGMA_PX",
           "estimate_with_sensor_response", "fit_sensor_response", "grid_shape",
           "remove_sensor_response"]

#: Smoothing of the response, a Gaussian's standard deviation in full-size pixels.
SIGMA_PX = 15.0
#: Rounds of the alternation (PSF, then response); the PSF estimated after the last
#: round is the caller's.
ROUNDS = 2
#: Full-size pixels per sample of the pairs the response is fitted on.
SENSOR_BIN = 4
#: The fewest pixels a binned side keeps (less binning otherwise).
MIN_SIDE_PX = 48
#: The least gain of a response (of its median): a measurement is divided by it.
MIN_GAIN = 0.05
#: Where the predicted light is this small a fraction of its maximum the response is
#: 1 (nothing to fit it on).
_FLOOR = 1e-6


def grid_shape(shape) -> tuple[int, int]:
    """The grid of nodes a response of a ``shape`` (rows, cols[, ...]) sensor is
    stored on: one node per :data:`recon.field_response.STEP_PX` pixels, at least 2."""
    return tuple(max(2, int(n) // STEP_PX) for n in shape[:2])


def remove_sensor_response(measurement, grid) -> np.ndarray:
    """``measurement`` divided by the sensor response ``grid`` (every channel alike).

    Parameters
    ----------
    measurement : array_like, (rows, cols) or (rows, cols, channels), real
        Dark-subtracted (the response multiplies light, not the dark level), at any
        binning: the grid covers the sensor evenly
        (:func:`recon.field_response.field_gain_like`).
    grid : array_like, (n_rows, n_cols), > 0, or None
        None: the measurement unchanged (as float32).

    Returns
    -------
    ndarray, float32, the measurement's shape
    """
    return apply_field_response(measurement, grid, divide=True)


def estimate_with_sensor_response(scenes, measurements, *, binned_by: int = 1,
                                  on_round=None, **psf_options):
    """The PSF of a calibration estimated with the sensor's shading as a nuisance: the
    response (:func:`fit_sensor_response`), then the PSF from the measurements
    divided by it (module docstring).

    Parameters
    ----------
    scenes, measurements, binned_by, on_round, **psf_options
        As for :func:`fit_sensor_response`.

    Returns
    -------
    estimate : recon.analysis.psf_from_scenes.PsfEstimate
        The PSF, at the pairs' size.
    grid : ndarray, float64, (n_rows, n_cols)
        The response it was estimated with.

    Raises
    ------
    ReconInputError
        What :func:`fit_sensor_response` or the estimate refuses.
    """
    grid = fit_sensor_response(scenes, measurements, binned_by=binned_by, on_round=on_round,
                               **psf_options)
    estimate = estimate_psf_from_scenes(
        scenes, [remove_sensor_response(m, grid) for m in measurements], **psf_options)
    return estimate, grid


def _binning(shape, binned_by: int) -> int:
    """The further binning of pairs of ``shape`` already binned by ``binned_by``."""
    factor = max(1, SENSOR_BIN // binned_by)
    while factor > 1 and min(shape[:2]) // factor < MIN_SIDE_PX:
        factor //= 2
    return factor


def fit_sensor_response(scenes, measurements, *, binned_by: int = 1, rounds: int = ROUNDS,
                        on_round=None, **psf_options) -> np.ndarray:
    """The sensor response of a calibration (module docstring), as a grid.

    Parameters
    ----------
    scenes, measurements
        The calibration pairs, as for
        :func:`recon.analysis.psf_from_scenes.estimate_psf_from_scenes` (measurements
        dark-subtracted), at the binning ``binned_by``.
    binned_by : int
        The pairs' binning against the full-size sensor (>= 1): they are binned further
        to :data:`SENSOR_BIN` (while each side keeps :data:`MIN_SIDE_PX`), and the grid
        is the full-size sensor's.
    rounds : int
        Rounds of the alternation (>= 1).
    on_round : callable, optional
        ``on_round(round, estimate)`` after each round's PSF (progress), ``round`` from 1.
    **psf_options
        Of :func:`recon.analysis.psf_from_scenes.estimate_psf_from_scenes`; a
        ``psf_shape`` of the pairs is binned with them.

    Returns
    -------
    ndarray, float64, :func:`grid_shape` of the full-size sensor
        The response, > 0, median about 1; divide it out of a measurement with
        :func:`remove_sensor_response`.

    Raises
    ------
    ReconInputError
        What the PSF estimate refuses, ``binned_by`` or ``rounds`` < 1, or a response
        whose median is not positive (a measurement with negative light).
    """
    from ..preprocess.binning import box_bin

    xs, bs = check_pairs(scenes, measurements)
    binned_by = as_int(binned_by, "binned_by", 1)
    rounds = as_int(rounds, "rounds", 1)
    full = tuple(n * binned_by for n in xs[0].shape[:2])
    factor = _binning(xs[0].shape, binned_by)
    if factor > 1:  # the last rows and columns short of a block left out (it is smooth)
        rows, cols = (n - n % factor for n in xs[0].shape[:2])
        xs, bs = ([box_bin(a[:rows, :cols], factor) for a in group] for group in (xs, bs))
        psf_options = binned_psf_options(psf_options, factor)
    sigma = SIGMA_PX / (binned_by * factor)
    grid = None
    for r in range(1, rounds + 1):
        est = estimate_psf_from_scenes(xs, [remove_sensor_response(b, grid) for b in bs],
                                       **psf_options)
        if on_round is not None:
            on_round(r, est)
        gain = _gain(est.psf, xs, bs, sigma)
        # the grid of the full-size sensor: the binned pairs cover it evenly; each gain
        # >= MIN_GAIN, so the grid too (bilinear)
        grid = resample_evenly(gain, grid_shape(full)).round(4)
    return grid


def _gain(psf, xs, bs, sigma) -> np.ndarray:
    """Each point's least-squares gain between the predicted and the measured light,
    smoothed (module docstring); 1 where nothing was predicted."""
    num = np.zeros(xs[0].shape[:2])
    den = np.zeros(xs[0].shape[:2])
    for p, b in zip(predict_measurements(psf, xs), bs, strict=True):
        p = p.astype(np.float64)
        num += np.einsum("ijc,ijc->ij", p, b)
        den += np.einsum("ijc,ijc->ij", p, p)
    num, den = gaussian_filter(num, sigma), gaussian_filter(den, sigma)
    floor = _FLOOR * max(float(den.max()), 1e-300)
    gain = np.where(den > floor, num / np.maximum(den, floor), 1.0)
    median = float(np.median(gain))
    if not median > 0:
        raise ReconInputError("the sensor response came out non-positive: check the pairs "
                              "(a measurement with negative light?)")
    return np.maximum(gain / median, MIN_GAIN)

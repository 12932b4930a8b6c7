"""The held-out pixels of the automatic weight's cross-validation
(:func:`recon.auto.weight.admm_auto`, whose module docstring gives the criterion):
which sensor pixels the fits keep and which they hold out (random square blocks,
smaller ones on a small sensor), and how well the kept pixels still see every object
pixel (a compact PSF's held-out blocks hide some, and the final solve then runs on
all pixels).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["BLOCK", "HOLDOUT", "MIN_BLOCKS", "SEEN", "SMALLER_BLOCKS", "coverage_ratio",
           "holdout_coverage", "holdout_mask", "holdout_split"]

#: Fraction of the sensor pixels held out for cross-validation.
HOLDOUT = 0.1
#: Side of the square blocks of pixels held out together. Single pixels are
#: predicted from their neighbours even by a fit that follows the model's mismatch
#: (spatially correlated): on the virtual bench's demo scene the pixel-wise held-out
#: error kept falling to the smallest weight (13.7 dB against 18.5 dB at the best
#: fixed weight). So did 8 x 8 blocks once each weight's solve settled: the demo's
#: spatially varying model (PSF grid, predicted model error 0.087) errs alike over
#: more than 8 pixels, the fits that follow it predicted 8 x 8 held-out blocks best
#: at TV 7.2e-5 (19.1 dB; the best fixed weight, 1.9e-4, 21.4 dB at 200 iterations
#: on all pixels), and a block-wise standard error (2.7x the pixel-wise one) with
#: the one-standard-error rule moved the choice up on the scene suite too (camera,
#: astronaut, text 3000 e-: 0.8-1.0 dB below their oracles). With 32 x 32 blocks the
#: demo's held-out minimum is 1.9e-4 (20.7 dB, the result on the fit pixels), and
#: all 15 scenes of the auto benchmark's suite keep their weights, PSNR within 0.11
#: dB of the 8 x 8 blocks' (mean shortfall to the oracle 0.26 dB, worst shapes 0.99).
BLOCK = 32
#: Smaller blocks tried in turn when the sensor is too small for :data:`BLOCK`
#: (fewer than :data:`MIN_BLOCKS` whole blocks of a side above the first of these,
#: fewer than 16 measured pixels held out, or none kept); single pixels last.
SMALLER_BLOCKS = (8, 1)
#: An object pixel counts as seen by the camera where ``A^T w`` is above this fraction
#: of its largest value (:func:`holdout_coverage`).
SEEN = 1e-3
#: Fewest whole blocks a sensor must hold for blocks wider than 8 x 8 (the former
#: side, whose small-sensor cases the tests pin) to be held out: with
#: fewer, a random 10 % of them is a few blocks (a 48 x 48 sensor: one 32 x 32 block
#: of four, 44 % of the pixels), and the held-out fraction and the object pixels the
#: fits still see (:func:`holdout_coverage`) swing with the draw. The demo's 256 x
#: 320 sensor holds 80 blocks of 32 x 32.
MIN_BLOCKS = 64


def holdout_mask(shape, fraction: float, seed: int, block: int = BLOCK) -> np.ndarray:
    """True where a pixel is kept: random ``block`` x ``block`` blocks held out."""
    rng = np.random.default_rng(seed)
    blocks = rng.random((-(-shape[0] // block), -(-shape[1] // block))) >= fraction
    return np.repeat(np.repeat(blocks, block, 0), block, 1)[:shape[0], :shape[1]]


def holdout_coverage(op, keep: np.ndarray) -> float:
    """How well the kept pixels still see every object pixel of the field of view.

    The smallest ratio, over the object pixels in the sensor's field of view that the
    camera sees at all (``A^T w`` above 1e-3 of its peak), of ``A^T (w keep)`` to
    ``A^T w``: about 0.9 for a lensless PSF that spreads every point over many
    pixels, 0 for a compact PSF, whose held-out blocks leave object pixels unseen.
    ``A`` is the cropped convolution model (Eq. 3.4), its adjoint the sensitivity of
    each object pixel to the kept sensor pixels.

    Parameters
    ----------
    op : ConvolutionOperator or VolumeConvolutionOperator
        (a volume: the smallest ratio over every plane's object pixels); or a model
        with its own ``coverage(keep)`` that computes the same where its planes live
        (the streamed volume's slabs, :class:`recon.volume.streamed_auto.SlabModel`).
    keep : ndarray of bool, ``op.shape_out``

    Returns
    -------
    float
    """
    if hasattr(op, "coverage"):
        return float(op.coverage(keep))
    fov = (Ellipsis, *op.crop)  # a volume operator: every plane's field of view
    seen = op.adjoint(np.ones(op.shape_out, np.float32))[fov]
    seen_fit = op.adjoint(np.asarray(keep, np.float32))[fov]
    ratio = coverage_ratio(seen, seen_fit, float(seen.max()))
    return ratio if math.isfinite(ratio) else 0.0


def coverage_ratio(seen: np.ndarray, seen_fit: np.ndarray, peak: float) -> float:
    """The smallest ``seen_fit / seen`` over the object pixels the camera sees: those
    where ``seen`` (``A^T w``) is above :data:`SEEN` times ``peak`` (its largest value).

    Parameters
    ----------
    seen, seen_fit : ndarray, float32, same shape
        ``A^T w`` and ``A^T (w keep)`` over (part of) the field of view.
    peak : float
        Largest ``A^T w`` over the whole field of view.

    Returns
    -------
    float
        ``inf`` when no pixel here is seen.
    """
    lit = seen > SEEN * peak
    return float(np.min(seen_fit[lit] / seen[lit])) if np.any(lit) else math.inf


def holdout_split(op, holdout: float = HOLDOUT, seed: int = 0, block: int = BLOCK
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The pixels the fits keep and the measured pixels they hold out.

    Random ``block`` x ``block`` blocks (:func:`holdout_mask`), smaller ones
    (:data:`SMALLER_BLOCKS`, down to single pixels) when the sensor is too small for
    them (fewer than :data:`MIN_BLOCKS` whole blocks wider than 8 x 8, fewer than 16
    measured pixels held out, or none kept).

    Parameters
    ----------
    op : forward model with ``sensor_shape`` and ``sensor_weights``
    holdout : float
        Fraction held out.
    seed : int
    block : int
        Side of the held-out blocks, pixels (:data:`BLOCK`).

    Returns
    -------
    keep, held : ndarray of bool, ``op.sensor_shape``
    """
    w = op.sensor_weights
    rows, cols = op.sensor_shape[:2]
    for side in (block, *(b for b in SMALLER_BLOCKS if b < block)):
        if side > SMALLER_BLOCKS[0] and (rows // side) * (cols // side) < MIN_BLOCKS:
            continue
        keep = holdout_mask(op.sensor_shape, holdout, seed, side)
        held = (w > 0) & ~keep
        if held.sum() >= 16 and np.any(keep & (w > 0)):  # else too small for blocks
            break
    return keep, held

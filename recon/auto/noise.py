"""Camera noise from one frame: the Poisson-Gaussian model var(b) = a b + c.

A camera pixel holding ``b`` (dark-subtracted, any unit) has shot noise whose
variance grows linearly with ``b`` and read noise of constant variance, so
``var = a b + c`` (Foi et al. 2008, "Practical Poissonian-Gaussian noise modeling
and fitting for single-image raw-data", IEEE TIP 17). Both parameters are fitted
from the frame itself: the finest diagonal Haar detail
``d = (b[i,j] - b[i+1,j] - b[i,j+1] + b[i+1,j+1]) / 2`` has the noise's variance and
almost none of a lensless measurement's signal (the diffuser's caustics are
several pixels wide); its robust variance (1.4826 MAD, squared) within classes of
equal local mean gives points (mean, variance) to which a line is fitted.

The expected noise energy ``E ||n||^2 = sum_i (a b_i + c)`` sets the scale of
automatic stopping (:class:`recon.auto.weight.Stopping`) and the no-signal check
(:func:`recon.auto.choice.check_signal`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ReconInputError

__all__ = ["NoiseModel", "estimate_noise"]

#: MAD to standard deviation for Gaussian data.
MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class NoiseModel:
    """``var(b) = shot * b + read`` in the units of the frame it was fitted to.

    Attributes
    ----------
    shot : float
        Variance per unit signal (>= 0; the inverse gain for electrons-per-unit data).
    read : float
        Signal-independent variance (>= 0; read noise squared plus quantisation).
    points : list of (mean, variance)
        The class estimates the line was fitted to (for the record).
    """

    shot: float
    read: float
    points: list

    def variance(self, b: np.ndarray) -> np.ndarray:
        """Per-pixel variance ``shot * max(b, 0) + read``, float64, shape of ``b``."""
        return self.shot * np.maximum(np.asarray(b, np.float64), 0.0) + self.read

    def energy(self, b: np.ndarray) -> float:
        """Expected ``||n||^2`` over the frame ``b``: ``sum(variance(b))``."""
        return float(self.variance(b).sum())

    def scaled(self, factor: float) -> NoiseModel:
        """The model of ``b / factor`` (shot / factor, read / factor^2)."""
        return NoiseModel(self.shot / factor, self.read / factor**2,
                          [(m / factor, v / factor**2) for m, v in self.points])

    def as_dict(self) -> dict:
        """JSON-ready record."""
        return {"model": "var = shot * b + read (Poisson-Gaussian)", "shot": self.shot,
                "read": self.read, "points": [[float(m), float(v)] for m, v in self.points]}


def estimate_noise(b: np.ndarray, *, classes: int = 12) -> NoiseModel:
    """Fit the Poisson-Gaussian noise model to one dark-subtracted frame.

    Parameters
    ----------
    b : ndarray, (rows, cols), real
        Dark-subtracted frame (at least 8 x 8), any unit.
    classes : int
        Number of local-mean classes (equal pixel counts) for the fit.

    Returns
    -------
    NoiseModel
        ``shot`` and ``read`` fitted by least squares on the classes' (mean, robust
        variance), clipped at 0; a frame with no detail at all gives 0, 0.

    Raises
    ------
    ReconInputError
        Not a 2D frame of at least 8 x 8, or not finite.
    """
    x = np.asarray(b, np.float64)
    if x.ndim != 2 or min(x.shape) < 8:
        raise ReconInputError(f"noise estimate needs a 2D frame of at least 8 x 8, got "
                              f"shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ReconInputError("noise estimate: the frame holds NaN/inf; mask those pixels")
    r, c = (x.shape[0] // 2) * 2, (x.shape[1] // 2) * 2
    q = x[:r, :c]
    a, b2 = q[0::2, 0::2], q[0::2, 1::2]
    c2, d2 = q[1::2, 0::2], q[1::2, 1::2]
    detail = 0.5 * (a - b2 - c2 + d2)  # variance sigma^2 for iid noise
    mean = 0.25 * (a + b2 + c2 + d2)
    order = np.argsort(mean, axis=None)
    groups = np.array_split(order, max(2, int(classes)))
    points = []
    for g in groups:
        if g.size < 16:
            continue
        dd = detail.ravel()[g]
        mad = float(np.median(np.abs(dd - np.median(dd))))
        points.append((float(np.mean(mean.ravel()[g])), (MAD_TO_SIGMA * mad) ** 2))
    if not points:
        return NoiseModel(0.0, 0.0, [])
    m = np.array([p[0] for p in points])
    v = np.array([p[1] for p in points])
    if np.ptp(m) > 0:
        slope, icpt = np.polyfit(m, v, 1)
    else:
        slope, icpt = 0.0, float(np.mean(v))
    if slope < 0:  # no visible shot noise: constant variance
        slope, icpt = 0.0, float(np.mean(v))
    if icpt < 0:  # no visible read noise: a line through the origin
        icpt = 0.0
        slope = float(np.sum(m * v) / np.sum(m * m)) if np.sum(m * m) > 0 else 0.0
    return NoiseModel(max(float(slope), 0.0), max(float(icpt), 0.0), points)


def signal_to_noise_db(b: np.ndarray, model: NoiseModel) -> float:
    """``10 log10((||b||^2 - E||n||^2) / E||n||^2)``: the frame's SNR under ``model``;
    -inf when the noise explains the whole frame."""
    x = np.asarray(b, np.float64)
    noise = model.energy(x)
    signal = float(np.sum(x * x)) - noise
    if noise <= 0:
        return math.inf
    return 10 * math.log10(signal / noise) if signal > 0 else -math.inf

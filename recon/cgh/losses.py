"""Intensity losses of the hologram optimiser (Kuo 2020, Eq. 7.16-7.19, 7.23, A.7).

All losses act on intensities only; the phase at the image plane is free. With
``R = sigma I - T`` the residual of one plane (``sigma`` below):

* plain L2 (Eq. 7.16): ``L = 1/2 sum R^2``;
* frequency constraints (Eq. 7.17-7.18): ``L = 1/2 ||P R||^2``, ``P`` the 5th-order
  Butterworth low-pass whose passband holds as many DFT frequencies as the SLM
  has pixels;
* spatial constraints (Eq. 7.19): ``L = 1/2 ||c_s P R||^2`` with a grey-scale weight
  map ``c_s`` (e.g. :func:`foveation_map`);
* several planes (Eq. 7.23): the sum of the per-plane losses.

``sigma = sum T / sum I`` (``match_mean=True``, the default of the evaluation
protocol) makes the loss blind to the overall brightness, which a phase-only SLM
cannot change; it is differentiated like everything else. With ``match_mean=False``
``sigma = 1`` and the target is scaled to the power of a unit-modulus SLM field.

Filters and maps here are in the *centred* image frame (zero order in the middle)
unless a ``layout`` says otherwise; the Butterworth response depends only on the
frequency, so it applies to centred and uncentred images alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from ..errors import ReconInputError
from ..fft import WORKERS

__all__ = [
    "IntensityLoss",
    "butterworth_lowpass",
    "cutoff_radius",
    "foveation_map",
    "lowpass",
    "passband_count",
]


def _grid(shape) -> tuple[int, int]:
    try:
        gy, gx = (int(v) for v in shape)
    except (TypeError, ValueError):
        raise ReconInputError(f"grid shape must be (rows, cols), got {shape!r}") from None
    if gy < 1 or gx < 1:
        raise ReconInputError(f"grid shape must be positive, got {shape!r}")
    return gy, gx


def cutoff_radius(n_slm: int) -> float:
    """Butterworth cutoff ``r0 = sqrt(N_x N_y / pi)`` in DFT frequency samples (Eq. 7.18).

    On the mask grid one DFT frequency sample is ``Delta_m`` in the SLM plane, so the
    physical cutoff is ``Delta_m r0``, the dissertation's ``r_0``. A disc of this
    radius holds ``pi r0^2 = N_x N_y`` frequencies: as many as the SLM has pixels.

    Parameters
    ----------
    n_slm : int
        SLM pixel count ``N_x N_y`` (> 0).

    Returns
    -------
    float
    """
    if isinstance(n_slm, bool) or not isinstance(n_slm, int | np.integer) or n_slm < 1:
        raise ReconInputError(f"n_slm must be a positive integer pixel count, got {n_slm!r}")
    return math.sqrt(float(n_slm) / math.pi)


def _freq_sq(shape, layout: str) -> np.ndarray:
    gy, gx = _grid(shape)
    fy = sfft.fftfreq(gy) * gy
    if layout == "rfft":
        fx = sfft.rfftfreq(gx) * gx
    elif layout == "full":
        fx = sfft.fftfreq(gx) * gx
    elif layout == "centred":
        fy = sfft.fftshift(fy)
        fx = sfft.fftshift(sfft.fftfreq(gx) * gx)
    else:
        raise ReconInputError(f"layout must be 'rfft', 'full' or 'centred', got {layout!r}")
    return fy[:, None] ** 2 + fx[None, :] ** 2


def butterworth_lowpass(shape, n_slm: int, order: int = 5, layout: str = "rfft") -> np.ndarray:
    """Butterworth low-pass ``c_f(u) = 1 / (1 + (|u|^2 / r0^2)^order)`` (Eq. 7.18).

    Parameters
    ----------
    shape : (int, int)
        Image (mask) grid ``(G_y, G_x)``.
    n_slm : int
        SLM pixel count; sets ``r0`` (:func:`cutoff_radius`).
    order : int
        Filter order (5 in the dissertation).
    layout : {"rfft", "full", "centred"}
        ``"rfft"``: ``(G_y, G_x // 2 + 1)`` for :func:`scipy.fft.rfft2` spectra;
        ``"full"``: ``(G_y, G_x)`` in FFT order; ``"centred"``: zero frequency at
        ``(G_y // 2, G_x // 2)``.

    Returns
    -------
    numpy.ndarray
        float32 response in (0, 1], 1 at zero frequency and 1/2 at ``|u| = r0``.
    """
    if isinstance(order, bool) or not isinstance(order, int | np.integer) or order < 1:
        raise ReconInputError(f"order must be a positive integer, got {order!r}")
    r0 = cutoff_radius(n_slm)
    f2 = _freq_sq(shape, layout) / (r0 * r0)
    return (1.0 / (1.0 + f2 ** int(order))).astype(np.float32)


def passband_count(shape, n_slm: int, order: int = 5) -> int:
    """Number of DFT frequencies of the grid in the filter's passband (``c_f >= 1/2``).

    Parameters
    ----------
    shape : (int, int)
        Image grid.
    n_slm : int
        SLM pixel count.
    order : int
        Filter order.

    Returns
    -------
    int
        Close to ``n_slm`` (the lattice points in a disc of area ``n_slm``) when the
        disc fits in the grid.
    """
    return int(np.count_nonzero(butterworth_lowpass(shape, n_slm, order, "full") >= 0.5))


def lowpass(image: np.ndarray, response: np.ndarray) -> np.ndarray:
    """Apply a real-FFT-layout filter to a real image: ``irfft2(H rfft2(image))``.

    Parameters
    ----------
    image : numpy.ndarray
        Real 2D image (any float dtype).
    response : numpy.ndarray
        ``(G_y, G_x // 2 + 1)`` filter (e.g. :func:`butterworth_lowpass`).

    Returns
    -------
    numpy.ndarray
        float64 (for float64 input) or float32 image of the same shape.
    """
    a = np.asarray(image)
    if a.ndim != 2 or response.shape != (a.shape[0], a.shape[1] // 2 + 1):
        raise ReconInputError(f"filter shape {response.shape} does not match image {a.shape}")
    return sfft.irfft2(sfft.rfft2(a, workers=WORKERS) * response, s=a.shape, workers=WORKERS)


def foveation_map(shape, floor: float = 0.1, radius: float | None = None,
                  edge: float | None = None, centre=None) -> np.ndarray:
    """Grey-scale spatial weight ``c_s``: 1 in a disc, a Gaussian fall-off to ``floor``.

    ``c_s(r) = 1`` for ``r <= radius`` and ``floor + (1 - floor) exp(-(r - radius)^2 /
    (2 edge^2))`` outside (Eq. 7.19, Fig. 7.3 inset). The defaults, fixed before any
    evaluation, make the disc ``radius = min(shape) / 4`` (the central quarter of
    the field; 20 deg of eccentricity for an 80 deg display, Patney et al.'s foveal
    and blend zones) with ``edge = min(shape) / 16``.

    Parameters
    ----------
    shape : (int, int)
        Image grid (rows, cols), centred frame.
    floor : float
        Peripheral weight in [0, 1] (0.1 in the dissertation).
    radius, edge : float, optional
        Disc radius and Gaussian edge width in samples.
    centre : (float, float), optional
        ``(row, col)`` of the fovea; default the grid centre ``(G_y // 2, G_x // 2)``
        (the zero order). Move it to follow the gaze.

    Returns
    -------
    numpy.ndarray
        float32 ``shape`` in ``[floor, 1]``.
    """
    gy, gx = _grid(shape)
    if not 0.0 <= float(floor) <= 1.0:
        raise ReconInputError(f"floor must be in [0, 1], got {floor!r}")
    n = min(gy, gx)
    radius = n / 4.0 if radius is None else float(radius)
    edge = n / 16.0 if edge is None else float(edge)
    if not (radius >= 0 and edge > 0 and math.isfinite(radius) and math.isfinite(edge)):
        raise ReconInputError(f"radius must be >= 0 and edge > 0, got {radius}, {edge}")
    cy, cx = (gy // 2, gx // 2) if centre is None else (float(centre[0]), float(centre[1]))
    r = np.hypot((np.arange(gy) - cy)[:, None], (np.arange(gx) - cx)[None, :])
    out = np.where(r <= radius, 1.0,
                   floor + (1.0 - floor) * np.exp(-((r - radius) ** 2) / (2.0 * edge * edge)))
    return out.astype(np.float32)


@dataclass(frozen=True, eq=False)
class IntensityLoss:
    """Which intensity loss the optimiser minimises (Eq. 7.16, 7.17, 7.19).

    Build with :meth:`l2`, :meth:`frequency` or :meth:`spatial`.

    Attributes
    ----------
    lowpass : bool
        Filter the residual with the Butterworth low-pass ``P`` (Eq. 7.17).
    weights : numpy.ndarray or None
        Spatial weights ``c_s`` (centred frame, ``grid_shape``, finite, >= 0), or
        ``None``; the string ``"fovea"`` means :func:`foveation_map` at the grid size.
    order : int
        Butterworth order (5).
    match_mean : bool
        Use ``sigma = sum T / sum I`` (see module docstring).
    name : str
        Label for tables ("l2", "frequency", "spatial").
    """

    lowpass: bool = False
    weights: object = None
    order: int = 5
    match_mean: bool = True
    name: str = "l2"

    @classmethod
    def l2(cls, match_mean: bool = True) -> IntensityLoss:
        """Plain least squares on intensity (Eq. 7.16)."""
        return cls(False, None, 5, match_mean, "l2")

    @classmethod
    def frequency(cls, order: int = 5, match_mean: bool = True) -> IntensityLoss:
        """Frequency-constrained loss with the Butterworth low-pass (Eq. 7.17-7.18)."""
        return cls(True, None, order, match_mean, "frequency")

    @classmethod
    def spatial(cls, weights="fovea", order: int = 5, lowpass: bool = True,
                match_mean: bool = True) -> IntensityLoss:
        """Spatially weighted, frequency-constrained loss (Eq. 7.19).

        Parameters
        ----------
        weights : numpy.ndarray or "fovea"
            ``c_s`` on the centred image grid, or ``"fovea"`` for :func:`foveation_map`.
        order : int
            Butterworth order.
        lowpass : bool
            Keep the frequency constraint (Eq. 7.19 has both; ``False`` weights the
            plain residual).
        match_mean : bool
            See the module docstring.
        """
        if weights is None:
            raise ReconInputError("spatial loss needs weights: an array or 'fovea'")
        return cls(lowpass, weights, order, match_mean, "spatial")

    def weight_map(self, shape) -> np.ndarray | None:
        """The spatial weights at ``shape`` (centred frame, float32) or ``None``.

        Raises
        ------
        ReconInputError
            Weights of the wrong shape, negative, non-finite or all zero.
        """
        if self.weights is None:
            return None
        if isinstance(self.weights, str):
            if self.weights != "fovea":
                raise ReconInputError(f"weights must be an array or 'fovea', got "
                                      f"{self.weights!r}")
            return foveation_map(shape)
        w = np.asarray(self.weights, dtype=np.float32)
        if w.shape != tuple(shape):
            raise ReconInputError(f"spatial weights have shape {w.shape}, the image grid is "
                                  f"{tuple(shape)}")
        if not np.all(np.isfinite(w)) or np.any(w < 0) or not np.any(w):
            raise ReconInputError("spatial weights must be finite, >= 0 and not all zero")
        return w

"""The device half of :class:`recon.live.LiveReconstructor`: its state and solves on a
GPU (CuPy, PyTorch) or any other array-API backend.

:class:`DeviceLive` keeps on the device, for the whole video, the PSF spectrum and the
sensor weights (:class:`recon.solvers.xp_admm.XpAdmmPlan`, made once), the Wiener filter
of the current lambda and the warm-start ADMM iterate
(:class:`recon.solvers.xp_admm.XpAdmmState`). Per frame only the scaled measurement
(sensor-sized) goes to the device and the sensor field of view comes back; the
frame's conversion (dark, binning, scale) stays the NumPy code of
:meth:`recon.live.LiveReconstructor.prepare`, so both paths see the same numbers.

- :meth:`DeviceLive.wiener`: :func:`recon.solvers.wiener` with whole-array operations
  (the same complex64 filter, computed on the host once per lambda).
- :meth:`DeviceLive.admm`: the ADMM loop (:func:`recon.solvers.admm_loop.run_admm`)
  with the generic kernel set from the carried state (Kuo 2020, Eq. 4.5 / App. A.3;
  Boyd et al. 2011).
"""

from __future__ import annotations

import math
import time

import numpy as np

from .backend import Backend, check_memory, free_device_bytes, to_device, to_numpy, total
from .solvers.common import History, SolveResult
from .solvers.xp_admm import XpAdmmPlan, XpAdmmState, memory_bytes

__all__ = ["DeviceLive", "live_memory_bytes", "wiener_filter"]


def live_memory_bytes(padded_shape: tuple[int, int]) -> int:
    """Peak device memory of a live reconstruction (bytes).

    The ADMM solve with its state (:func:`recon.solvers.xp_admm.memory_bytes`, about
    30 float32 planes of the padded grid), plus 4 planes held across frames or by a
    Wiener frame beside a kept ADMM state: the Wiener filter (a complex half-spectrum),
    the frame's padded measurement and its spectrum, and the estimate a
    :class:`recon.live.LiveResult` holds on the device until it is read.

    Parameters
    ----------
    padded_shape : (P0, P1)
        The padded object grid.

    Returns
    -------
    int
    """
    return memory_bytes(padded_shape) + 4 * 4 * padded_shape[0] * padded_shape[1]


def wiener_filter(op, regularization: float) -> np.ndarray:
    """conj(H) / (|H|^2 + lambda), complex64, (P0, P1 // 2 + 1): the filter of
    :func:`recon.solvers.wiener` (same expression, same float32/complex64 rounding).

    Parameters
    ----------
    op : ConvolutionOperator
    regularization : float
        lambda > 0, in units of |H|^2.
    """
    spec = op.spectrum
    return (op.spectrum_conj / (spec.real**2 + spec.imag**2 + regularization)).astype(
        np.complex64)


class DeviceLive:
    """A live reconstructor's operator, filter and ADMM state on one backend's device.

    Parameters
    ----------
    backend : Backend
        Not NumPy (the NumPy path is :class:`recon.live.LiveReconstructor`'s own).
    plan : AdmmPlan
        The host plan of the live reconstructor (operator, spectra); copied to the
        device once, here.
    prior : Prior or str, optional
        ADMM's image prior (:mod:`recon.priors`; default anisotropic TV, the
        generic kernel set's); the live reconstructor passes its options' prior.

    Raises
    ------
    ReconInputError
        The live reconstruction does not fit in the device's free memory
        (:func:`recon.backend.check_memory` with :func:`live_memory_bytes`; nothing
        is allocated on the device then).
    """

    def __init__(self, backend: Backend, plan, prior=None):
        op = plan.op
        rows, cols = op.sensor_shape
        check_memory(live_memory_bytes(op.padded_shape), free_device_bytes(backend),
                     what=f"live reconstruction at {rows} x {cols} (binned)",
                     where=backend.label)
        self.backend = backend
        self.plan = plan
        like = to_device(np.zeros(1, np.float32), backend)
        self.xplan = XpAdmmPlan(plan, like, prior=prior)
        self.xop = self.xplan.xop
        self.xp = self.xop.xp
        self._filter: tuple[float, object] | None = None

    def upload(self, b: np.ndarray):
        """The host measurement ``b`` (float32, sensor shape) on the device."""
        return to_device(b, self.backend)

    def zeros(self, mu, use_tv: bool) -> XpAdmmState:
        """A cold ADMM state (everything zero) with penalties ``mu``."""
        return self.xplan.zeros(mu, use_tv)

    def admm(self, b: np.ndarray, state: XpAdmmState, *, iterations: int, tv: float,
             penalty) -> SolveResult:
        """ADMM iterations on the device from ``state`` (updated in place).

        Parameters
        ----------
        b : ndarray, float32, sensor shape
            Scaled measurement on the host (moved to the device here).
        state : XpAdmmState
        iterations : int
        tv : float
        penalty : AdmmPenalty

        Returns
        -------
        SolveResult
            As :func:`recon.solvers.admm_loop.run_admm`: ``x`` on the device;
            ``params["device"]`` the backend's label.

        Raises
        ------
        DivergenceError, ReconInputError
            From the solve.
        """
        res = self.xplan.run(self.upload(b), state, iterations=iterations, tv=tv,
                             penalty=penalty)
        res.params["device"] = self.backend.label
        return res

    def wiener(self, b: np.ndarray, regularization: float) -> SolveResult:
        """Wiener / Tikhonov deconvolution of :func:`recon.solvers.wiener` on the device:
        x = F^-1 [W F(P b)] with W of :func:`wiener_filter`, and its data residual.

        Parameters
        ----------
        b : ndarray, float32, sensor shape
            Scaled measurement on the host (validated by the caller).
        regularization : float
            lambda > 0.

        Returns
        -------
        SolveResult
            ``x`` (P0, P1) float32 on the device; ``history.seconds`` the solve with
            its residual (that residual's sum waits for the device).
        """
        xp, xop = self.xp, self.xop
        if self._filter is None or self._filter[0] != regularization:
            self._filter = (regularization,
                            xop.asarray(wiener_filter(self.plan.op, regularization)))
        bd = self.upload(b)
        t0 = time.perf_counter()
        spectrum = xp.fft.rfftn(xop.pad(bd), axes=(-2, -1)) * self._filter[1]
        x = xp.fft.irfftn(spectrum, s=xop.padded_shape, axes=(-2, -1))
        r = xop.forward(x) - bd
        data_sq = total(xp, r * r)
        seconds = time.perf_counter() - t0
        relative = math.sqrt(data_sq) / math.sqrt(total(xp, bd * bd))
        hist = History(objective=[0.5 * data_sq], data_residual=[relative], seconds=[seconds])
        return SolveResult(x, hist, 0.5 * data_sq, relative,
                           {"regularization": regularization, "device": self.backend.label})

    def images(self, x, scale: float, crop) -> tuple[np.ndarray, object]:
        """The estimate in measurement units: its sensor field of view on the host and
        the whole padded grid still on the device.

        Parameters
        ----------
        x : array, float32, (P0, P1), on the device
            A solve's estimate in the scaled problem.
        scale : float
            The frame's max|b|.
        crop : tuple of slice
            The sensor's field of view on the padded grid.

        Returns
        -------
        image : ndarray, float32, sensor shape (C-contiguous, on the host)
        estimate : array, float32, (P0, P1), on the device
        """
        estimate = x * float(scale)
        return np.ascontiguousarray(to_numpy(estimate[crop]), dtype=np.float32), estimate

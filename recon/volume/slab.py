"""One slab of depth planes of the 3D model and of 3D FISTA's iterates (Kuo 2020, Eq. 4.4).

The forward model ``b = C sum_z h_z * v_z`` is a sum over planes, so the planes can
be split into slabs ``[start, stop)`` that are applied independently: a slab's
share of ``A v`` is the sensor crop of the inverse FFT of its planes' summed
spectra (a sensor-sized partial image), and its part of ``A^T r`` needs only the
sensor-sized residual ``r``. The 3D TV couples a slab to its neighbours through
one plane on each side. :class:`VolumeSlab` holds its planes' PSF spectra
(complex64 half-spectra, made by :func:`recon.volume.operator.plane_spectra`, the
one place the model's spectra are made) and its planes of the FISTA iterates
``x``, ``y`` and ``v = y - step grad``; :func:`recon.volume.streamed.slab_fista`
drives one or several slabs, in one process or as dask actors
(:mod:`instrument.processing.volume_shards`).

Each plane is padded to the FFT grid and transformed on the fly, one chunk of
planes at a time, so nothing of the padded volume's size is ever held unless the
iterates live on the padded grid (``support="padded"``, for comparison with the
in-memory solver).

For the automatic weight's held-out path (:mod:`recon.volume.streamed_auto`) a slab
also keeps named copies of its planes of an iterate (:meth:`VolumeSlab.save`): the
path's kept estimates and the warm state it returns to stay with the planes they
belong to (in a dask worker, in that worker), and only their names cross.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from ..auto.holdout import coverage_ratio
from ..errors import ReconInputError
from ..fft import fft_workers, irfftn, rfftn
from ..operators import checked_sensor_weights, padded_grid
from . import _kernels3d
from .operator import CHUNK_BYTES, plane_spectra

__all__ = ["SUPPORTS", "VolumeSlab", "warm_up"]

#: Where the iterates live: on the sensor's field of view (``sensor``: the object
#: is zero outside it; what makes the seed-size problem fit) or on the whole padded
#: grid (``padded``: the model of :class:`~recon.volume.VolumeConvolutionOperator`).
SUPPORTS = ("sensor", "padded")


class VolumeSlab:
    """Planes ``[start, stop)`` of the 3D model and of 3D FISTA's iterates.

    Parameters
    ----------
    psf_stack : array-like, shape (n_z, rows, cols)
        The whole PSF stack at sensor size (a NumPy array, or a Zarr array chunked
        by plane: only planes ``start:stop`` are read, one chunk of planes at a
        time), in the units of the unnormalised stack.
    start, stop : int
        The slab's planes in the stack.
    psf_scale : float
        Divisor of the planes (:func:`recon.volume.normalize_psf_stack`'s scale of
        the whole stack, so every slab is scaled alike).
    padded_shape : (P0, P1), optional
        FFT grid (default :func:`recon.fft.fast_padded_shape` of the sensor).
    sensor_weights : ndarray, shape (rows, cols), optional
    support : {"sensor", "padded"}
        Lateral grid of the iterates (:data:`SUPPORTS`).
    chunk_bytes : int
        Bound of one chunk of plane spectra (FFT temporaries).

    Attributes
    ----------
    start, stop : int
    lateral_shape : (L0, L1)
        The iterates' planes: the sensor shape or the padded shape.
    x, y, v : ndarray, float32, shape (k, L0, L1)
    spectra : ndarray, complex64, shape (k, P0, P1 // 2 + 1)
    peak_saved_bytes : int
        The most bytes the saved copies (:meth:`save`) held at once so far.

    Raises
    ------
    ReconInputError
        Planes not 3D, not finite, all zero, a bad support or scale.
    """

    def __init__(self, psf_stack, start: int, stop: int, psf_scale: float, *,
                 padded_shape: tuple[int, int] | None = None, sensor_weights=None,
                 support: str = "sensor", chunk_bytes: int = CHUNK_BYTES):
        if support not in SUPPORTS:
            raise ReconInputError(f"support {support!r}: use one of {', '.join(SUPPORTS)}")
        if len(psf_stack.shape) != 3 or not 0 <= start < stop <= psf_stack.shape[0]:
            raise ReconInputError(f"slab {start}:{stop} of a PSF stack of shape "
                                  f"{psf_stack.shape}: the stack must be (n_z, rows, cols) "
                                  "and the slab a non-empty range of its planes")
        if not psf_scale > 0:
            raise ReconInputError(f"psf_scale must be > 0, got {psf_scale!r}")
        self.start, self.stop = int(start), int(stop)
        k = self.stop - self.start
        self.sensor_shape = tuple(int(n) for n in psf_stack.shape[1:])
        self.padded_shape, self.offset, self.crop = padded_grid(self.sensor_shape,
                                                                padded_shape)
        self.support = support
        self.lateral_shape = self.sensor_shape if support == "sensor" else self.padded_shape
        self.spectrum_shape = (self.padded_shape[0], self.padded_shape[1] // 2 + 1)
        self.sensor_weights = checked_sensor_weights(sensor_weights, self.sensor_shape)
        plane_bytes = 8 * self.spectrum_shape[0] * self.spectrum_shape[1]
        per = int(max(1, min(k, chunk_bytes // plane_bytes)))
        self._chunks = [slice(i, min(i + per, k)) for i in range(0, k, per)]
        self.spectra = np.empty((k, *self.spectrum_shape), np.complex64)
        for c in self._chunks:
            h = (np.asarray(psf_stack[self.start + c.start:self.start + c.stop], np.float32)
                 / np.float32(psf_scale))
            if not np.all(np.isfinite(h)):
                first = self.start + c.start
                raise ReconInputError(f"PSF planes {first}..{first + h.shape[0] - 1} contain "
                                      "NaN or inf; fix the calibration frames")
            empty = [self.start + c.start + i for i in range(h.shape[0]) if not np.any(h[i])]
            if empty:
                raise ReconInputError(f"PSF planes {empty} are all zero; recapture them or "
                                      "drop those depths")
            self.spectra[c] = plane_spectra(h, self.padded_shape, self.crop)
        self.x = np.zeros((k, *self.lateral_shape), np.float32)
        self.y = np.zeros_like(self.x)
        self.v = np.zeros_like(self.x)
        self._sum_spec = np.empty(self.spectrum_shape, np.complex64)
        self._pad = np.zeros(self.padded_shape, np.float32)
        self._in = (np.zeros((per, *self.padded_shape), np.float32)
                    if support == "sensor" else None)
        self._conj = np.empty((per, *self.spectrum_shape), np.complex64)
        self._saved: dict[str, tuple[np.ndarray, ...]] = {}
        self.peak_saved_bytes = 0

    @property
    def n_planes(self) -> int:
        """Planes of the slab."""
        return self.stop - self.start

    def memory_bytes(self) -> int:
        """Bytes of the arrays the slab holds (spectra, iterates, buffers)."""
        held = [self.spectra, self.x, self.y, self.v, self._sum_spec, self._pad, self._conj,
                self.sensor_weights] + ([self._in] if self._in is not None else [])
        return int(sum(a.nbytes for a in held)) + self.saved_bytes()

    # -- named copies of the iterates (the automatic weight's path) -------------------
    def _array(self, which: str) -> np.ndarray:
        """The slab's planes of ``which``: ``"x"``, ``"y"`` or a saved copy's name (its
        ``x``)."""
        if which == "x":
            return self.x
        if which == "y":
            return self.y
        return self._saved[which][0]

    def save(self, name: str, source: str = "x", state: bool = False) -> None:
        """Keep a copy of the slab's planes of an iterate under ``name``.

        Parameters
        ----------
        name : str
            New name (refused if taken).
        source : str
            What to copy: ``"x"``, ``"y"`` or another saved copy's name.
        state : bool
            Copy ``x`` and ``y`` together (a warm state for :meth:`restore`): the
            slab's own (``source`` ``"x"``) or a saved state's.
        """
        if name in self._saved or name in ("x", "y"):
            raise ReconInputError(f"slab copy {name!r} exists already")
        if not state:
            self._saved[name] = (self._array(source).copy(),)
        elif source == "x":
            self._saved[name] = (self.x.copy(), self.y.copy())
        else:
            self._saved[name] = tuple(a.copy() for a in self._saved[source])
        self.peak_saved_bytes = max(self.peak_saved_bytes, self.saved_bytes())

    def restore(self, name: str) -> None:
        """Set ``x`` (and ``y``: the saved one, else ``x``) from the copy ``name``."""
        saved = self._saved[name]
        np.copyto(self.x, saved[0])
        np.copyto(self.y, saved[-1])

    def release(self, names) -> None:
        """Drop the saved copies ``names`` (missing names are ignored)."""
        for name in names:
            self._saved.pop(name, None)

    def saved_bytes(self) -> int:
        """Bytes the saved copies hold now."""
        return int(sum(a.nbytes for saved in self._saved.values() for a in saved))

    def reset(self) -> None:
        """Zero the iterates ``x`` and ``y`` (a cold start)."""
        self.x.fill(0.0)
        self.y.fill(0.0)

    def coverage(self, weights: np.ndarray, fit_weights: np.ndarray | None = None,
                 peak: float | None = None) -> float:
        """How well ``fit_weights`` still see the slab's object pixels, against
        ``weights`` (:func:`recon.auto.holdout.holdout_coverage`, plane by plane).

        Parameters
        ----------
        weights, fit_weights : ndarray, float32, sensor shape
            The sensor weights ``w`` and those of the fit pixels, ``w keep`` (needed
            with ``peak`` only).
        peak : float, optional
            Largest ``A^T w`` over every slab's field of view; None: return this
            slab's (the first of the two passes).

        Returns
        -------
        float
            Without ``peak``: the largest ``A^T w`` over the slab's planes within the
            sensor's field of view; with it: the smallest ratio ``A^T (w keep) / A^T
            w`` over those seen (:func:`recon.auto.holdout.coverage_ratio`; ``inf``
            when none is).
        """
        out = -np.inf if peak is None else np.inf
        specs = [self._spectrum_of(weights)]
        if peak is not None:
            specs.append(self._spectrum_of(fit_weights))
        for c in self._chunks:
            backs = [self._back(spec, c) for spec in specs]
            for k in range(c.stop - c.start):
                seen = backs[0][(k, *self.crop)]
                out = (max(out, float(seen.max())) if peak is None
                       else min(out, coverage_ratio(seen, backs[1][(k, *self.crop)], peak)))
        return out

    def _spectrum_of(self, image: np.ndarray) -> np.ndarray:
        """rfft2 of a sensor image zero-padded to the FFT grid."""
        self._pad[self.crop] = image
        return rfftn(self._pad)

    def _back(self, spec: np.ndarray, c: slice) -> np.ndarray:
        """The chunk ``c`` of planes' ``H_z^*`` times ``spec``, back on the padded grid
        (float32, (len(c), P0, P1))."""
        g = self._conj[:c.stop - c.start]
        _kernels3d.conj_products(g, spec, self.spectra[c])
        return sfft.irfftn(g, s=self.padded_shape, axes=(-2, -1), workers=fft_workers(),
                           overwrite_x=True)

    def power_spectrum(self) -> np.ndarray:
        """``sum_z |H_z(f)|^2`` over the slab's planes (float64, the spectrum's shape):
        summed over slabs, its maximum times ``max(w)^2`` bounds the Lipschitz constant
        (:meth:`recon.volume.VolumeConvolutionOperator.lipschitz_bound`)."""
        power = np.zeros(self.spectrum_shape, np.float64)
        for k in range(self.n_planes):
            power += np.abs(self.spectra[k].astype(np.complex128)) ** 2
        return power

    # -- the model, plane chunk by plane chunk ----------------------------------------
    def _padded(self, a: np.ndarray, c: slice) -> np.ndarray:
        if self.support == "padded":
            return a[c]
        buf = self._in[:c.stop - c.start]
        buf[(slice(None), *self.crop)] = a[c]
        return buf

    def forward(self, which: str = "y") -> np.ndarray:
        """The slab's share of ``C sum_z h_z * v_z`` for the iterate ``which``.

        Parameters
        ----------
        which : str
            ``"y"``, ``"x"`` or a saved copy's name (:meth:`save`).

        Returns
        -------
        ndarray, float32, sensor shape
            Unweighted; the sum over slabs is the model's sensor image before the
            sensor weights.
        """
        a = self._array(which)
        for c in self._chunks:
            _kernels3d.accumulate_products(self._sum_spec, rfftn(self._padded(a, c)),
                                           self.spectra[c], c.start == 0)
        return np.ascontiguousarray(irfftn(self._sum_spec, self.padded_shape)[self.crop])

    def gradient_step(self, weighted_residual: np.ndarray, step: float,
                      before: bool = True, after: bool = True) -> list:
        """``v = y - step A_slab^T r``, and the boundary planes the neighbours need.

        Parameters
        ----------
        weighted_residual : ndarray, float32, sensor shape
            ``w * (w * A y - b)`` (the gradient's sensor image).
        step : float
        before, after : bool
            Whether a slab precedes / follows this one (only then are its boundary
            planes returned).

        Returns
        -------
        [v_first, v_last, y_first] : list of ndarray (float32, lateral shape) or None
            ``v`` of the first plane and ``y`` of the first plane for the slab before
            (its TV prox and the objective's depth term; None without one), ``v`` of
            the last plane for the slab after (None without one).
        """
        spec = self._spectrum_of(weighted_residual)
        step32 = np.float32(step)
        for c in self._chunks:
            back = self._back(spec, c)
            if self.support == "sensor":
                back = back[(slice(None), *self.crop)]
            np.multiply(back, step32, out=self.v[c])
            np.subtract(self.y[c], self.v[c], out=self.v[c])
        return [self.v[0].copy() if before else None, self.v[-1].copy() if after else None,
                self.y[0].copy() if before else None]

    def penalty(self, which: str = "y", after: np.ndarray | None = None
                ) -> tuple[float, float]:
        """(TV, l1) of the slab's planes of ``which`` (``"y"``, ``"x"`` or a saved
        copy's name); ``after``: the next slab's first plane of it (None for the
        volume's last slab)."""
        a = self._array(which)
        tv, l1 = _kernels3d.slab_penalty(a, a[0] if after is None else after,
                                         after is not None)
        return float(tv), float(l1)

    def prox(self, before: np.ndarray | None, after: np.ndarray | None,
             y_after: np.ndarray | None, thr: float, l1thr: float, beta: float,
             nonneg: bool) -> tuple[float, float, float]:
        """TV / l1 / non-negativity prox from ``v``, then the momentum step, in place.

        Parameters
        ----------
        before, after : ndarray or None
            ``v`` of the planes next to the slab (None at the volume's ends).
        y_after : ndarray or None
            ``y`` of the next slab's first plane (for the penalty at ``y``).
        thr, l1thr : float
            TV and l1 thresholds (:func:`recon.solvers.gradient.prox_threshold`).
        beta : float
            Momentum of this iteration.
        nonneg : bool

        Returns
        -------
        tv_y, l1_y, restart_dot : float
            The unweighted penalties of the slab at ``y`` (before the update) and its
            share of ``<y - x_new, x_new - x_old>``.
        """
        tv_y, l1_y = self.penalty("y", y_after)
        dot = _kernels3d.slab_prox(self.v, self.v[0] if before is None else before,
                                   self.v[0] if after is None else after,
                                   before is not None, after is not None, self.y, self.x,
                                   thr, l1thr, beta, nonneg)
        return tv_y, l1_y, float(dot)

    def restart(self) -> None:
        """Drop the momentum: ``y = x``."""
        np.copyto(self.y, self.x)

    def first_plane(self, which: str = "x") -> np.ndarray:
        """A copy of the first plane of ``which`` (``"x"``, ``"y"`` or a saved copy's
        name; the previous slab's ``after``)."""
        return self._array(which)[0].copy()

    def estimate(self, which: str = "x") -> np.ndarray:
        """The slab's planes of ``x`` or of a saved copy (float32, (k, L0, L1); the
        array itself)."""
        return self._array(which)

    def estimate_shape(self) -> tuple[int, ...]:
        """Shape of :meth:`estimate`."""
        return self.x.shape


def warm_up() -> None:
    """Compile the slab's numba kernels and plan its FFTs on a tiny problem, so that a
    process's memory and time figures taken afterwards leave compilation out (a dask
    worker runs it before its resident set is read)."""
    rng = np.random.default_rng(0)
    slab = VolumeSlab(rng.random((2, 8, 8), dtype=np.float32) + 0.1, 0, 2, 1.0)
    slab.forward("y")
    slab.gradient_step(np.zeros((8, 8), np.float32), 0.1)
    slab.prox(None, None, None, 0.01, 0.0, 0.5, True)

"""Spatially varying forward models: local convolution and low-rank PCA (Kuo 2020, Ch. 5).

Both models have the form of Eq. 5.5,

    A y = diag(w) C sum_j F^-1 diag(F P k_j) F diag(W_j) y_{z_j},

a sum of cropped convolutions of weighted copies of the object: kernel ``k_j``
(a registered calibration PSF for the local convolution model, Eq. 5.3-5.4; a
principal PSF for the PCA model, Eq. 5.6-5.7) acts on plane ``z_j`` of the object
through the weight map ``W_j`` over the padded object grid (the bilinear
``alpha_i`` of Eq. 5.3; the interpolated PCA weights ``w_i`` of Eq. 5.7).
:class:`SpatialConvolutionOperator` implements it with the conventions of
:class:`recon.operators.ConvolutionOperator` (padded grid, centred kernels, crop,
sensor weights, float32 / complex64 real FFTs) in 2D (``shape_in = (P0, P1)``)
and in 3D (``shape_in = (n_z, P0, P1)``, Eq. 5.4 summed over depth), so the FISTA
solvers (:func:`recon.solvers.fista`, :func:`recon.volume.fista3d`) take it as it is.

Cost with ``K`` kernels (``K = sum_z N_z`` for the local model, ``sum_z k_z`` for
PCA; ``K`` counts only kernels whose weights touch the object support):
``forward`` ``K`` rfft2 + 1 irfft2, ``adjoint`` 1 rfft2 + ``K`` irfft2, the fused
``data_term`` ``K + 1`` rfft2/irfft2 pairs -- ``K`` convolutions per apply plus one
transform, exactly the 3D convolution model with ``K`` planes
(:func:`recon.volume.fft_floor_seconds` is its floor). The weight maps are
separable tents (local) or sums of them (PCA), computed per chunk from
``(ny, P0)`` and ``(nx, P1)`` factors unless they fit a small cache.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from .. import _kernels
from ..errors import ReconInputError
from ..fft import fft_workers, irfftn, rfftn
from ..operators import LinearOperator, SensorWeighted, checked_sensor_weights, padded_grid
from ..volume import _kernels3d
from ..volume.operator import CHUNK_BYTES, VolumeConvolutionOperator
from . import _kernels as _spatial_kernels
from .grid import PsfGrid, synthesize_grid

__all__ = ["SpatialConvolutionOperator", "local_convolution_operator", "pca_components",
           "pca_operator", "spatial_memory_bytes"]

#: Weight maps are cached when they take at most this many bytes.
WEIGHT_CACHE_BYTES = 256 * 2**20


class SpatialConvolutionOperator(SensorWeighted, LinearOperator):
    """Sum of cropped convolutions of weighted object planes (Eq. 5.5; module docstring).

    Parameters
    ----------
    kernels : ndarray, (K, rows, cols)
        Convolution kernels at sensor size (registered or principal PSFs).
    planes : array_like of int, (K,)
        Object plane of each kernel (0 in 2D).
    coefficients : list of ndarray
        Per kernel, its weight map's coefficients ``c_j`` (ny_z, nx_z) over the
        node tents of its plane: ``W_j = wy_z^T c_j wx_z``.
    tents : list of (wy, wx)
        Per plane, the node tents ``wy`` (ny_z, P0) and ``wx`` (nx_z, P1)
        (:meth:`recon.spatial.PsfGrid.tents`).
    volume : bool
        3D (``shape_in = (n_z, P0, P1)``) or 2D (``(P0, P1)``, one plane).
    padded_shape : (P0, P1), optional
    support : ndarray of bool, shape ``shape_in``, optional
        Known object support: the object is zero elsewhere (folded into the
        weights), and kernels whose weights vanish on it are dropped.
    sensor_weights : ndarray, (rows, cols), optional
        Erasure mask (Eq. 3.10).
    depths : array_like, (n_z,), optional
        Metadata (mm).

    Attributes
    ----------
    n_kernels : int
        Kernels kept (convolutions per apply).
    ffts_per_apply : int
        ``n_kernels + 1``.
    brightness : ndarray or None
        With caustic kernels (the two-part model of a far scene,
        :func:`recon.spatial.api.grid_model`), the relative brightness map (float32,
        sensor shape) reconstructions are divided by; None otherwise.

    Raises
    ------
    ReconInputError
        Inconsistent shapes, a support of the wrong shape or empty on every kernel.
    """

    brightness: np.ndarray | None = None

    def __init__(self, kernels, planes, coefficients, tents, *, volume: bool,
                 padded_shape=None, support=None, sensor_weights=None, depths=None,
                 chunk_bytes: int = CHUNK_BYTES, _spectra=None):
        kernels = np.asarray(kernels, np.float32)
        planes = np.asarray(planes, int).reshape(-1)
        if kernels.ndim != 3 or len(planes) != kernels.shape[0] or len(coefficients) != len(
                planes):
            raise ReconInputError("kernels, planes and coefficients must have one entry per "
                                  "kernel")
        n_z = len(tents)
        if not volume and n_z != 1:
            raise ReconInputError("a 2D spatially varying model has one plane of tents")
        if planes.min() < 0 or planes.max() >= n_z:
            raise ReconInputError(f"kernel planes {planes.tolist()} outside 0..{n_z - 1}")
        self.sensor_shape = kernels.shape[1:]
        self.padded_shape, self.offset, self.crop = padded_grid(self.sensor_shape, padded_shape)
        self.volume, self.n_z = bool(volume), n_z
        self.shape_in = (n_z, *self.padded_shape) if volume else self.padded_shape
        self.shape_out = self.sensor_shape
        self.tents = [(np.asarray(wy, np.float32), np.asarray(wx, np.float32))
                      for wy, wx in tents]
        for wy, wx in self.tents:
            if wy.shape[1] != self.padded_shape[0] or wx.shape[1] != self.padded_shape[1]:
                raise ReconInputError("tents do not match the padded shape")
        self.coefficients = [np.asarray(c, np.float32) for c in coefficients]
        self.depths = depths
        self.support = None
        if support is not None:
            sup = np.asarray(support, bool)
            if sup.shape != tuple(self.shape_in):
                raise ReconInputError(
                    f"object support has shape {sup.shape}, the model's object is "
                    f"{tuple(self.shape_in)}")
            self.support = sup.reshape(n_z, *self.padded_shape)
        keep = [j for j in range(len(planes)) if self._touches_support(j, planes[j])]
        if not keep:
            raise ReconInputError("the object support is empty (or outside every PSF's "
                                  "region); give a support with some object pixels")
        self.kept = np.array(keep)
        self.kernels = np.ascontiguousarray(kernels[keep])
        self.planes = planes[keep]
        self.coefficients = [self.coefficients[j] for j in keep]
        self.n_kernels = len(keep)
        self.ffts_per_apply = self.n_kernels + 1
        self.sensor_weights = checked_sensor_weights(sensor_weights, self.sensor_shape)
        self._conv = VolumeConvolutionOperator(self.kernels, padded_shape=self.padded_shape,
                                               chunk_bytes=chunk_bytes, _spectra=_spectra)
        self.spectra = self._conv.spectra
        self._chunks = self._conv._chunks
        plane_bytes = 4 * self.padded_shape[0] * self.padded_shape[1]
        self._cache = None
        if self.n_kernels * plane_bytes <= WEIGHT_CACHE_BYTES:
            self._cache = np.stack([self._weight_map(j) for j in range(self.n_kernels)])
        self._plane_index = np.ascontiguousarray(self.planes, dtype=np.int64)
        per = self._conv.planes_per_chunk
        self._tmp = np.empty((per, *self.padded_shape), np.float32)
        self._pad_buf = np.zeros(self.padded_shape, np.float32)
        self._zero_b = np.zeros(self.sensor_shape, np.float32)

    # -- weights ---------------------------------------------------------------------
    def _raw_map(self, coef, plane) -> np.ndarray:
        wy, wx = self.tents[plane]
        nz = np.flatnonzero(coef)
        if nz.size == 1:  # one node (local model): an outer product of two tents
            a, b = np.unravel_index(nz[0], coef.shape)
            return np.multiply.outer(wy[a] * coef[a, b], wx[b])
        return (wy.T @ coef) @ wx

    def _touches_support(self, j, plane) -> bool:
        w = self._raw_map(self.coefficients[j], plane)
        if self.support is not None:
            w = w * self.support[plane]
        return bool(np.any(w))

    def _weight_map(self, j: int) -> np.ndarray:
        """``W_j`` (P0, P1) float32, the support folded in."""
        if getattr(self, "_cache", None) is not None:
            return self._cache[j]
        w = self._raw_map(self.coefficients[j], self.planes[j]).astype(np.float32, copy=False)
        if self.support is not None:
            w = w * self.support[self.planes[j]]
        return w

    def weight_sum(self, plane: int = 0) -> np.ndarray:
        """``sum_j W_j`` over the kernels of one plane (1 on the support for the local
        model: a partition of unity)."""
        total = np.zeros(self.padded_shape, np.float32)
        for j in np.flatnonzero(self.planes == plane):
            total += self._weight_map(int(j))
        return total

    # -- composition -----------------------------------------------------------------
    @property
    def final_on_all_pixels(self) -> bool:
        """Whether the automatic weight's result is a final solve on all pixels from
        the chosen estimate (2D; ``recon.auto.weight.FINAL_ON_ALL_PIXELS``) rather than
        its fit-pixel iterate (a volume, like a convolution)."""
        return not self.volume

    def with_weights(self, sensor_weights) -> SpatialConvolutionOperator:
        """A copy with other sensor weights, sharing the kernel spectra."""
        sup = None if self.support is None else self.support.reshape(self.shape_in)
        return SpatialConvolutionOperator(
            self.kernels, self.planes, self.coefficients, self.tents, volume=self.volume,
            padded_shape=self.padded_shape, support=sup, sensor_weights=sensor_weights,
            depths=self.depths, _spectra=self.spectra)

    # -- application -----------------------------------------------------------------
    def _planes_of(self, x) -> np.ndarray:
        return x if self.volume else x[None]

    def _sum_spectrum(self, x: np.ndarray) -> np.ndarray:
        xv = np.ascontiguousarray(self._planes_of(x))
        acc = self._conv._sum_spec
        for c in self._chunks:
            tmp = self._tmp[:c.stop - c.start]
            if self._cache is not None:  # fused: one parallel pass over the chunk
                _spatial_kernels.weighted_planes(tmp, xv, self._cache[c], self._plane_index[c])
            else:
                for k, j in enumerate(range(c.start, c.stop)):
                    np.multiply(xv[self.planes[j]], self._weight_map(j), out=tmp[k])
            _kernels3d.accumulate_products(acc, rfftn(tmp), self.spectra[c], c.start == 0)
        return acc

    def _backproject(self, spec: np.ndarray, out: np.ndarray) -> np.ndarray:
        ov = self._planes_of(out)
        ov[...] = 0.0
        g = self._conv._plane_spec
        for c in self._chunks:
            gc = g[:c.stop - c.start]
            _kernels3d.conj_products(gc, spec, self.spectra[c])
            planes = sfft.irfftn(gc, s=self.padded_shape, axes=(-2, -1),
                                 workers=fft_workers(), overwrite_x=True)
            if self._cache is not None:
                _spatial_kernels.accumulate_weighted(ov, planes, self._cache[c],
                                                     self._plane_index[c])
                continue
            for k, j in enumerate(range(c.start, c.stop)):
                planes[k] *= self._weight_map(j)
                ov[self.planes[j]] += planes[k]
        return out

    def convolve_full(self, x: np.ndarray) -> np.ndarray:
        """``M x``: the sum of circular convolutions on the padded grid, before the
        crop and the sensor weights (``K`` rfft2 + 1 irfft2).

        Parameters
        ----------
        x : ndarray, ``shape_in``, float32

        Returns
        -------
        ndarray, float32, ``padded_shape``
        """
        x = self._check(x, self.shape_in, "object")
        return irfftn(self._sum_spectrum(x), self.padded_shape)

    def correlate_full(self, v: np.ndarray) -> np.ndarray:
        """``M^T v``, the adjoint of :meth:`convolve_full` (1 rfft2 + ``K`` irfft2).

        Parameters
        ----------
        v : ndarray, ``padded_shape``, float32

        Returns
        -------
        ndarray, float32, ``shape_in``
        """
        v = self._check(v, self.padded_shape, "padded sensor image")
        return self._backproject(rfftn(v), np.empty(self.shape_in, np.float32))

    def forward(self, x):
        full = self.convolve_full(x)
        return (self.sensor_weights * full[self.crop]).astype(np.float32)

    def adjoint(self, y):
        y = self._check(y, self.shape_out, "sensor image")
        buf = self._pad_buf
        np.multiply(self.sensor_weights, y, out=buf[self.crop])
        return self._backproject(rfftn(buf), np.empty(self.shape_in, np.float32))

    def data_term(self, x, b, out: np.ndarray | None = None):
        """Fused loss 1/2 ||A x - b||^2 and gradient: ``K + 1`` rfft2/irfft2 pairs.

        Parameters
        ----------
        x : ndarray, ``shape_in``, float32
        b : ndarray, ``shape_out``, float32
        out : ndarray, ``shape_in``, float32, optional
            Gradient buffer.

        Returns
        -------
        loss : float
        grad : ndarray, ``shape_in``, float32
        """
        x = self._check(x, self.shape_in, "object")
        b = self._check(b, self.shape_out, "measurement")
        if out is None:
            out = np.empty(self.shape_in, np.float32)
        full = irfftn(self._sum_spectrum(x), self.padded_shape)
        loss = _kernels.crop_residual(full, np.ascontiguousarray(b), self.sensor_weights,
                                      *self.offset)
        self._backproject(rfftn(full), out)
        return 0.5 * loss, out

    def normal(self, x):
        """A^T A x via the fused data term with b = 0."""
        return self.data_term(x, self._zero_b)[1]

    def memory_bytes(self) -> int:
        """Bytes held: kernel spectra and stack, weight factors or cache, buffers."""
        held = [self.spectra, self.kernels, self.sensor_weights, self._tmp, self._pad_buf,
                self._conv._sum_spec, self._conv._plane_spec]
        held += [a for t in self.tents for a in t]
        if self._cache is not None:
            held.append(self._cache)
        if self.support is not None:
            held.append(self.support)
        return int(sum(a.nbytes for a in held))

    def _check(self, a, shape, what):
        return VolumeConvolutionOperator._check(self, a, shape, what)


def spatial_memory_bytes(sensor_shape, n_kernels: int, *, chunk_bytes: int = CHUNK_BYTES,
                         volumes: int = 5, n_z: int = 1) -> dict[str, int]:
    """Estimated bytes of a spatially varying model and a FISTA solve, without building it.

    Parameters
    ----------
    sensor_shape : (rows, cols)
    n_kernels : int
        Kernels (``N`` per depth times depths for the local model).
    chunk_bytes : int
    volumes : int
        Object-sized arrays the solver keeps (FISTA: 5).
    n_z : int
        Object planes.

    Returns
    -------
    dict
        ``kernel_spectra``, ``kernels``, ``weight_cache`` (0 when above
        :data:`WEIGHT_CACHE_BYTES`), ``chunk_buffers``, ``objects``, ``total`` (bytes).
    """
    from ..fft import fast_padded_shape

    p0, p1 = fast_padded_shape(tuple(sensor_shape))
    spec = 8 * p0 * (p1 // 2 + 1)
    plane = 4 * p0 * p1
    per_chunk = max(1, min(n_kernels, chunk_bytes // spec))
    cache = n_kernels * plane
    est = {"kernel_spectra": n_kernels * spec,
           "kernels": 4 * n_kernels * sensor_shape[0] * sensor_shape[1],
           "weight_cache": cache if cache <= WEIGHT_CACHE_BYTES else 0,
           "chunk_buffers": per_chunk * (2 * spec + 2 * plane),
           "objects": volumes * n_z * plane}
    est["total"] = sum(est.values())
    return est


# ----------------------------------------------------------------------------- builders
def _plane_grids(grids, depths_mm) -> tuple[list[PsfGrid], bool]:
    if isinstance(grids, PsfGrid):
        if depths_mm is not None:
            raise ReconInputError("depths need a list of calibrated PSF grids (one per depth)")
        return [grids], False
    grids = list(grids)
    if not grids or not all(isinstance(g, PsfGrid) for g in grids):
        raise ReconInputError("pass a PsfGrid (2D) or a list of PsfGrid, one per depth (3D)")
    if depths_mm is None:
        return sorted(grids, key=lambda g: (g.z_mm is None, g.z_mm or 0.0)), True
    return [synthesize_grid(grids, float(z)) for z in np.asarray(depths_mm, float)], True


def _scale(per_plane_sums: list[float], volume: bool) -> float:
    sums = np.asarray(per_plane_sums, np.float64)
    return float(np.sqrt(np.sum(sums**2)) if volume else sums[0])


def local_convolution_operator(grids, *, depths_mm=None, padded_shape=None, support=None,
                               sensor_weights=None, normalize: bool = True
                               ) -> SpatialConvolutionOperator:
    """The local convolution model (Eq. 5.3-5.5) from registered PSF grids.

    Parameters
    ----------
    grids : PsfGrid or list of PsfGrid
        One grid: 2D model. A list: 3D model with one plane per grid (sorted by
        depth), or per entry of ``depths_mm`` (grids synthesised at those depths,
        :func:`recon.spatial.synthesize_grid`).
    depths_mm : array_like, optional
        Reconstruction depths, mm.
    padded_shape, support, sensor_weights
        As :class:`SpatialConvolutionOperator`.
    normalize : bool
        Scale the kernels so the central (reference-row) PSF of a 2D model has unit
        sum, or ``sum_z (sum h_ref,z)^2 = 1`` in 3D (the solvers' scaling convention,
        :func:`recon.api.scaled_problem`, :func:`recon.volume.normalize_psf_stack`);
        the divisor is ``op.scale``.

    Returns
    -------
    SpatialConvolutionOperator
        ``N`` kernels per plane (fewer with a support), ``op.scale`` set.
    """
    plane_grids, volume = _plane_grids(grids, depths_mm)
    kernels, planes, coefs, tents, ref_sums = [], [], [], [], []
    padded = padded_grid(plane_grids[0].sensor_shape, padded_shape)[0]
    for z, g in enumerate(plane_grids):
        if g.sensor_shape != plane_grids[0].sensor_shape:
            raise ReconInputError("the PSF grids differ in sensor shape")
        tents.append(g.tents(padded))
        ny, nx = g.grid_shape
        for i in range(g.n):
            c = np.zeros((ny, nx), np.float32)
            c.flat[i] = 1.0
            kernels.append(g.psfs[i])
            planes.append(z)
            coefs.append(c)
        ref_sums.append(float(g.psfs[g.central].sum()))
    return _assemble("local", kernels, planes, coefs, tents, plane_grids, ref_sums, volume,
                     normalize, padded_shape=padded, support=support,
                     sensor_weights=sensor_weights)


def _assemble(model, kernels, planes, coefs, tents, plane_grids, ref_sums, volume, normalize,
              **options) -> SpatialConvolutionOperator:
    scale = _scale(ref_sums, volume) if normalize else 1.0
    if not scale > 0:
        raise ReconInputError("the central PSF has no positive energy; check the calibration")
    op = SpatialConvolutionOperator(
        np.stack(kernels) / scale, planes, coefs, tents, volume=volume,
        depths=[g.z_mm for g in plane_grids] if volume else None, **options)
    op.scale, op.model = scale, model
    return op


def pca_components(grid: PsfGrid, *, k: int | None = None, energy: float = 0.99
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Principal PSFs and node weights of one grid (Eq. 5.6, SVD of the registered PSFs).

    ``H = [h~_1 ... h~_N] ~ sum_{i<=k} p_i w_i^T``: ``p_i`` the left singular
    vectors times their singular values (the principal PSFs, in PSF units), ``w_i``
    the right singular vectors (one weight per node). ``k`` is given, or the smallest
    with ``sum_{i<=k} s_i^2 >= energy * sum s_i^2`` (explained energy).

    Parameters
    ----------
    grid : PsfGrid
    k : int, optional
        Components (1..N).
    energy : float
        Explained-energy fraction in (0, 1] used when ``k`` is None.

    Returns
    -------
    principal : ndarray, float32, (k, rows, cols)
    weights : ndarray, float32, (k, ny, nx)
    explained : ndarray, float64, (N,)
        Cumulative explained energy after 1..N components.

    Raises
    ------
    ReconInputError
        ``k`` outside 1..N or ``energy`` outside (0, 1].
    """
    n = grid.n
    H = grid.psfs.reshape(n, -1).astype(np.float64)  # rows: PSFs
    gram = H @ H.T  # N x N: the SVD through the small Gram matrix
    evals, evecs = np.linalg.eigh(gram)
    order = np.argsort(evals)[::-1]
    evals, evecs = np.clip(evals[order], 0, None), evecs[:, order]
    explained = np.cumsum(evals) / evals.sum()
    if k is None:
        if not (isinstance(energy, int | float) and 0 < energy <= 1):
            raise ReconInputError(f"energy must be in (0, 1], got {energy!r}; e.g. 0.99")
        k = int(np.searchsorted(explained, energy - 1e-12) + 1)
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 1 <= k <= n:
        raise ReconInputError(f"k = {k!r} principal PSFs: use 1..{n} (the grid's PSFs)")
    k = int(min(k, np.count_nonzero(evals > evals[0] * 1e-12) or 1))
    # left singular vectors times singular values: u_i s_i = H^T v_i
    principal = (evecs[:, :k].T @ H).reshape(k, *grid.sensor_shape)
    weights = evecs[:, :k].T.reshape(k, *grid.grid_shape)
    return principal.astype(np.float32), weights.astype(np.float32), explained


def pca_operator(grids, *, k: int | None = None, energy: float = 0.99, depths_mm=None,
                 padded_shape=None, support=None, sensor_weights=None, normalize: bool = True
                 ) -> SpatialConvolutionOperator:
    """The low-rank PCA model (Eq. 5.6-5.7) from registered PSF grids.

    Per plane the registered PSFs are decomposed by :func:`pca_components`; the
    node weights of each component are interpolated over the field with the
    bilinear tents of the grid (Eq. 5.7), so with ``k = N`` the model equals
    :func:`local_convolution_operator` (up to rounding). Arguments as there, plus
    ``k`` / ``energy`` (per plane). ``op.components`` lists ``k`` per plane and
    ``op.explained`` the cumulative explained energy.
    """
    plane_grids, volume = _plane_grids(grids, depths_mm)
    padded = padded_grid(plane_grids[0].sensor_shape, padded_shape)[0]
    kernels, planes, coefs, tents, ref_sums, ks, explained = [], [], [], [], [], [], []
    for z, g in enumerate(plane_grids):
        tents.append(g.tents(padded))
        principal, weights, expl = pca_components(g, k=k, energy=energy)
        kernels.extend(principal)
        coefs.extend(weights)
        planes.extend([z] * len(principal))
        ks.append(len(principal))
        explained.append(expl.tolist())
        ref_sums.append(float(g.psfs[g.central].sum()))
    op = _assemble("pca", kernels, planes, coefs, tents, plane_grids, ref_sums, volume,
                   normalize, padded_shape=padded, support=support,
                   sensor_weights=sensor_weights)
    op.components, op.explained = ks, explained
    return op

"""The SLM -> relay -> mask -> Fourier lens -> camera model.

Part of :mod:`recon.optics.holo_display` (see its docstring for the model). The spot
metric measured on camera frames (:func:`~recon.optics.holo_display.spot.efficiency`)
is in :mod:`.spot`.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from ...errors import ReconInputError
from ...validate import as_int, as_vec2, finite_float
from .basics import WORKERS, check_gray, check_phase
from .components import CameraMapping, LaserDrift, RelayModel, SlmModel
from .mask import MaskModel, StagePose
from .spot import block_reduce, check_u0, phase_ramp


@dataclass
class _Relayed:
    """Defocus field of a pose: ``dz(i, j) = dz0 + gy y_um(i) + gx x_um(j)`` (um)."""

    dz0: float
    gy: float
    gx: float


class HolographicDisplayModel:
    """SLM -> relay -> random mask -> Fourier lens -> camera, for a gray image and pose.

    Parameters
    ----------
    mask : MaskModel
        Mask model with its ground truth (sets the SLM shape, k, q and pitches).
    slm : SlmModel, optional
        SLM response (default: linear LUT, fill factor 1, no crosstalk).
    relay : RelayModel, optional
        Relay optics (default: 0.66 um, no pupil, paraxial).
    camera : CameraMapping, optional
        Far field -> camera affine and camera shape (default 480 x 640, identity,
        zero order at the centre).
    drift : LaserDrift, optional
        Laser power drift (default: a seeded drift with factor 1 until advanced).
    power_e_per_s : float
        Laser power scale: photo-electrons per second the camera would collect if the
        entire far field of a fully transmitting SLM fell on it.
    pad : int
        Far-field oversampling (zero padding of the fine field before the FFT, >= 1):
        ``pad = 2`` resolves the sinc profile of a spot; the cost grows as ``pad^2``.

    Notes
    -----
    Normalisation: with ``N`` fine samples and ``N_pad = pad^2 N`` FFT samples, the
    far-field grid value is ``power * drift * |F|^2 / (N N_pad)``; by Parseval the
    whole far field sums to ``power * drift * mean |U m|^2 <= power * drift``.
    """

    def __init__(self, mask: MaskModel, slm: SlmModel | None = None,
                 relay: RelayModel | None = None, camera: CameraMapping | None = None,
                 drift: LaserDrift | None = None, power_e_per_s: float = 1e9, pad: int = 1):
        if not isinstance(mask, MaskModel):
            raise ReconInputError(f"mask must be a MaskModel, got {type(mask).__name__}")
        self._mask = mask
        self._slm = slm if slm is not None else SlmModel()
        self._relay = relay if relay is not None else RelayModel()
        self._camera = camera if camera is not None else CameraMapping()
        for name, val, typ in (("slm", self._slm, SlmModel), ("relay", self._relay, RelayModel),
                               ("camera", self._camera, CameraMapping)):
            if not isinstance(val, typ):
                raise ReconInputError(f"{name} must be a {typ.__name__}, got {type(val).__name__}")
        self.drift = drift if drift is not None else LaserDrift()
        if not isinstance(self.drift, LaserDrift):
            raise ReconInputError("drift must be a LaserDrift")
        self.power_e_per_s = finite_float(power_e_per_s, "power_e_per_s", lo=0.0)
        self.pad = as_int(pad, "pad", 1)
        self._n = mask.k * mask.q
        ap = self._slm.aperture(self._n)
        rows, cols = mask.slm_shape
        self._wy = np.tile(ap, rows)
        self._wx = np.tile(ap, cols)
        self._cache: OrderedDict = OrderedDict()
        self._lock = threading.Lock()
        self._band_cache = None
        self._pupil_cache = None
        # pupil-limited relay of a pixel-wise constant SLM field: spectrum from the
        # SLM-resolution FFT, inverse FFT pruned to the pupil's rows (see _relay_band)
        self._band_ok = (self._relay.na is not None and self._slm.crosstalk_px == 0.0
                         and not (self._slm.gap_amplitude and self._slm.fill_factor < 1.0))

    # -- properties --------------------------------------------------------------------

    mask = property(lambda self: self._mask, doc="The :class:`MaskModel`.")
    slm = property(lambda self: self._slm, doc="The :class:`SlmModel`.")
    relay = property(lambda self: self._relay, doc="The :class:`RelayModel`.")
    camera = property(lambda self: self._camera, doc="The :class:`CameraMapping`.")

    @property
    def slm_shape(self) -> tuple[int, int]:
        """SLM (rows, cols)."""
        return self._mask.slm_shape

    @property
    def fov_samples(self) -> tuple[int, int]:
        """Display field of view (Eq. 7.9) in far-field samples, ``(C k, R k)`` (x, y)."""
        r, c = self._mask.slm_shape
        return (c * self._mask.k, r * self._mask.k)

    @property
    def slm_band_samples(self) -> tuple[int, int]:
        """Width of the mask-free SLM band in far-field samples, ``(C, R)`` (x, y)."""
        r, c = self._mask.slm_shape
        return (c, r)

    def spot_camera_px(self, u0) -> tuple[float, float]:
        """Camera position ``(x, y)`` of far-field frequency ``u0`` (the affine)."""
        return tuple(float(v) for v in self._camera.to_camera(as_vec2(u0, "u0")))

    # -- geometry of a pose ------------------------------------------------------------

    def _defocus(self, pose: StagePose) -> _Relayed:
        tr = self._mask.effective_transform(pose)
        # dz(x, y) = dz0 + rx * y - ry * x   (x, y, dz in um)
        return _Relayed(dz0=tr.defocus_mm * 1000.0, gy=tr.tip_rad, gx=-tr.tilt_rad)

    def _plane_um(self):
        mm = self._mask
        ny, nx = mm.fine_shape
        hx, hy = mm.half_size
        y = ((np.arange(ny) + 0.5) / mm.q - hy) * mm.mask_pitch_um
        x = ((np.arange(nx) + 0.5) / mm.q - hx) * mm.mask_pitch_um
        return y, x

    def _levels(self, rel: _Relayed):
        """Planes ``z_l`` and tent spacing for the blended propagation (or None)."""
        y, x = self._plane_um()
        span = abs(rel.gy) * (y[-1] - y[0]) + abs(rel.gx) * (x[-1] - x[0])
        if span == 0.0:
            return [rel.dz0], None
        lo = rel.dz0 - 0.5 * span
        step = self._relay.level_step_um
        if step is None:  # quarter radian at the highest frequency that matters
            f_max = 1.0 / self._mask.slm_pitch_um
            if self._relay.na is not None:  # nothing passes beyond the pupil
                f_max = min(f_max, self._relay.na / self._relay.wavelength_um)
            step = 0.25 / (math.pi * self._relay.wavelength_um * f_max**2)
        n_lv = min(self._relay.max_levels, max(2, int(math.ceil(span / step)) + 1))
        spacing = span / (n_lv - 1)
        return [lo + i * spacing for i in range(n_lv)], spacing

    def _transfer(self, dz_um: float) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        mm = self._mask
        ny, nx = mm.fine_shape
        lam = self._relay.wavelength_um
        fy = sfft.fftfreq(ny, d=mm.fine_pitch_um)
        fx = sfft.fftfreq(nx, d=mm.fine_pitch_um)
        if self._relay.paraxial:
            hy = np.exp(-1j * math.pi * lam * dz_um * fy * fy).astype(np.complex64)
            hx = np.exp(-1j * math.pi * lam * dz_um * fx * fx).astype(np.complex64)
            return hy, hx
        f2 = (fy * fy)[:, None] + (fx * fx)[None, :]
        arg = np.maximum(1.0 / lam**2 - f2, 0.0)
        h = np.exp(-2j * math.pi * dz_um * (1.0 / lam - np.sqrt(arg)))
        h[f2 > 1.0 / lam**2] = 0.0
        return h.astype(np.complex64)

    def _pupil(self) -> np.ndarray | None:
        if self._relay.na is None:
            return None
        if self._pupil_cache is None:
            mm = self._mask
            ny, nx = mm.fine_shape
            fy = sfft.fftfreq(ny, d=mm.fine_pitch_um)
            fx = sfft.fftfreq(nx, d=mm.fine_pitch_um)
            fc = self._relay.na / self._relay.wavelength_um
            self._pupil_cache = ((fy * fy)[:, None] + (fx * fx)[None, :]) <= fc * fc
        return self._pupil_cache

    def _band(self):
        """Pupil bounding box on the fine FFT grid: rows ``iy``, cols ``ix``, the pupil
        on it, and the 1-D DFTs of one pixel's aperture at those frequencies."""
        if self._band_cache is None:
            pupil = self._pupil()
            iy = np.flatnonzero(pupil.any(axis=1))
            ix = np.flatnonzero(pupil.any(axis=0))
            ny, nx = self._mask.fine_shape
            ap = self._slm.aperture(self._n).astype(np.float64)
            a = np.arange(self._n)

            def dft(k, size):  # sum_a A[a] exp(-2 pi i k a / size)
                return (np.exp(-2j * np.pi * np.outer(k, a) / size) @ ap).astype(np.complex64)

            self._band_cache = (iy, ix, pupil[np.ix_(iy, ix)], dft(iy, ny), dft(ix, nx))
        return self._band_cache

    def _relay_band(self, phase: np.ndarray, rel: _Relayed) -> np.ndarray:
        """The relayed field for a pupil and a pixel-wise constant SLM field.

        The fine field is ``s`` box-upsampled by ``n`` (aperture ``A``), so its DFT is
        ``S[k_y mod R, k_x mod C] A_y(k_y) A_x(k_x)`` with ``S`` the (R, C) DFT of
        ``s``: no fine-grid forward FFT. Only the pupil's bounding box is nonzero,
        so the inverse runs along x on those rows only, then along y (about half a
        full 2-D FFT). Equal to :meth:`_propagate` of :meth:`_slm_fine_field` to
        float32 rounding (tested).
        """
        rows, cols = self.slm_shape
        ny, nx = self._mask.fine_shape
        iy, ix, pup, ay, ax = self._band()
        s = np.empty(phase.shape, np.complex64)
        s.real = np.cos(phase)
        s.imag = np.sin(phase)
        big = sfft.fft2(s, workers=WORKERS)
        spec0 = big[np.ix_(iy % rows, ix % cols)]
        spec0 *= ay[:, None]
        spec0 *= ax[None, :]
        spec0 *= pup
        full = np.zeros((ny, nx), np.complex64)  # one buffer for every plane

        def level(z_l: float) -> np.ndarray:
            spec = spec0.copy()
            if z_l != 0.0:
                h = self._transfer(z_l)
                if isinstance(h, tuple):
                    spec *= h[0][iy][:, None]
                    spec *= h[1][ix][None, :]
                else:
                    spec *= h[np.ix_(iy, ix)]
            part = np.zeros((iy.size, nx), np.complex64)
            part[:, ix] = spec
            full[iy] = sfft.ifft(part, axis=1, workers=WORKERS, overwrite_x=True)
            return sfft.ifft(full, axis=0, workers=WORKERS)  # rows outside iy stay zero

        levels, spacing = self._levels(rel)
        if spacing is None:
            return level(levels[0])
        out = np.zeros((ny, nx), np.complex64)
        for z_l in levels:
            w = self._tent(rel, z_l, spacing)
            if not np.any(w):
                continue
            u_l = level(z_l)
            u_l *= w
            out += u_l
        return out

    def _is_identity(self, rel: _Relayed) -> bool:
        levels, spacing = self._levels(rel)
        return self._relay.na is None and spacing is None and levels[0] == 0.0

    def _tent(self, rel: _Relayed, z_l: float, spacing: float) -> np.ndarray:
        """Blending weight ``max(0, 1 - |dz(x) - z_l| / spacing)`` (float32 fine grid)."""
        y, x = self._plane_um()
        dz_y = (rel.dz0 + rel.gy * y - z_l).astype(np.float32)
        dz_x = (rel.gx * x).astype(np.float32)
        w = np.abs(dz_y[:, None] + dz_x[None, :])
        w *= np.float32(-1.0 / spacing)
        w += np.float32(1.0)
        np.maximum(w, 0.0, out=w)
        return w

    def _propagate(self, field: np.ndarray, rel: _Relayed,
                   transpose: bool = False) -> np.ndarray:
        """Relay: ``U = sum_l w_l P_l field``; with ``transpose``: ``sum_l P_l (w_l field)``.

        ``P_l`` is symmetric (``H(-f) = H(f)`` on the FFT grid), so the second form is
        the transpose of the first (used by the direct spot evaluation). Returns
        ``field`` itself (no copy) when the relay is the identity for this pose.
        """
        if self._is_identity(rel):
            return field
        levels, spacing = self._levels(rel)
        pupil = self._pupil()
        if spacing is None:  # one plane: a shift-invariant transfer function
            spec = sfft.fft2(field, workers=WORKERS)
            if pupil is not None:
                spec *= pupil
            self._apply_transfer(spec, levels[0])
            return sfft.ifft2(spec, workers=WORKERS, overwrite_x=True)
        if transpose:
            acc = np.zeros(field.shape, np.complex64)
            for z_l in levels:
                w = self._tent(rel, z_l, spacing)
                if not np.any(w):
                    continue
                spec = sfft.fft2(field * w, workers=WORKERS, overwrite_x=True)
                self._apply_transfer(spec, z_l)
                acc += spec
            if pupil is not None:
                acc *= pupil
            return sfft.ifft2(acc, workers=WORKERS, overwrite_x=True)
        spec0 = sfft.fft2(field, workers=WORKERS)
        if pupil is not None:
            spec0 *= pupil
        out = np.zeros(field.shape, np.complex64)
        for z_l in levels:
            w = self._tent(rel, z_l, spacing)
            if not np.any(w):
                continue
            spec = spec0.copy()
            self._apply_transfer(spec, z_l)
            u_l = sfft.ifft2(spec, workers=WORKERS, overwrite_x=True)
            u_l *= w
            out += u_l
        return out

    def _apply_transfer(self, spec: np.ndarray, dz_um: float) -> None:
        """In place: ``spec *= H_dz``."""
        if dz_um == 0.0:
            return
        h = self._transfer(dz_um)
        if isinstance(h, tuple):
            spec *= h[1][None, :]
            spec *= h[0][:, None]
        else:
            spec *= h

    # -- SLM field ---------------------------------------------------------------------

    def _slm_fine_field(self, phase: np.ndarray) -> np.ndarray:
        """Box-upsampled SLM field on the fine grid (Eq. 7.15), complex64 (Ny, Nx)."""
        rows, cols = self.slm_shape
        n = self._n
        slm = self._slm
        ap = slm.aperture(n)
        a4 = (ap[:, None] * ap[None, :])[None, :, None, :]
        if slm.crosstalk_px > 0.0:
            from scipy.ndimage import gaussian_filter1d

            ph = np.repeat(np.repeat(phase.astype(np.float32), n, axis=0), n, axis=1)
            sigma = slm.crosstalk_px * n
            ph = gaussian_filter1d(ph, sigma, axis=0, mode="nearest")
            ph = gaussian_filter1d(ph, sigma, axis=1, mode="nearest")
            field = np.empty(ph.shape, np.complex64)
            field.real = np.cos(ph)
            field.imag = np.sin(ph)
            a_full = np.tile(a4[0, :, 0, :], (rows, cols))
            field *= a_full
            if slm.gap_amplitude:
                field += np.float32(slm.gap_amplitude) * (1.0 - a_full)
            return field
        s = np.exp(1j * phase).astype(np.complex64)
        out = np.empty((rows, n, cols, n), np.complex64)
        np.multiply(s[:, None, :, None], a4, out=out)
        if slm.gap_amplitude and slm.fill_factor < 1.0:
            out += (np.float32(slm.gap_amplitude) * (1.0 - a4)).astype(np.complex64)
        return out.reshape(rows * n, cols * n)

    def _phase_of(self, gray) -> np.ndarray:
        return self._slm.gray_to_phase(check_gray(gray, self.slm_shape))

    # -- far field ---------------------------------------------------------------------

    def _spectrum(self, phase: np.ndarray, pose) -> np.ndarray:
        pose = StagePose.coerce(pose)
        if self._band_ok:
            u = self._relay_band(phase, self._defocus(pose))
        else:
            u = self._propagate(self._slm_fine_field(phase), self._defocus(pose))
        u *= self._mask.true_fine(pose)
        ny, nx = self._mask.fine_shape
        shape = (ny * self.pad, nx * self.pad)
        return sfft.fft2(u, s=shape, workers=WORKERS, overwrite_x=True)

    def _scale(self) -> float:
        ny, nx = self._mask.fine_shape
        n = float(ny * nx)
        return self.power_e_per_s * self.drift.factor / (n * n * self.pad**2)

    def far_field(self, gray: np.ndarray, pose=None) -> np.ndarray:
        """Far-field intensity on the (padded) FFT grid, zero order at the centre.

        Parameters
        ----------
        gray : numpy.ndarray
            uint8 (R, C) gray levels.
        pose : StagePose or sequence of 6, optional
            Stage pose (default zero).

        Returns
        -------
        numpy.ndarray
            float64 ``(pad Ny, pad Nx)``, e-/s per grid point; index ``[i, j]`` is
            ``u = ((j - pad Nx // 2) / pad, (i - pad Ny // 2) / pad)``.
        """
        return self.far_field_phase(self._phase_of(gray), pose)

    def far_field_phase(self, phase: np.ndarray, pose=None) -> np.ndarray:
        """:meth:`far_field` for an ideal (unquantised) SLM phase (float (R, C), rad)."""
        phase = check_phase(phase, self.slm_shape)
        spec = self._spectrum(phase, pose)
        inten = spec.real * spec.real + spec.imag * spec.imag
        return sfft.fftshift(inten).astype(np.float64) * self._scale()

    def render(self, gray: np.ndarray, pose=None) -> np.ndarray:
        """Camera irradiance for a displayed gray image and a stage pose.

        Parameters
        ----------
        gray : numpy.ndarray
            uint8 (R, C): SLM gray levels (through the LUT).
        pose : StagePose or sequence of 6, optional
            ``(x_mm, y_mm, z_mm, rx_rad, ry_rad, rz_rad)`` (default zero).

        Returns
        -------
        numpy.ndarray
            float64, camera shape, photo-electrons per second per pixel (no noise;
            current laser drift factor applied).
        """
        return self.render_phase(self._phase_of(gray), pose)

    def render_phase(self, phase: np.ndarray, pose=None) -> np.ndarray:
        """:meth:`render` for an ideal (unquantised) SLM phase (float (R, C), rad)."""
        phase = check_phase(phase, self.slm_shape)
        return self._to_camera(self._spectrum(phase, pose))

    def _to_camera(self, spec: np.ndarray) -> np.ndarray:
        cam = self._camera
        rows, cols = cam.shape
        m = cam.matrix_array
        b = np.asarray(cam.offset)
        pny, pnx = spec.shape
        pad = self.pad
        scale = self._scale()
        # far-field grid index range visible by the camera (with a 2-px border)
        corners = np.array([[-2, -2], [cols + 1, -2], [-2, rows + 1], [cols + 1, rows + 1]],
                           np.float64)
        uc = cam.to_far_field(corners) * pad  # grid units
        jlo = max(int(math.floor(uc[:, 0].min())) - 1, -(pnx // 2))
        jhi = min(int(math.ceil(uc[:, 0].max())) + 1, (pnx - 1) // 2)
        ilo = max(int(math.floor(uc[:, 1].min())) - 1, -(pny // 2))
        ihi = min(int(math.ceil(uc[:, 1].max())) + 1, (pny - 1) // 2)
        out = np.zeros(rows * cols, np.float64)
        if jlo > jhi or ilo > ihi:
            return out.reshape(rows, cols)
        gi = np.arange(ilo, ihi + 1)
        gj = np.arange(jlo, jhi + 1)
        sub = spec[np.ix_(gi % pny, gj % pnx)]
        inten = (sub.real * sub.real + sub.imag * sub.imag).astype(np.float64) * scale
        det = abs(np.linalg.det(m))
        if det <= pad * pad:  # bin: split each grid point over 4 pixel centres
            uy = (gi / pad)[:, None]
            ux = (gj / pad)[None, :]
            cx = (m[0, 0] * ux + m[0, 1] * uy + b[0]).ravel()
            cy = (m[1, 0] * ux + m[1, 1] * uy + b[1]).ravel()
            w = inten.ravel()
            x0 = np.floor(cx)
            y0 = np.floor(cy)
            fx = cx - x0
            fy = cy - y0
            x0 = x0.astype(np.int64)
            y0 = y0.astype(np.int64)
            for dx, dy, ww in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                               (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
                xx = x0 + dx
                yy = y0 + dy
                ok = (xx >= 0) & (xx < cols) & (yy >= 0) & (yy < rows)
                out += np.bincount(yy[ok] * cols + xx[ok], weights=(w * ww)[ok],
                                   minlength=rows * cols)
            return out.reshape(rows, cols)
        # interpolate: sample the intensity at each pixel centre (grid points per pixel)
        yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float64)
        minv = np.linalg.inv(m)
        gx = (minv[0, 0] * (xx - b[0]) + minv[0, 1] * (yy - b[1])) * pad - jlo
        gy = (minv[1, 0] * (xx - b[0]) + minv[1, 1] * (yy - b[1])) * pad - ilo
        h, w_ = inten.shape
        x0 = np.floor(gx).astype(np.int64)
        y0 = np.floor(gy).astype(np.int64)
        fx = gx - x0
        fy = gy - y0
        val = np.zeros((rows, cols), np.float64)
        for dx, dy, ww in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                           (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            xi = x0 + dx
            yi = y0 + dy
            ok = (xi >= 0) & (xi < w_) & (yi >= 0) & (yi < h)
            val[ok] += ww[ok] * inten[yi[ok], xi[ok]]
        return val * (pad * pad / det)

    # -- direct spot evaluation --------------------------------------------------------

    def _spot_kernel(self, pose: StagePose, u0: tuple[float, float]):
        """Cached ``(c, c_gap)`` or fine ``G`` such that the spot amplitude is linear.

        ``A(u0) = sum_x U(x) m(x) e^{-i 2 pi u0 . x} = sum_x s(x) G(x)`` with
        ``G = sum_l P_l(w_l T)``, ``T = m e^{-i 2 pi u0 . x}``; without crosstalk the
        SLM field is piecewise constant, so ``A = sum_p e^{i phi_p} c_p + c_gap`` with
        ``c_p`` the aperture-weighted block sums of ``G``.
        """
        key = (self._mask.version, pose.as_tuple(), u0)
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        mm = self._mask
        ny, nx = mm.fine_shape
        rows, cols = mm.slm_shape
        rel = self._defocus(pose)
        ry = phase_ramp(u0[1], ny, ny)
        rx = phase_ramp(u0[0], nx, nx)
        mtrue = mm.true_fine(pose)
        trivial = self._is_identity(rel)
        if trivial:
            g = mtrue
        else:
            t = mtrue * ry[:, None]
            t *= rx[None, :]
            g = self._propagate(t, rel, transpose=True)
            ry = np.ones(ny, np.complex64)
            rx = np.ones(nx, np.complex64)
        if self._slm.crosstalk_px > 0.0:
            if trivial:
                g = mtrue * ry[:, None]
                g *= rx[None, :]
            val = ("fine", g)
        else:
            c_ap, c_full = block_reduce(g, ry, rx, self._wy, self._wx, self._n, (rows, cols))
            c_gap = complex((c_full - c_ap).sum()) * self._slm.gap_amplitude
            val = ("coef", c_ap, c_gap)
        with self._lock:
            self._cache[key] = val
            while len(self._cache) > (4 if val[0] == "fine" else 64):
                self._cache.popitem(last=False)
        return val

    def spot_amplitude_phase(self, phase: np.ndarray, u0, pose=None) -> complex:
        """Complex far-field amplitude ``A(u0)`` for an ideal SLM phase (unnormalised).

        ``A(u0) = sum_x U(x) m(x) exp(-i 2 pi (ux j/Nx + uy i/Ny))``, the FFT of the
        field behind the mask evaluated at ``u0`` (any real ``u0``, also off-grid).
        """
        phase = check_phase(phase, self.slm_shape)
        pose = StagePose.coerce(pose)
        u0 = check_u0(u0, self._mask.fine_shape)
        kern = self._spot_kernel(pose, u0)
        if kern[0] == "coef":
            s = np.exp(1j * phase)
            return complex(np.sum(s * kern[1]) + kern[2])
        field = self._slm_fine_field(phase)
        return complex(np.dot(field.ravel(), kern[1].ravel()))

    def spot_power(self, gray: np.ndarray, u0, pose=None) -> float:
        """Direct spot evaluation: far-field intensity at ``u0`` without the full FFT.

        Parameters
        ----------
        gray : numpy.ndarray
            uint8 (R, C) gray levels.
        u0 : (float, float)
            Far-field frequency (samples).
        pose : StagePose or sequence of 6, optional
            Stage pose.

        Returns
        -------
        float
            ``power * drift * |A(u0)|^2 / N^2``: e-/s in one (unpadded) far-field
            sample at ``u0``, equal to :meth:`far_field` at that sample for ``pad = 1``.
            The first call for a (pose, u0) costs one pass over the fine grid (plus the
            relay FFTs when defocused); later calls cost O(R C).
        """
        return self.spot_power_phase(self._phase_of(gray), u0, pose)

    def spot_power_phase(self, phase: np.ndarray, u0, pose=None) -> float:
        """:meth:`spot_power` for an ideal (unquantised) SLM phase (float (R, C), rad)."""
        a = self.spot_amplitude_phase(phase, u0, pose)
        ny, nx = self._mask.fine_shape
        n = float(ny * nx)
        return self.power_e_per_s * self.drift.factor * (a.real**2 + a.imag**2) / (n * n)

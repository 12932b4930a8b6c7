"""Holographic display with a random binary-phase scattering mask (Kuo 2020, Ch. 7).

A deterministic, seeded forward model of the bench

    laser -> SLM (8-bit gray -> phase LUT) -> relay (defocus/tilt from the stage pose)
          -> random binary-phase mask (true pose) -> Fourier lens -> camera pixels

returning the camera irradiance in photo-electrons per second per camera pixel, plus
the helpers the mask-alignment procedure needs (phase-conjugated spot patterns, the
LUT inverse, a cheap direct evaluation of one far-field spot and the window
efficiency metric). There is no camera noise here (the simulated camera driver adds
shot and read noise, offsets, saturation); slow laser-power drift is part of the
model (:class:`LaserDrift`, advanced explicitly by the caller).

Image formation (Eq. 7.8 with the relay of Sec. 7.4 and the box upsampling of
Eq. 7.15)::

    s(x) = sum_p [ a(x - x_p) exp(i phi_p) + g (1 - a(x - x_p)) ] R(x - x_p)   (SLM, Eq. 7.15)
    U(x) = P_dz(x) { s }(x)                                  (relay, angular spectrum)
    F(u) = sum_x U(x) m(x) exp(-i 2 pi u . x / N)            (Fourier lens: FFT)
    I_cam = affine-binned |F|^2 * power * drift / (N * N_pad)

with ``R`` the SLM pixel box, ``a`` its fill-factor aperture, ``g`` the gap
amplitude, ``m`` the *true* mask transmission and ``N`` the number of fine samples.

Grids and units
---------------
* SLM: ``slm_shape = (R, C)`` pixels of pitch ``slm_pitch_um`` as imaged onto the mask
  plane by the relay (the relay is nominally designed so that one SLM pixel covers
  exactly ``k x k`` mask pixels; a relay magnification error is part of the mask
  ground truth, ``MaskTransform.magnification``).
* Mask: pixel pitch ``Delta_m = slm_pitch_um / k``; the physical mask is larger than
  the SLM footprint by ``margin`` mask pixels on each side (so that shifts bring in
  new mask content, as on the bench). The dissertation's etendue factor (Eq. 7.10) is
  ``(Delta / Delta_m)^2 = k^2``.
* Fine grid: ``q`` samples per mask pixel, ``n = k q`` per SLM pixel; fine shape
  ``(Ny, Nx) = (R k q, C k q)``, sample pitch ``Delta_m / q``.
* Plane coordinates (mask geometry, distortion, tilt): mask pixels, origin at the
  centre of the SLM footprint (the optical axis), ``x`` along columns, ``y`` along
  rows. Fine sample ``[i, j]`` sits at ``x = (j + 0.5)/q - C k/2``,
  ``y = (i + 0.5)/q - R k/2``.
* Far field: spatial frequencies ``u = (ux, uy)`` in far-field samples (cycles per
  SLM aperture along each axis; the FFT index relative to the zero order). The phase
  ramp of a frequency ``u`` on the fine grid is ``exp(-i 2 pi (ux j / Nx + uy i / Ny))``
  (the FFT convention). The display's field of view (Eq. 7.9) is ``|ux| < C k/2``,
  ``|uy| < R k/2``; the mask-free SLM band is ``|ux| < C/2``, ``|uy| < R/2``.
* Camera: pixel centres at integer ``(x, y) = (col, row)``; far field -> camera through
  the affine ``c = M u + b`` (slmsuite ``SimulatedCamera`` style, :class:`CameraMapping`).

Every 2-vector in this module (``u0``, translations, shifts, camera positions) is in
``(x, y)`` = ``(column, row)`` order; arrays are indexed ``[row, col]``.

Physics checks (docs/protocols.md, "Mask alignment"): with the spot pattern of the
model mask, a true-mask shift ``d`` scales the spot by ``(1-|dx|/k)^2 (1-|dy|/k)^2``
(triangle law), a random SLM phase gives a background of about ``4/(pi N_SLM)`` of
the spot peak, and rotation lowers the spot; these are tested in
``tests/recon/test_optics_holo_display.py``.
"""

from __future__ import annotations

from .basics import gray_to_phase, linear_lut, phase_to_gray
from .components import CameraMapping, LaserDrift, RelayModel, SlmModel
from .mask import MaskModel, MaskTransform, StagePose
from .model import HolographicDisplayModel
from .spot import efficiency, spot_phase

__all__ = [
    "CameraMapping",
    "HolographicDisplayModel",
    "LaserDrift",
    "MaskModel",
    "MaskTransform",
    "RelayModel",
    "SlmModel",
    "StagePose",
    "efficiency",
    "gray_to_phase",
    "linear_lut",
    "phase_to_gray",
    "spot_phase",
]

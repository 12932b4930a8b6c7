"""3D ADMM with 3D TV, l1 and non-negativity on any array-API backend: the volume's plan
for the generic kernel set.

The algorithm of :func:`recon.volume.admm3d` (Kuo 2020, Eq. 4.5 / App. A.3) iteration
for iteration: the loop of every ADMM (:func:`recon.solvers.admm_loop.run_admm`) with
the generic kernel set (:class:`recon.solvers.xp_admm.XpKernels`: q-form splits, v on
the padded plane, w = x, u = the z, y, x forward differences, no wrap in z), and the
exact per-frequency x-update of this module (tridiagonal Thomas solve across depth and
Sherman-Morrison, :func:`recon.volume._admm_kernels3d.admm_xupdate_3d`), vectorised
over the lateral frequencies instead of looped in numba.
"""

from __future__ import annotations

import math

from ..backend import total
from ..solvers.xp_admm import Differences, XpAdmmState, XpPlanBase
from ..xp_operators import XpVolumeConvolution

__all__ = ["DIFFERENCES_3D", "XpVolumeAdmmPlan", "auto3d_extra_bytes", "memory_bytes",
           "x_update"]

#: Psi of a volume (n_z, P0, P1): forward differences along z (no wrap), y and x.
DIFFERENCES_3D = Differences((0, 1, 2), open_axis=0)


def memory_bytes(n_z: int, padded_shape: tuple[int, int], use_tv: bool = True) -> int:
    """Peak device memory of a 3D generic ADMM solve in bytes (an estimate with margin).

    Volumes of ``(n_z, P0, P1)`` float32: x, q_w, the stored dual a_w, with TV three
    q's and three duals, and about six temporaries of the split pass; complex
    half-spectra (about half a float32 volume's elements, twice the bytes): the PSF
    spectra, the batched spectrum of [R, q_v] and the Thomas sweep's two stacks.
    """
    vol = 4 * n_z * padded_shape[0] * padded_shape[1]
    volumes = 3 + (6 if use_tv else 0) + 6
    spectra = 4 * vol * (padded_shape[1] // 2 + 1) / padded_shape[1] * 2
    return int(volumes * vol + spectra)


def auto3d_extra_bytes(n_z: int, padded_shape: tuple[int, int]) -> int:
    """Device memory the automatic 3D weight needs beyond :func:`memory_bytes` (bytes):
    up to 6 volumes (the path's kept estimates, the final solve's best iterate, the
    FISTA final solve's fit measurement) and a second copy of the PSF spectra (the fit
    plan's and the final plan's operators)."""
    vol = 4 * n_z * padded_shape[0] * padded_shape[1]
    return int(6 * vol + 2 * vol * (padded_shape[1] // 2 + 1) / padded_shape[1])


def x_update(xp, spec, h, d_lat, mu1: float, mu2: float, mu3: float):
    """The exact x-update at every lateral frequency (see
    :func:`recon.volume._admm_kernels3d.admm_xupdate_3d`: same pivots, same order).

    Parameters
    ----------
    spec : array, complex64, (n_z + 1, F0, F1)
        R (planes 0..n_z-1) and Qv (plane n_z).
    h : array, complex64, (n_z, F0, F1)
        PSF spectra.
    d_lat : array, float32, (F0, F1)
    mu1, mu2, mu3 : float
        ``mu2 = 0`` without TV.

    Returns
    -------
    array, complex64, (n_z + 1, F0, F1)
        X (planes 0..n_z-1) and ``h^T X`` (plane n_z).
    """
    nz = h.shape[0]
    off = -mu2
    c = mu3 + mu2 * d_lat
    qv = spec[nz, ...]
    ys, gs, cps = [], [], []
    e_prev = None
    for k in range(nz):
        last = k == nz - 1
        hc = xp.conj(h[k, ...])
        r = spec[k, ...] + mu1 * hc * qv
        if k == 0:
            e = c
        else:
            e = c - e_prev * cps[k - 1]  # c + mu2 e_{k-1} / m_{k-1}
        inv = 1.0 / (e if last else e + mu2)
        if k == 0:
            ys.append(r * inv)
            gs.append(hc * inv)
        else:
            ys.append((r - off * ys[k - 1]) * inv)
            gs.append((hc - off * gs[k - 1]) * inv)
        e_prev = e
        cps.append(off * inv)
    s1 = h[nz - 1, ...] * ys[nz - 1]
    s2 = xp.real(h[nz - 1, ...] * gs[nz - 1])
    for k in range(nz - 2, -1, -1):
        ys[k] = ys[k] - cps[k] * ys[k + 1]
        gs[k] = gs[k] - cps[k] * gs[k + 1]
        s1 = s1 + h[k, ...] * ys[k]
        s2 = s2 + xp.real(h[k, ...] * gs[k])
    s1 = s1 * (1.0 / (1.0 + mu1 * s2))
    return xp.stack([*(ys[k] - (mu1 * s1) * gs[k] for k in range(nz)), s1])


class XpVolumeAdmmPlan(XpPlanBase):
    """:class:`recon.volume.VolumeAdmmPlan` on the device of ``like``.

    Parameters
    ----------
    plan : VolumeAdmmPlan
        The NumPy path's plan (operator, lateral ``|F Psi|^2``).
    like : array
        Any array of the target backend and device.

    Attributes
    ----------
    plan : VolumeAdmmPlan
    op : VolumeConvolutionOperator
        ``plan.op`` (validation, crop, shapes).
    xop : XpVolumeConvolution
        The operator on the device (its PSF spectra copied there).
    d_lat : array, float32, (P0, P1 // 2 + 1)
    prior : Prior
        The u split's prior (:mod:`recon.priors`; default 3D TV).
    differences : Differences or IdentitySplit
        :data:`DIFFERENCES_3D`, or ``IDENTITY`` for a prior on the volume itself
        (plane by plane).

    Raises
    ------
    ReconInputError
        An unknown prior.
    """

    differences = DIFFERENCES_3D

    def __init__(self, plan, like, prior=None):
        self.plan, self.op = plan, plan.op
        self.xop = XpVolumeConvolution(plan.op, like)
        self.xp = self.xop.xp
        self.d_lat = self.xop.asarray(plan.d_lat)
        self.adopt_prior(prior)

    def inverse_denominator(self, mu, use_tv: bool) -> None:
        """None: the x-update solves per lateral frequency (no fixed denominator)."""
        return None

    def x_update(self, state: XpAdmmState):
        """R = mu2 Psi^T q_u + mu3 q_w, one batched rfft2 of [R, q_v], the exact solve
        per lateral frequency (:func:`x_update`), one batched irfft2: ``(x, M x)``."""
        xp, nz = self.xp, self.op.n_z
        mu1, mu2, mu3 = state.mu
        rhs = mu3 * state.qw
        if state.use_tv:
            rhs = rhs + mu2 * self.differences.adjoint(xp, state.qu)
        spec = xp.fft.rfftn(xp.concat([rhs, state.qv[None, ...]], axis=0), axes=(-2, -1))
        if state.use_tv and self.prior.identity_split:  # u = x: mu2 joins mu3, no coupling
            spec = x_update(xp, spec, self.xop.spectra, self.d_lat, mu1, 0.0, mu3 + mu2)
        else:
            spec = x_update(xp, spec, self.xop.spectra, self.d_lat, mu1,
                            mu2 if state.use_tv else 0.0, mu3)
        stack = xp.fft.irfftn(spec, s=self.xop.padded_shape, axes=(-2, -1))
        return stack[:nz, ...], stack[nz, ...]

    def objective(self, b, x, *, tv: float, l1: float, b_norm: float) -> tuple[float, float]:
        """Objective of Eq. 4.5 at ``x`` and its relative data residual against ``b``
        (:meth:`recon.volume.VolumeAdmmPlan.objective` on the device)."""
        if self.prior.identity_split:  # the prior's term instead of 3D TV's
            final, data_sq = _final_objective(self.xp, self.xop, x, b, 0.0, l1)
            final += tv * self.prior.value(self.xp, x, (x,)) if tv > 0 else 0.0
        else:
            final, data_sq = _final_objective(self.xp, self.xop, x, b, tv, l1)
        return final, math.sqrt(data_sq) / b_norm


def _final_objective(xp, xop, x, b, tv: float, l1: float) -> tuple[float, float]:
    """:func:`recon.volume.fista.final_objective` on the device: the objective and the
    squared data residual."""
    r = xop.forward(x) - b
    data_sq = total(xp, r * r)
    final = 0.5 * data_sq
    if tv:
        final += tv * sum(total(xp, xp.abs(d)) for d in DIFFERENCES_3D.apply(xp, x))
    if l1:
        final += l1 * total(xp, xp.abs(x))
    return final, data_sq

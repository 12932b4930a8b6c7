"""The linearized ADMM of the spatially varying models on any array-API backend.

:func:`recon.spatial.spatial_admm` given a measurement of another backend (CuPy,
PyTorch) runs the ADMM loop of every ADMM with the generic kernel set
(:class:`recon.solvers.xp_admm.XpAdmmPlan`: the same splits and residual balancing)
with this module's x-update, the preconditioned
gradient step of :mod:`recon.spatial.admm` (Deng & Yin 2016) written with whole-array
operations on :class:`~recon.spatial.xp_operator.XpSpatialConvolution`:

    g = mu1 M^T (M x - q_v) + mu2 Psi^T (Psi x - q_u) + mu3 (x - q_w),
    x+ = x - F^-1 (F g / P),  P = mu1 rho + mu2 |F Psi|^2 + mu3.

Cost per iteration ``2K + 4`` transforms, as the NumPy path's.
"""

from __future__ import annotations

__all__ = ["linearized_x_update"]


def linearized_x_update(xop, x, mx, q, mu, inv_den, use_tv: bool):
    """One preconditioned gradient step on the ADMM x-subproblem
    (:meth:`recon.spatial.SpatialAdmmPlan.x_update`, :func:`~recon.spatial._kernels.
    linearized_gradient_2d`).

    Parameters
    ----------
    xop : XpSpatialConvolution
        2D model.
    x, mx : arrays, float32, (P0, P1)
        The iterate and ``M x`` (uncropped).
    q : (qv, qux, quy, qw)
        The splits' q's.
    mu : (mu1, mu2, mu3)
    inv_den : array, float32, (P0, P1 // 2 + 1)
        ``1 / P`` (module docstring).
    use_tv : bool

    Returns
    -------
    (x, mx) : arrays, float32, (P0, P1)
        The new iterate and its ``M x`` (1 rfft2 + ``K`` irfft2, 1 rfft2 + 1 irfft2,
        ``K`` rfft2 + 1 irfft2).
    """
    xp = xop.xp
    qv, qux, quy, qw = q
    mu1, mu2, mu3 = mu
    g = mu1 * xop.correlate_full(mx - qv) + mu3 * (x - qw)
    if use_tv:  # Psi^T (Psi x - q_u), circular forward differences
        rx = (xp.roll(x, -1, axis=1) - x) - qux
        ry = (xp.roll(x, -1, axis=0) - x) - quy
        g = g + mu2 * ((xp.roll(rx, 1, axis=1) - rx) + (xp.roll(ry, 1, axis=0) - ry))
    step = xp.fft.irfftn(xp.fft.rfftn(g, axes=(-2, -1)) * inv_den, s=xop.padded_shape,
                         axes=(-2, -1))
    x = x - step
    return x, xop.convolve_full(x)

"""Fused numba kernels of the spatially varying models (Eq. 5.5): the weighting of
object planes by the kernels' weight maps, parallel over rows, one pass each.
C-contiguous float32, as :mod:`recon.volume._kernels3d`."""

from __future__ import annotations

from ..jit import PARALLEL_FAST, njit, prange


@njit(**PARALLEL_FAST)
def weighted_planes(out, x, weights, planes):
    """``out[k] = x[planes[k]] * weights[k]`` (the ``diag(W_j) y`` of Eq. 5.5)."""
    n, rows, cols = out.shape
    for i in prange(rows):
        for k in range(n):
            z = planes[k]
            for j in range(cols):
                out[k, i, j] = x[z, i, j] * weights[k, i, j]


@njit(**PARALLEL_FAST)
def accumulate_weighted(out, g, weights, planes):
    """``out[planes[k]] += g[k] * weights[k]`` (the adjoint's ``diag(W_j)``)."""
    n, rows, cols = g.shape
    for i in prange(rows):
        for k in range(n):
            z = planes[k]
            for j in range(cols):
                out[z, i, j] += g[k, i, j] * weights[k, i, j]



@njit(**PARALLEL_FAST)
def linearized_gradient_2d(x, qux, quy, qw, g, mu1, mu2, mu3, use_tv):
    """The gradient of the ADMM x-subproblem at ``x``, in place in ``g``.

    On entry ``g`` holds ``M^T (M x - q_v)``; on return
    ``g = mu1 g + mu2 Psi^T (Psi x - q_u) + mu3 (x - q_w)`` (forward differences,
    circular, as :func:`recon._kernels.admm_rhs_2d`): what the linearized x-update of
    :mod:`recon.spatial.admm` preconditions.
    """
    n0, n1 = x.shape
    for i in prange(n0):
        im = i - 1 if i > 0 else n0 - 1
        ip = i + 1 if i < n0 - 1 else 0
        for j in range(n1):
            jm = j - 1 if j > 0 else n1 - 1
            jp = j + 1 if j < n1 - 1 else 0
            xc = x[i, j]
            val = mu1 * g[i, j] + mu3 * (xc - qw[i, j])
            if use_tv:
                rx = (x[i, jp] - xc) - qux[i, j]
                rx_m = (xc - x[i, jm]) - qux[i, jm]
                ry = (x[ip, j] - xc) - quy[i, j]
                ry_m = (xc - x[im, j]) - quy[im, j]
                val += mu2 * ((rx_m - rx) + (ry_m - ry))
            g[i, j] = val

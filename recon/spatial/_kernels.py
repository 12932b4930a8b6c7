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

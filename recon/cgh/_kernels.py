"""Fused, multithreaded grid kernels for the hologram optimiser's hot loop (numba).

Each kernel makes one pass over the full mask grid (``Gy x Gx``, e.g. 2160 x 3840)
so an iteration costs little more than its FFTs. The SLM field is upsampled on the
fly (``w[i // k, j // k]``), so the upsampled field of Eq. 7.15 is never stored and
no exponential is evaluated on the full grid. Reductions accumulate in float64.
Reference formulas are in :mod:`recon.cgh.optimize`; the tests check them
against plain numpy.
"""

from __future__ import annotations

import numpy as np

from ..jit import PARALLEL, njit, prange


@njit(**PARALLEL)
def upsample_multiply(w, mask, k, out):  # pragma: no cover - jitted
    """``out[i, j] = mask[i, j] * w[i // k, j // k]`` (box upsampling, Eq. 7.15, times m)."""
    gy, gx = out.shape
    for i in prange(gy):
        r = i // k
        for j in range(gx):
            out[i, j] = mask[i, j] * w[r, j // k]


@njit(**PARALLEL)
def bin_conj_multiply(x, mask, k, out):  # pragma: no cover - jitted
    """``out[r, c] = sum over the k x k block of conj(mask) * x`` (U^T diag(m*), Eq. A.9)."""
    rows, cols = out.shape
    for r in prange(rows):
        for c in range(cols):
            out[r, c] = 0
        for a in range(k):
            i = r * k + a
            for c in range(cols):
                acc = out[r, c]
                for e in range(k):
                    j = c * k + e
                    acc += np.conj(mask[i, j]) * x[i, j]
                out[r, c] = acc


@njit(**PARALLEL)
def _residual_pass(a, za, b, zb, z, target, sigma, out, combine):  # pragma: no cover - jitted
    """One pass of :func:`residual` (``combine`` false) or :func:`combine_residual`."""
    gy, gx = out.shape
    rr = 0.0
    ri = 0.0
    for i in prange(gy):
        acc_rr = 0.0
        acc_ri = 0.0
        for j in range(gx):
            if combine:
                v = a * za[i, j] + b * zb[i, j]
                z[i, j] = v
            else:
                v = z[i, j]
            inten = v.real * v.real + v.imag * v.imag
            r = sigma * inten - target[i, j]
            out[i, j] = r
            acc_rr += r * r
            acc_ri += r * inten
        rr += acc_rr
        ri += acc_ri
    return rr, ri


def combine_residual(a, za, b, zb, z, target, sigma, out):
    """``z = a za + b zb`` and :func:`residual` of it, in one pass; same returns."""
    return _residual_pass(a, za, b, zb, z, target, sigma, out, True)


def residual(z, target, sigma, out):
    """``out = sigma |z|^2 - target``; returns ``(sum out^2, sum out * |z|^2)``.

    ``sigma`` must have the targets' precision (float32 keeps the pass in float32).
    """
    return _residual_pass(sigma, z, sigma, z, z, target, sigma, out, False)


@njit(**PARALLEL)
def spectrum_filter(spec, h2, t_spec, n_cols, apply, cross):  # pragma: no cover - jitted
    """Parseval sums of an rfft2 spectrum against the squared filter ``h2``.

    Returns ``(sum' h2 |spec|^2, sum' h2 Re(conj(spec) t_spec))`` (the second only
    with ``cross``, else 0) with the Hermitian
    column weights of a real FFT (2 for the interior columns, 1 for column 0 and,
    for an even number ``n_cols`` of real columns, the last); divide by the number
    of grid samples for the real-space inner products. With ``apply`` the spectrum
    is multiplied by ``h2`` in place (``P^T P`` in Fourier space).
    """
    ny, nx = spec.shape
    last = nx - 1 if n_cols % 2 == 0 else -1
    e = 0.0
    c = 0.0
    for i in prange(ny):
        acc_e = 0.0
        acc_c = 0.0
        for j in range(nx):
            wgt = 1.0 if (j == 0 or j == last) else 2.0
            v = spec[i, j]
            h = h2[i, j]
            acc_e += wgt * h * (v.real * v.real + v.imag * v.imag)
            if cross:
                t = t_spec[i, j]
                acc_c += wgt * h * (v.real * t.real + v.imag * t.imag)
            if apply:
                spec[i, j] = v * h
        e += acc_e
        c += acc_c
    return e, c


@njit(**PARALLEL)
def multiply_real(spec, h):  # pragma: no cover - jitted
    """In place: ``spec *= h`` (real ``h``, same shape)."""
    ny, nx = spec.shape
    for i in prange(ny):
        for j in range(nx):
            spec[i, j] = spec[i, j] * h[i, j]


@njit(**PARALLEL)
def weight_filtered(rf, c2, pt):  # pragma: no cover - jitted
    """In place ``rf <- c2 * rf``; returns ``(sum c2 rf^2, sum c2 rf pt)`` (old rf)."""
    gy, gx = rf.shape
    e = 0.0
    c = 0.0
    for i in prange(gy):
        acc_e = 0.0
        acc_c = 0.0
        for j in range(gx):
            v = rf[i, j]
            wv = c2[i, j] * v
            acc_e += wv * v
            acc_c += wv * pt[i, j]
            rf[i, j] = wv
        e += acc_e
        c += acc_c
    return e, c


@njit(**PARALLEL)
def weighted_sum(rf, c2):  # pragma: no cover - jitted
    """``sum c2 rf^2`` (float64 accumulation)."""
    gy, gx = rf.shape
    e = 0.0
    for i in prange(gy):
        acc = 0.0
        for j in range(gx):
            v = rf[i, j]
            acc += c2[i, j] * v * v
        e += acc
    return e

"""Shared numba set-up and inlined building blocks of the recon kernels.

Every numba kernel module of :mod:`recon` (:mod:`recon._kernels`,
:mod:`recon.volume._kernels3d`, :mod:`recon.volume._admm_kernels3d`,
:mod:`recon.cgh._kernels`, :mod:`recon.optics._raytrace`,
:mod:`recon.optics.holo_display.basics`) imports numba through this module, so:

* the threading policy is set once, before numba's OpenMP runtime starts:
  ``OMP_WAIT_POLICY=PASSIVE`` (unless the user set it). numba's workers then
  sleep between parallel regions instead of spinning; spinning workers steal
  the cores from scipy.fft's workers and double the FFT time, and every speed
  target is stated as a ratio to that FFT floor;
* the compile flags are the same everywhere: :data:`PARALLEL` (parallel,
  cached, GIL released) and :data:`PARALLEL_FAST`, which adds the fast-math
  flags that let LLVM vectorise reductions while keeping NaN/inf semantics
  (divergence still shows as NaN in the objective);
* the per-element ADMM updates (:func:`shrink_split`, :func:`data_split`) and
  the clip of the Haar-shift TV prox (:func:`clip`) exist once. They are
  compiled with ``inline="always"``, so a kernel that calls them runs the same
  machine code as one that spells them out.

ADMM splits are kept in q-form (Kuo 2020, Eq. 4.5 and App. A.3; Boyd et al.
2011, Sec. 3.1.1 scaled form): for a split ``z = G x`` with scaled dual ``a``,
only ``q = z - a`` is stored between iterations, and one update is
``a_new = G x - q_old``, ``z_new = prox(G x + a_new)``, ``q_new = z_new - a_new``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from numba import get_num_threads as thread_count  # noqa: E402
from numba import njit, prange, set_num_threads  # noqa: E402

__all__ = ["PARALLEL", "PARALLEL_FAST", "balance_terms", "clip", "data_split", "njit",
           "prange", "set_num_threads", "shrink_split", "thread_count"]

#: numba flags of the parallel kernels: threads over ``prange``, on-disk cache,
#: GIL released (the acquisition thread keeps running during a solve).
PARALLEL = dict(parallel=True, cache=True, nogil=True)

#: :data:`PARALLEL` plus fast-math reassociation/contraction (no ``nnan``/``ninf``:
#: NaN and inf still propagate), used by the solver kernels.
PARALLEL_FAST = dict(PARALLEL, fastmath={"reassoc", "contract", "nsz", "arcp"})


@njit(inline="always")
def clip(d, t):
    """``min(max(d, -t), t)``: ``d`` clipped to [-t, t] (``t >= 0``).

    ``d - clip(d, t)`` is the soft threshold of ``d`` at ``t`` (the prox of
    ``t |.|``); the Haar-shift TV prox of App. A.1 clips half-differences.
    """
    return min(max(d, -t), t)


@njit(inline="always")
def shrink_split(g, q, thr, lo):
    """One element of a shrinkage split, in q-form.

    ``a = g - q``, ``z = max(soft(g + a, thr), lo)``, ``q_new = z - a``. With
    ``thr = 0, lo = 0`` the prox is the projection on ``x >= 0``; with
    ``lo = -inf`` the soft threshold alone (the TV and l1 splits).

    Parameters
    ----------
    g : float32
        ``(G x)`` at this element.
    q : float32
        Stored ``z - a`` of the previous iteration.
    thr, lo : float32
        Soft threshold and lower bound of the prox.

    Returns
    -------
    q_new, a, z : float32
        New ``q``, new scaled dual and new split variable (for :func:`balance_terms`).
    """
    a = g - q
    t = g + a
    z = max(t - clip(t, thr), lo)
    return z - a, a, z


@njit(inline="always")
def data_split(g, q, w, b, mu1):
    """One element of the data split ``v = M x`` (Eq. 4.5, v-update), in q-form.

    ``a = g - q``, ``v = (w b + mu1 t) / (w^2 + mu1)`` with ``t = g + a``: the
    prox of ``1/2 ||w C v - b||^2`` with ``w`` and ``b`` zero-padded off the
    sensor (there ``v = t``); ``q_new = v - a``.

    Parameters
    ----------
    g, q : float32
        As in :func:`shrink_split`, with ``g = (M x)`` on the padded grid.
    w, b : float32
        Sensor weight and (pre-weighted) measurement at this element, 0 off the sensor.
    mu1 : float32
        Penalty of the split.

    Returns
    -------
    q_new, a, z, res2 : float32
        New ``q``, new dual, new split variable and ``(w g - b)^2`` (the data misfit).
    """
    a = g - q
    t = g + a
    z = (w * b + mu1 * t) / (w * w + mu1)
    r = w * g - b
    return z - a, a, z, r * r


@njit(inline="always")
def balance_terms(g, q, a, z, a_old):
    """Residual-balancing terms of one split element (see
    :func:`recon.solvers.admm.balanced_penalty`).

    Parameters
    ----------
    g, q : float32
        ``(G x)`` and the ``q`` the update started from.
    a, z : float32
        New dual and split variable (from :func:`shrink_split` / :func:`data_split`).
    a_old : float32
        The dual stored by the previous iteration (so ``z_old = q + a_old``).

    Returns
    -------
    r2, s2, n2, a2 : float32
        ``(a - a_old)^2`` (primal residual), ``(z - z_old)^2`` (dual residual),
        ``max(g^2, z^2)`` and ``a^2`` (their scales).
    """
    d = a - a_old
    e = z - q - a_old
    return d * d, e * e, max(g * g, z * z), a * a

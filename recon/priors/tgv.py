"""Second-order total generalised variation as the ADMM's denoising step."""

from __future__ import annotations

import math

import numpy as np

from ..errors import ReconInputError
from . import _kernels as k
from .base import Prior, on_host, put_like

__all__ = ["TgvPrior"]


class TgvPrior(Prior):
    """Second-order TGV (Bredies, Kunisch & Pock 2010): g(x) = min_w a1 ||D+ x - w||_{2,1}
    + a0 ||E w||_{F,1}, with a1 = 1 and a0 = ``ratio`` (the prior's weight scales both).

    TGV charges a piecewise-affine image only at its kinks, where TV charges every
    step of a ramp and so turns smooth shading into flat steps (TV's staircase).

    The u split is u = x (G_u the identity, as :class:`~recon.priors.WaveletPrior`'s),
    so the split needs no auxiliary field w in the loop: the u-update is the TGV
    denoising prox, z = argmin_z 0.5 ||z - t||^2 + (weight / mu2) g(z), solved
    inexactly by ``iterations`` primal-dual iterations (Chambolle & Pock 2011,
    "A first-order primal-dual algorithm for convex problems with applications to
    imaging", J. Math. Imaging Vis. 40, Algorithm 1, as in Bredies et al. 2010 Sec. 5;
    steps tau = sigma = 1 / sqrt(12)), each two fused numba passes over the plane
    (``recon.priors._kernels``). Each step continues from the primal-dual state
    (z, w and the duals) the last step left on a plane of that shape: the inner
    solver warm-started at the previous ADMM iterate's, as inexact ADMM's inner
    solvers are (Eckstein & Bertsekas 1992), so successive steps converge to the exact
    prox as the ADMM's input settles (from a cold start, 20 iterations stay about 40 %
    of the correction away from it; warm, 30 steps of 20 agree with 3000 iterations).
    A prior made by name (:func:`~recon.priors.prior_of`) is new for every solve;
    :meth:`reset` forgets the state of one that is reused. Applied over the last two
    axes (a volume's planes each); circular boundaries, as the padded grid's.

    :meth:`value` is a1 ||D+ x - w|| + a0 ||E w|| with w the field of the last
    step on a plane of that shape (zero before any): TGV(x) at the iterate the step
    returned, an upper bound on it elsewhere (the history's objective term).

    Parameters
    ----------
    ratio : float
        a0 / a1 (default 2, the value of Bredies et al. 2010's and Knoll et al. 2011's
        experiments); > 0.
    inner_iterations : int
        Primal-dual iterations of each prox step (default 20; the inner loop, not the
        ADMM's iterations); >= 1.

    Raises
    ------
    ReconInputError
        ``ratio`` not a positive finite number or ``inner_iterations`` < 1.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> ramp = np.tile(np.linspace(0, 1, 64, dtype=np.float32), (32, 1))
    >>> noisy = ramp + 0.05 * rng.standard_normal(ramp.shape).astype(np.float32)
    >>> (z,) = TgvPrior(inner_iterations=200).prox(np, (noisy,), 0.05, 1.0)
    >>> bool(np.abs(z - ramp)[:, 4:-4].mean() < 0.5 * np.abs(noisy - ramp).mean())
    True
    """

    name = "tgv"
    identity_split = True

    def __init__(self, ratio: float = 2.0, inner_iterations: int = 20):
        if not (math.isfinite(ratio) and ratio > 0) or int(inner_iterations) < 1:
            raise ReconInputError(f"TGV ratio {ratio} / inner_iterations {inner_iterations}: "
                                  "the ratio a0/a1 > 0 (e.g. 2), inner_iterations >= 1")
        self.ratio, self.inner_iterations = float(ratio), int(inner_iterations)
        self._state: dict = {}  # array shape -> per plane the primal-dual state

    def reset(self) -> None:
        """Forget the warm-start state: the next step starts cold (z = t, w = 0)."""
        self._state.clear()

    def denoise(self, t: np.ndarray, lam: float, state: tuple | None = None) -> tuple:
        """The TGV denoising step of one plane.

        Parameters
        ----------
        t : ndarray, float32, (n0, n1)
            The noisy plane (C-contiguous).
        lam : float
            The weight of g (> 0): a1 = lam, a0 = lam * ratio.
        state : tuple of 11 ndarrays, optional
            A previous step's state on a plane of this shape (warm start, updated in
            place); default a cold start z = t, w = 0, zero duals.

        Returns
        -------
        state : tuple of ndarray, float32, (n0, n1)
            ``(z, w1, w2, ...)``: the denoised plane, its vector field w (x and y
            components), then the extrapolated points and the duals.
        """
        f32 = np.float32
        if state is None:
            zeros = [np.zeros_like(t) for _ in range(9)]
            state = (t.copy(), zeros[0], zeros[1], t.copy(), *zeros[2:])
        x, w1, w2, xb, w1b, w2b, p1, p2, q11, q22, q12 = state
        step = f32(1.0 / math.sqrt(k.TGV_NORM_SQ))
        r1, r0 = f32(lam), f32(lam * self.ratio)
        for _ in range(self.inner_iterations):
            k.tgv_dual_step(xb, w1b, w2b, p1, p2, q11, q22, q12, step, r1, r0)
            k.tgv_primal_step(x, w1, w2, xb, w1b, w2b, p1, p2, q11, q22, q12, t, step)
        return state

    def prox(self, xp, t: tuple, weight: float, mu2: float) -> tuple:
        (s,) = t
        lam = weight / mu2
        if lam <= 0:
            return (s,)
        a = on_host(s)
        planes = a.reshape((-1, *a.shape[-2:]))
        states = self._state.get(a.shape) or [None] * len(planes)
        states = [self.denoise(np.ascontiguousarray(plane), lam, st)
                  for plane, st in zip(planes, states, strict=True)]
        self._state[a.shape] = states
        out = np.stack([st[0] for st in states]).reshape(a.shape)
        return (put_like(xp, out.copy(), s),)

    def value(self, xp, x, g: tuple) -> float:
        a = on_host(x)
        planes = a.reshape((-1, *a.shape[-2:]))
        states = self._state.get(a.shape)
        total = 0.0
        for n, plane in enumerate(planes):
            plane = np.ascontiguousarray(plane)
            w1, w2 = states[n][1:3] if states else (np.zeros_like(plane),) * 2
            total += k.tgv_upper_value(plane, w1, w2, 1.0, self.ratio)
        return float(total)

    def record(self) -> dict:
        # the record's key stays "iterations" (records already written say so)
        return {"prior": self.name, "ratio": self.ratio, "iterations": self.inner_iterations}

    def __repr__(self) -> str:
        return f"TgvPrior(ratio={self.ratio:g}, inner_iterations={self.inner_iterations})"

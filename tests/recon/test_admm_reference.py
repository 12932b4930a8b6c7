"""2D ADMM against a plain numpy implementation of its documented iteration.

:func:`recon.solvers.admm` runs the splits in q-form through fused numba passes
(:mod:`recon._kernels`) and FFTs plane by plane; the reference below spells out the
textbook scaled-dual ADMM of its docstring (Eq. 4.5 / App. A.3 in 2D, Boyd et al.
2011 Sec. 3.1.1) in float64: the iterates must agree to float32 rounding. Also:
the fused right-hand side changes nothing (balancing on), and automatic stopping
ends a solve at the first iteration its documented condition holds.
"""

from __future__ import annotations

import numpy as np
import pytest

from recon.auto import Stopping
from recon.solvers import AdmmPenalty, admm
from recon.solvers.admm import AdmmPlan, AdmmState, difference_power, run_admm


def _soft(t, thr):
    return np.sign(t) * np.maximum(np.abs(t) - thr, 0.0)


def reference_admm(op, b, *, iterations, tv, l1, mu):
    """Scaled-dual ADMM with crop, TV, l1 and non-negativity splits, float64.

    Per iteration: z-updates at the current x (v: (w b + mu1 t) / (w^2 + mu1), u: soft
    threshold tau / mu2, w: max(t - l1 / mu3, 0), t = G x + a), the exact x-update
    in Fourier space, then the dual updates a += G x - z. Returns the estimate
    max(x, 0) and the objective 1/2 ||D M x - b||^2 + tau TV(x) + l1 sum(max(x, 0)) of
    each iterate entering an iteration.
    """
    shape = op.padded_shape
    mu1, mu2, mu3 = mu
    h = op.spectrum.astype(np.complex128)
    wp = np.zeros(shape)
    bp = np.zeros(shape)
    wp[op.crop] = op.sensor_weights
    bp[op.crop] = b

    def fwd(x):
        return np.fft.irfft2(h * np.fft.rfft2(x), shape)

    def grad(x):
        return np.roll(x, -1, axis=1) - x, np.roll(x, -1, axis=0) - x

    x = np.zeros(shape)
    zv, zux, zuy, zw = (np.zeros(shape) for _ in range(4))
    av, aux, auy, aw = (np.zeros(shape) for _ in range(4))
    den = mu1 * np.abs(h) ** 2 + mu2 * difference_power(shape) + mu3
    objective = []
    for _ in range(iterations):
        mx = fwd(x)
        gx, gy = grad(x)
        # the dual step of the previous iteration (zero at the start: x, z, a all 0)
        av += mx - zv
        aux += gx - zux
        auy += gy - zuy
        aw += x - zw
        objective.append(0.5 * np.sum((wp * mx - bp) ** 2)
                         + tv * (np.abs(gx).sum() + np.abs(gy).sum())
                         + l1 * np.maximum(x, 0.0).sum())
        zv = (wp * bp + mu1 * (mx + av)) / (wp * wp + mu1)
        zux = _soft(gx + aux, tv / mu2)
        zuy = _soft(gy + auy, tv / mu2)
        zw = np.maximum(x + aw - l1 / mu3, 0.0)
        qux, quy = zux - aux, zuy - auy
        psi_t = (np.roll(qux, 1, axis=1) - qux) + (np.roll(quy, 1, axis=0) - quy)
        rhs = (mu1 * np.conj(h) * np.fft.rfft2(zv - av)
               + np.fft.rfft2(mu2 * psi_t + mu3 * (zw - aw)))
        x = np.fft.irfft2(rhs / den, shape)
    return np.maximum(x, 0.0), np.asarray(objective)


@pytest.mark.parametrize("tv,l1", [(1e-3, 0.0), (3e-4, 2e-3)])
def test_admm_iterates_equal_the_numpy_reference(conv_problem, tv, l1):
    p = conv_problem
    mu = (3e-3, 2e-3, 4e-3)
    got = admm(p.op, p.b_noisy, iterations=40, tv=tv, l1=l1,
               penalty=AdmmPenalty(mu=mu, balance=False))
    x_ref, obj_ref = reference_admm(p.op, p.b_noisy, iterations=40, tv=tv, l1=l1, mu=mu)
    scale = float(np.abs(x_ref).max())
    np.testing.assert_allclose(got.x, x_ref, rtol=0, atol=2e-5 * scale)
    np.testing.assert_allclose(got.history.objective, obj_ref, rtol=2e-5)


class _SeparateRhsPlan(AdmmPlan):
    """The x-update forms its right-hand side in its own pass (as before the fusion)."""

    rhs_in_split = False


@pytest.mark.parametrize("tv", [1e-3, 0.0])
def test_fused_right_hand_side_changes_nothing(conv_problem, tv):
    """Balancing on (mode-1 and mode-2 iterations included): bit for bit the same."""
    p = conv_problem
    penalty = AdmmPenalty(mu=(1e-2, 1e-4, 1e-1))  # far off, so balancing acts
    runs = []
    for plan in (AdmmPlan.of(p.op), _SeparateRhsPlan.of(p.op)):
        state = AdmmState.zeros(plan, penalty.initial(), tv > 0)
        runs.append(run_admm(plan, p.b_noisy, state, iterations=60, tv=tv, penalty=penalty))
    fused, separate = runs
    assert len(fused.history.extra["mu"]) > 2  # the penalties moved
    np.testing.assert_array_equal(fused.x, separate.x)
    assert fused.history.extra["mu"] == separate.history.extra["mu"]
    np.testing.assert_allclose(fused.history.objective, separate.history.objective,
                               rtol=1e-6)


def test_stopping_happens_at_the_documented_condition(conv_problem):
    """Stopping(window, tolerance) ends the solve after the first iteration k whose
    data term differs from that of k - window by less than tolerance * target."""
    p = conv_problem
    rule = Stopping(window=10, tolerance=1e-3)
    target = 0.5 * p.b_noisy.size * 1e-4
    b_norm = float(np.linalg.norm(p.b_noisy))
    full = admm(p.op, p.b_noisy, iterations=300, tv=1e-3)
    data = [0.5 * (r * b_norm) ** 2 for r in full.history.data_residual]
    first = next(k for k in range(rule.window, len(data))
                 if abs(data[k - rule.window] - data[k]) < rule.tolerance * target)
    stopped = admm(p.op, p.b_noisy, iterations=300, tv=1e-3,
                   stop=rule.hook(target, b_norm))
    assert stopped.params["iterations_used"] == first + 1 < 300
    assert stopped.history.data_residual == full.history.data_residual[:first + 1]

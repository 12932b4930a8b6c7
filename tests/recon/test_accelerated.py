"""The accelerated proximal-gradient loop every FISTA shares (recon.solvers.accelerated),
checked against a plain numpy FISTA / momentum gradient descent written from Beck &
Teboulle 2009 and O'Donoghue & Candes 2015, on a small non-negative least-squares
problem, and through the three solvers that use it (2D, 3D, object + background)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recon.errors import DivergenceError
from recon.solvers.accelerated import accelerated_loop
from recon.solvers.common import Monitor


def _nnls(seed=0, m=40, n=25):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((m, n)).astype(np.float32)
    x_true = np.maximum(rng.standard_normal(n), 0).astype(np.float32)
    b = (a @ x_true + 0.05 * rng.standard_normal(m)).astype(np.float32)
    step = 1.0 / float(np.linalg.norm(a.astype(np.float64), 2) ** 2)
    return a, b, step


def _reference(a, b, step, iterations, momentum=None, restart=True):
    """min 1/2 ||A x - b||^2 s.t. x >= 0, written out: FISTA with gradient restart
    (or a constant momentum); returns x, the objectives at y_k and the restarts."""
    x = np.zeros(a.shape[1], np.float32)
    y, t, objectives, restarts = x.copy(), 1.0, [], []
    for k in range(iterations):
        r = a @ y - b
        objectives.append(0.5 * float(r @ r))
        x_new = np.maximum(y - np.float32(step) * (a.T @ r), 0)
        if momentum is None:
            t_next = (1 + math.sqrt(1 + 4 * t * t)) / 2
            beta = (t - 1) / t_next
        else:
            t_next, beta = t, momentum
        if restart and float((y - x_new) @ (x_new - x)) > 0:
            y, t_next = x_new.copy(), 1.0
            restarts.append(k)
        else:
            y = x_new + np.float32(beta) * (x_new - x)
        x, t = x_new, t_next
    return x, objectives, restarts


def _loop(a, b, step, iterations, **kw):
    def data_term(y):
        r = a @ y - b
        return 0.5 * float(r @ r), a.T @ r

    def prox_step(y, grad, x, y_next, beta):
        x_new = np.maximum(y - np.float32(step) * grad, 0)
        dot = float((y - x_new) @ (x_new - x))
        y_next[...] = x_new + np.float32(beta) * (x_new - x)
        x[...] = x_new
        return 0.0, dot

    x = np.zeros(a.shape[1], np.float32)
    mon = Monitor(float(b @ b), "test")
    used, restarts = accelerated_loop(x, iterations=iterations, data_term=data_term,
                                      prox_step=prox_step, monitor=mon, **kw)
    return x, mon.history, used, restarts


@pytest.mark.parametrize("momentum,restart", [(None, True), (None, False), (0.8, False)],
                         ids=["fista-restart", "fista", "momentum"])
def test_loop_matches_a_plain_numpy_fista(momentum, restart):
    a, b, step = _nnls()
    want, objectives, restarts = _reference(a, b, step, 60, momentum, restart)
    got, hist, used, got_restarts = _loop(a, b, step, 60, momentum=momentum, restart=restart)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(hist.objective, objectives, rtol=1e-5)
    assert got_restarts == restarts and used == 60 == len(hist.seconds)
    if restart:
        assert restarts  # the test exercises the restart branch
    # converged towards the NNLS solution: the objective fell by orders of magnitude
    assert hist.objective[-1] < 0.05 * hist.objective[0]


def test_loop_stops_when_asked_and_reports_divergence():
    a, b, step = _nnls(1)
    _, hist, used, _ = _loop(a, b, step, 50, stop=lambda h: len(h.objective) == 7)
    assert used == 7 == len(hist.objective)
    with pytest.raises(DivergenceError, match="test diverged") as info:
        _loop(a, b, 5.0 * step, 200, momentum=0.0, restart=False)
    assert info.value.last_good is not None and info.value.last_good.shape == (25,)


def test_fista3d_and_background_take_stop_and_report_iterations_used():
    from recon.operators import ConvolutionOperator
    from recon.spatial.background import fista_background
    from recon.volume import VolumeConvolutionOperator, fista3d

    rng = np.random.default_rng(2)
    psf = np.maximum(rng.standard_normal((24, 32)), 1.5).astype(np.float32)
    psf /= psf.sum()
    b = rng.random((24, 32)).astype(np.float32) + 0.1
    vol = VolumeConvolutionOperator(np.stack([psf, np.roll(psf, 3, axis=1)]))
    full = fista3d(vol, b, iterations=12, tv=1e-4)
    stopped = fista3d(vol, b, iterations=12, tv=1e-4, stop=lambda h: len(h.objective) == 5)
    assert full.params["iterations_used"] == full.params["iterations"] == 12
    assert stopped.params["iterations_used"] == 5 == len(stopped.history.objective)
    assert stopped.params["iterations"] == 12
    op = ConvolutionOperator(psf)
    res = fista_background(op, b, iterations=12, stop=lambda h: len(h.objective) == 4)
    assert res.params["iterations_used"] == 4 == len(res.history.objective)
    assert res.params["background"].shape == b.shape and res.x.shape == op.shape_in
    # the objective of iteration k is at the extrapolated point y_k, l1 term included:
    # at y_0 = 0 without a background it is 1/2 ||b||^2 exactly
    plain = fista_background(op, b, iterations=3, l1=1e-2, estimate_background=False)
    assert plain.history.objective[0] == pytest.approx(0.5 * float(np.vdot(b, b)), rel=1e-6)
    assert plain.history.objective[1] > 0.5 * plain.history.data_residual[1] ** 2 * float(
        np.vdot(b, b))  # y_1 != 0: the l1 term counts

"""The array-API (generic) path against the NumPy path, on every backend present.

The generic operators and solvers (:mod:`recon.xp_operators`,
:mod:`recon.solvers.xp_admm`, :mod:`recon.solvers.xp_fista`,
:mod:`recon.volume.xp_admm3d`) run here under ``array-api-strict`` (the standard and
nothing more), PyTorch on the CPU when installed, and CuPy / PyTorch on a CUDA GPU
when one is visible (skipped otherwise, with the reason).

Tolerances. The adjoint identity holds to float32 rounding of the FFTs: 1e-5 relative.
The two paths do the same float32 arithmetic in another order (numba's fused passes
with per-row float32 sums against whole-array reductions) and through other FFT
implementations (scipy's pocketfft against numpy's, torch's or cuFFT), so their
iterates differ by rounding that the iterations carry along: measured up to 5e-6 of
the estimate's peak after 40 iterations, on every solver. The tests allow 1e-4 (20x
that); a wrong term (a missing TV split, an l1 threshold off by mu, a transposed
difference) moves the estimate by 1e-2 or more.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from recon.backend import Backend, torch_cpu
from recon.errors import ReconInputError
from recon.operators import ConvolutionOperator
from recon.solvers import admm, fista, gradient_descent
from recon.volume import VolumeConvolutionOperator, admm3d
from recon.xp_operators import XpConvolution, XpVolumeConvolution

xs = pytest.importorskip("array_api_strict")

SOLVER_TOL = 1e-4
ADJOINT_TOL = 1e-5


def _cuda_torch():
    if importlib.util.find_spec("torch") is None:
        return None, "PyTorch is not installed"
    import torch

    if not torch.cuda.is_available():
        return None, f"PyTorch {torch.__version__} sees no CUDA device"
    import array_api_compat.torch as xpt

    return Backend("torch", xpt, torch.device("cuda:0"), "cuda:0 (torch)"), ""


def _cupy():
    if importlib.util.find_spec("cupy") is None:
        return None, "CuPy is not installed (pip install 'diffuserlab[gpu]')"
    import cupy

    try:
        if cupy.cuda.runtime.getDeviceCount() < 1:
            return None, "CuPy sees no CUDA device"
    except Exception as exc:  # no driver
        return None, f"CuPy sees no CUDA device ({exc})"
    import array_api_compat.cupy as xpc

    return Backend("cupy", xpc, cupy.cuda.Device(0), "cuda:0 (cupy)"), ""


def _backend(name: str) -> Backend:
    if name == "array-api-strict":
        return Backend(name, xs, None, "cpu (array-api-strict)")
    if name == "torch-cpu":
        b = torch_cpu()
        if b is None:
            pytest.skip("PyTorch is not installed")
        return b
    backend, why = _cuda_torch() if name == "torch-cuda" else _cupy()
    if backend is None:
        pytest.skip(why)
    return backend


GENERIC = ["array-api-strict", "torch-cpu", "cupy", "torch-cuda"]


def on(backend: Backend, a):
    return backend.xp.asarray(np.asarray(a, np.float32), device=backend.device)


def host(a) -> np.ndarray:
    from recon.backend import to_numpy

    return np.asarray(to_numpy(a))


def _problem_2d():
    rng = np.random.default_rng(1)
    psf = np.zeros((40, 48), np.float32)
    psf[rng.integers(8, 32, 40), rng.integers(8, 40, 40)] = rng.random(40)
    psf /= psf.sum()
    op = ConvolutionOperator(psf)
    truth = np.zeros(op.padded_shape, np.float32)
    truth[30:50, 40:60] = 1.0
    truth[45:48, 30:70] = 2.0
    b = op.forward(truth)
    b = (b / b.max() + 0.01 * rng.standard_normal(b.shape)).astype(np.float32)
    return op, b


def _problem_3d():
    rng = np.random.default_rng(2)
    stack = rng.random((4, 20, 24)).astype(np.float32) ** 8
    stack /= np.sqrt((stack.sum(axis=(1, 2)) ** 2).sum())
    op = VolumeConvolutionOperator(stack)
    truth = np.zeros(op.shape_in, np.float32)
    truth[1, 15:25, 18:30] = 1.0
    truth[3, 20:22, 10:40] = 2.0
    b = op.forward(truth)
    b = (b / b.max() + 0.01 * rng.standard_normal(b.shape)).astype(np.float32)
    return op, b


def _weights(shape, seed=3):
    return (np.random.default_rng(seed).random(shape) > 0.2).astype(np.float32)


@pytest.mark.parametrize("name", ["numpy", *GENERIC])
@pytest.mark.parametrize("dims", [2, 3])
def test_adjoint_identity_on_every_backend(name, dims):
    op = (ConvolutionOperator(_problem_2d()[0].psf, _weights((40, 48))) if dims == 2 else
          VolumeConvolutionOperator(_problem_3d()[0].psf_stack,
                                    sensor_weights=_weights((20, 24))))
    rng = np.random.default_rng(4)
    x = rng.standard_normal(op.shape_in).astype(np.float32)
    y = rng.standard_normal(op.shape_out).astype(np.float32)
    if name == "numpy":
        ax, aty = op.forward(x), op.adjoint(y)
    else:
        backend = _backend(name)
        xop = (XpConvolution if dims == 2 else XpVolumeConvolution)(op, on(backend, y))
        ax, aty = host(xop.forward(on(backend, x))), host(xop.adjoint(on(backend, y)))
    lhs = float(np.vdot(ax.astype(np.float64), y))
    rhs = float(np.vdot(x.astype(np.float64), aty))
    assert abs(lhs - rhs) <= ADJOINT_TOL * max(abs(lhs), abs(rhs))


@pytest.mark.parametrize("name", GENERIC)
@pytest.mark.parametrize("dims", [2, 3])
def test_generic_operator_equals_the_numpy_operator(name, dims):
    backend = _backend(name)
    op, b = _problem_2d() if dims == 2 else _problem_3d()
    xop = (XpConvolution if dims == 2 else XpVolumeConvolution)(op, on(backend, b))
    x = np.random.default_rng(5).random(op.shape_in, dtype=np.float32)
    loss, grad = op.data_term(x, b)
    loss_g, grad_g = xop.data_term(on(backend, x), on(backend, b))
    fwd = op.forward(x)
    assert np.abs(host(xop.forward(on(backend, x))) - fwd).max() <= ADJOINT_TOL * np.abs(fwd).max()
    assert abs(loss_g - loss) <= ADJOINT_TOL * loss
    assert np.abs(host(grad_g) - grad).max() <= ADJOINT_TOL * np.abs(grad).max()


SOLVES = {
    "admm-tv": (admm, {"tv": 1e-3}),
    "admm-l1": (admm, {"tv": 0.0, "l1": 1e-3}),
    "admm-tv-l1": (admm, {"tv": 1e-3, "l1": 1e-3}),
    "fista-tv": (fista, {"tv": 1e-3}),
    "fista-l1": (fista, {"tv": 0.0, "l1": 1e-3}),
    "gd-tv": (gradient_descent, {"tv": 1e-3}),
    "admm3d-tv": (admm3d, {"tv": 1e-3}),
    "admm3d-tv-l1": (admm3d, {"tv": 1e-3, "l1": 1e-3}),
}


@pytest.mark.parametrize("name", GENERIC)
@pytest.mark.parametrize("solve", sorted(SOLVES))
def test_generic_solver_matches_the_numpy_path(name, solve):
    backend = _backend(name)
    func, kwargs = SOLVES[solve]
    op, b = _problem_3d() if func is admm3d else _problem_2d()
    ref = func(op, b, iterations=40, **kwargs)
    res = func(op, on(backend, b), iterations=40, **kwargs)
    x = host(res.x)
    assert not isinstance(res.x, np.ndarray)  # the estimate stays on the device
    assert x.shape == ref.x.shape
    assert np.abs(x - ref.x).max() <= SOLVER_TOL * np.abs(ref.x).max()
    assert res.final_objective == pytest.approx(ref.final_objective, rel=SOLVER_TOL)
    assert res.history.objective == pytest.approx(ref.history.objective, rel=SOLVER_TOL)
    assert res.history.extra.get("mu") == ref.history.extra.get("mu")  # same balancing
    assert res.history.extra.get("restarts") == ref.history.extra.get("restarts")


def test_a_wrong_weight_is_caught_by_the_tolerance():
    """The tolerance above separates rounding from a real difference: the same solve
    with a TV weight 10 % off already fails it."""
    backend = _backend("array-api-strict")
    op, b = _problem_2d()
    ref = admm(op, b, iterations=40, tv=1e-3)
    off = host(admm(op, on(backend, b), iterations=40, tv=1.1e-3).x)
    assert np.abs(off - ref.x).max() > 10 * SOLVER_TOL * np.abs(ref.x).max()


def test_the_generic_path_refuses_bad_measurements():
    backend = _backend("array-api-strict")
    op, b = _problem_2d()
    bad = b.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ReconInputError, match="NaN/inf"):
        admm(op, on(backend, bad), iterations=2, tv=1e-3)
    with pytest.raises(ReconInputError, match="all zero"):
        fista(op, on(backend, np.zeros_like(b)), iterations=2)
    with pytest.raises(ReconInputError, match="shape"):
        admm(op, on(backend, b[:-1]), iterations=2, tv=1e-3)


def test_a_diverging_generic_solve_reports_the_last_good_estimate_on_the_host():
    from recon.errors import DivergenceError

    backend = _backend("array-api-strict")
    op, b = _problem_2d()
    with pytest.raises(DivergenceError) as info:
        fista(op, on(backend, b), iterations=200, step_scale=2.5)
    assert isinstance(info.value.last_good, np.ndarray)
    assert info.value.last_good.shape == op.shape_in

"""The spatially varying models (PSF grids) on the array-API path, against the NumPy path.

The generic grid operator (:mod:`recon.spatial.xp_operator`) and the grid's solvers --
FISTA on Eq. 6.2 with and without the background (:mod:`recon.spatial.xp_background`)
and the linearized ADMM (:mod:`recon.spatial.xp_admm`) -- run under
``array-api-strict``, PyTorch's CPU backend and, where one is visible, CuPy / PyTorch on
a CUDA GPU (skipped otherwise, with the reason). The model choice
(:func:`recon.spatial.choose_model`: predicted errors, no solve) and ADMM's automatic
weight (:mod:`recon.auto`) run on the CPU; the front door's tests below check that the
chosen weight's ADMM then runs on the device.

Tolerances as tests/recon/test_backends.py's: the adjoint identity to 1e-5 relative,
the solvers' iterates to 1e-4 of the estimate's peak after 40 iterations (measured
here up to 2.2e-6: float32 rounding through other FFTs and summation orders).
"""

from __future__ import annotations

import numpy as np
import pytest

import recon.backend as backend_mod
import recon.solvers.device as device_mod
import recon.spatial.api as grid_api
from recon import reconstruct
from recon.backend import NUMPY, Backend
from recon.errors import DivergenceError, ReconInputError
from recon.operators import ConvolutionOperator
from recon.solvers import admm
from recon.spatial import (
    PsfGrid,
    SpatialAdmmPlan,
    fista_background,
    local_convolution_operator,
    pca_operator,
    spatial_admm,
)
from recon.spatial.xp_operator import XpSpatialConvolution, device_memory_bytes

from .test_backends import ADJOINT_TOL, GENERIC, SOLVER_TOL, _backend, host, on

xs = pytest.importorskip("array_api_strict")


def _grid(seed=0, z_mm=None, shape=(30, 40), n=3) -> PsfGrid:
    """A 3 x 3 grid: one sparse pattern shifted with the node, brightness varying."""
    rng = np.random.default_rng(seed)
    base = (rng.random(shape) > 0.97).astype(np.float32)
    step = (shape[0] / (n + 1), shape[1] / (n + 1))
    shifts = [((a - (n - 1) / 2) * step[0], (b - (n - 1) / 2) * step[1])
              for a in range(n) for b in range(n)]
    psfs = np.stack([np.roll(base, (int(dy) // 3, int(dx) // 3), axis=(0, 1))
                     * (0.5 + rng.random(shape, dtype=np.float32)) for dy, dx in shifts])
    return PsfGrid(psfs, shifts, (n, n), z_mm)


def _support():
    """An object support on the padded grid over 4 of the 9 nodes' regions."""
    support = np.zeros((60, 80), bool)
    support[15:30, 20:40] = True
    return support


MODELS = {
    "local": lambda: local_convolution_operator(_grid(3)),
    "pca-2": lambda: pca_operator(_grid(3), k=2),
    "local-3d": lambda: local_convolution_operator([_grid(1, 1.0), _grid(2, 2.0)]),
    "local-support": lambda: local_convolution_operator(_grid(3), support=_support()),
}


def _convolution():
    """The convolution model of the grid's central PSF (what FISTA on Eq. 6.2 also takes)."""
    grid = _grid(3)
    psf = grid.psfs[grid.central]
    return ConvolutionOperator(psf / psf.sum())


#: The solver tests' models: the grid's, and a plain convolution.
SOLVE_MODELS = {**MODELS, "convolution": _convolution}
#: Generic operator options: weight maps kept, or made per batch from their factors
#: with one kernel a batch.
LAYOUTS = {"kept": {}, "factored": {"cache_bytes": 0, "batch_bytes": 1}}


def _measurement(op, offset=0.2, seed=2):
    rng = np.random.default_rng(seed)
    volume = getattr(op, "volume", False)
    truth = np.zeros(op.shape_in, np.float32)
    (truth[0] if volume else truth)[20:40, 30:50] = 1.0
    (truth[-1] if volume else truth)[35:38, 20:60] = 2.0
    b = op.forward(truth) + offset
    return (b / b.max() + 0.01 * rng.standard_normal(b.shape)).astype(np.float32)


@pytest.mark.parametrize("model", sorted(MODELS))
@pytest.mark.parametrize(("name", "layout"), [("numpy", "kept")] + [
    (name, layout) for name in GENERIC for layout in sorted(LAYOUTS)])
def test_adjoint_identity_of_the_grid_operator_on_every_backend(name, model, layout):
    """<A x, y> = <x, A^T y> with sensor weights (an erasure mask) folded in."""
    op = MODELS[model]().with_weights(
        (np.random.default_rng(3).random((30, 40)) > 0.2).astype(np.float32))
    pair = np.random.default_rng(4)
    x, y = (pair.standard_normal(s).astype(np.float32) for s in (op.shape_in, op.shape_out))
    forward, adjoint = op.forward, op.adjoint
    if name != "numpy":
        backend = _backend(name)
        xop = XpSpatialConvolution(op, on(backend, y), **LAYOUTS[layout])

        def forward(v):
            return host(xop.forward(on(backend, v)))

        def adjoint(v):
            return host(xop.adjoint(on(backend, v)))

    lhs = float(np.vdot(forward(x).astype(np.float64), y))
    rhs = float(np.vdot(x.astype(np.float64), adjoint(y)))
    assert abs(lhs - rhs) <= ADJOINT_TOL * max(abs(lhs), abs(rhs))


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
@pytest.mark.parametrize("model", sorted(MODELS))
@pytest.mark.parametrize("name", GENERIC)
def test_generic_grid_operator_equals_the_numpy_operator(name, model, layout):
    backend = _backend(name)
    op = MODELS[model]()
    b = _measurement(op)
    xop = XpSpatialConvolution(op, on(backend, b), **LAYOUTS[layout])
    assert (xop.weights is None) == (layout == "factored")
    assert len(xop.batches) == (op.n_kernels if layout == "factored" else op.n_z)
    x = np.random.default_rng(5).random(op.shape_in, dtype=np.float32)
    fwd, adj = op.forward(x), op.adjoint(b)
    fwd_g, adj_g = xop.forward(on(backend, x)), xop.adjoint(on(backend, b))
    assert type(fwd_g) is type(on(backend, b)) and type(adj_g) is type(fwd_g)  # no NumPy
    assert np.abs(host(fwd_g) - fwd).max() <= ADJOINT_TOL * np.abs(fwd).max()
    assert np.abs(host(adj_g) - adj).max() <= ADJOINT_TOL * np.abs(adj).max()
    loss, grad = op.data_term(x, b)
    loss_g, grad_g = xop.data_term(on(backend, x), on(backend, b))
    assert abs(loss_g - loss) <= ADJOINT_TOL * loss
    assert np.abs(host(grad_g) - grad).max() <= ADJOINT_TOL * np.abs(grad).max()


SOLVES = {
    "admm-tv": ("local", spatial_admm, {"tv": 1e-3}),
    "admm-l1": ("local", spatial_admm, {"tv": 0.0, "l1": 1e-3}),
    "admm-tv-l1-pca": ("pca-2", spatial_admm, {"tv": 1e-3, "l1": 1e-3}),
    "fista-background": ("local", fista_background, {"l1": 1e-3}),
    "fista-background-pca": ("pca-2", fista_background, {"l1": 1e-3}),
    "fista-no-background": ("local", fista_background,
                            {"l1": 1e-3, "estimate_background": False}),
    "fista-background-3d": ("local-3d", fista_background, {"l1": 1e-3}),
    "fista-background-convolution": ("convolution", fista_background, {"l1": 1e-3}),
}


@pytest.mark.parametrize("name", GENERIC)
@pytest.mark.parametrize("solve", sorted(SOLVES))
def test_generic_grid_solver_matches_the_numpy_path(name, solve):
    backend = _backend(name)
    model, func, kwargs = SOLVES[solve]
    op = SOLVE_MODELS[model]()
    b = _measurement(op)
    ref = func(op, b, iterations=40, **kwargs)
    res = func(op, on(backend, b), iterations=40, **kwargs)
    assert type(res.x) is type(on(backend, b))  # the estimate stays on the device
    assert res.params["backend"] == backend.xp.__name__
    x = host(res.x)
    assert x.shape == ref.x.shape
    assert np.abs(x - ref.x).max() <= SOLVER_TOL * np.abs(ref.x).max()
    objectives = [res.final_objective, *res.history.objective]
    assert objectives == pytest.approx([ref.final_objective, *ref.history.objective],
                                       rel=SOLVER_TOL)
    # the same penalty balancing (ADMM) and momentum restarts (FISTA)
    for key in ("mu", "restarts"):
        assert res.history.extra.get(key) == ref.history.extra.get(key), key
    if "background" in ref.params:
        g = host(res.params["background"])
        assert np.abs(g - ref.params["background"]).max() <= SOLVER_TOL * np.abs(b).max()


def test_a_wrong_preconditioner_is_caught_by_the_tolerance():
    """The tolerance separates rounding from a real difference: ADMM with its x-update's
    preconditioner 10 % off already fails it."""
    backend = _backend("array-api-strict")
    op = MODELS["local"]()
    b = _measurement(op)
    ref = spatial_admm(op, b, iterations=40, tv=1e-3)
    plan = SpatialAdmmPlan.of(op)
    plan.h_pow = plan.h_pow * np.float32(1.1)
    off = host(admm(op, on(backend, b), iterations=40, tv=1e-3, plan=plan).x)
    assert np.abs(off - ref.x).max() > 10 * SOLVER_TOL * np.abs(ref.x).max()


def test_the_generic_grid_solvers_refuse_bad_measurements_and_report_divergence():
    backend = _backend("array-api-strict")
    op = MODELS["local"]()
    b = _measurement(op)
    bad = b.copy()
    bad[0, 0] = np.inf
    with pytest.raises(ReconInputError, match="NaN/inf"):
        fista_background(op, on(backend, bad), iterations=2)
    with pytest.raises(ReconInputError, match="all zero"):
        spatial_admm(op, on(backend, np.zeros_like(b)), iterations=2, tv=1e-3)
    with pytest.raises(ReconInputError, match="shape"):
        fista_background(op, on(backend, b[:-1]), iterations=2)
    loud = local_convolution_operator(_grid(3), normalize=False)  # L of A^T A ~ 1e3
    with pytest.raises(DivergenceError) as info:  # a step ~1e3 times too long
        fista_background(loud, on(backend, b), iterations=100, lipschitz=1e-3)
    assert isinstance(info.value.last_good, np.ndarray)
    assert info.value.last_good.shape == tuple(op.shape_in)  # the object, not the joint


def test_the_memory_estimate_counts_spectra_weights_and_the_solver():
    op = local_convolution_operator(_grid(3))
    p0, p1 = op.padded_shape
    plane, spec = 4 * p0 * p1, 8 * p0 * (p1 // 2 + 1)
    per_kernel = 2 * plane + 3 * spec  # a batch's planes, spectra and product
    kept = device_memory_bytes(op, planes=10)
    assert kept == op.n_kernels * (spec + plane + per_kernel) + 10 * plane
    factored = device_memory_bytes(op, planes=10, cache_bytes=0, batch_bytes=1)
    assert factored == op.n_kernels * spec + per_kernel + 10 * plane


# -- the front door and the command line --------------------------------------------------
def _stand_in(monkeypatch, name: str, free: int | None = None) -> Backend:
    """``device="cuda"`` resolves to a CPU array-API backend (the GPU's stand-in)."""
    standin = _backend(name)

    def resolve(device):
        return NUMPY if device == "cpu" else standin

    monkeypatch.setattr(grid_api, "resolve_device", resolve)
    monkeypatch.setattr(backend_mod, "resolve_device", resolve)
    monkeypatch.setattr(device_mod, "free_device_bytes", lambda b: free)
    return standin


def _frame(offset=5.0):
    grid = _grid(3)
    op = local_convolution_operator(grid, normalize=False)
    truth = np.zeros(op.shape_in, np.float32)
    truth[22:26, 30:34] = 40.0
    truth[40, 50] = 300.0
    return grid, np.maximum(op.forward(truth), 0) + offset


@pytest.mark.parametrize("name", ["array-api-strict", "torch-cpu"])
@pytest.mark.parametrize("case", ["fista", "fista-none", "admm"])
def test_reconstruct_a_grid_on_a_device_equals_the_cpu(monkeypatch, name, case):
    grid, raw = _frame()
    kwargs = {"fista": {"method": "fista", "model": "local"},
              "fista-none": {"method": "fista", "model": "pca", "k": 2,
                             "background": "none", "dark": 5.0},
              "admm": {"method": "admm", "model": "local", "background": "none",
                       "dark": 5.0, "tv": 1e-3}}[case]
    ref = reconstruct(grid, raw, iterations=30, **kwargs)
    standin = _stand_in(monkeypatch, name)
    got = reconstruct(grid, raw, iterations=30, device="cuda", **kwargs)
    assert ref.info.device == "cpu (numpy)" and got.info.device == standin.label
    assert got.results[0].params["device"] == standin.label
    assert isinstance(got.image, np.ndarray) and isinstance(got.results[0].x, np.ndarray)
    assert np.abs(got.image - ref.image).max() <= 1e-4 * np.abs(ref.image).max()
    if ref.background is not None:
        assert isinstance(got.background, np.ndarray)
        assert np.abs(got.background - ref.background).max() <= 1e-4 * raw.max()
        assert isinstance(got.results[0].params["background_dct"], np.ndarray)


def test_a_grid_with_an_automatic_weight_chooses_it_on_the_cpu_and_solves_on_the_device(
        monkeypatch):
    grid, raw = _frame(offset=0.0)
    standin = _stand_in(monkeypatch, "array-api-strict")
    got = reconstruct(grid, raw, "admm", iterations=40, background="none", model="local",
                      device="cuda")  # tv "auto"
    record = got.info.auto[0]
    assert record["weight"]["chosen_by"] == "ADMM path, used by admm"
    assert got.results[0].params["device"] == standin.label
    assert got.info.tv == record["weight"]["weight"]


def test_a_grid_too_large_for_the_device_is_refused_before_the_solve(monkeypatch):
    grid, raw = _frame()
    _stand_in(monkeypatch, "array-api-strict", free=1000)
    with pytest.raises(ReconInputError, match=r"FISTA of the local model \(9 kernels\) on "
                                              r"30 x 40 needs 0.00 GiB on cpu \(array-api-"
                                              r"strict\), 0.00 GiB are free"):
        reconstruct(grid, raw, iterations=5, model="local", device="cuda")
    with pytest.raises(ReconInputError, match=r"ADMM of the local model .* needs"):
        reconstruct(grid, raw, "admm", iterations=5, model="local", background="none",
                    tv=1e-3, device="cuda")


def test_an_unusable_device_for_a_grid_is_a_clear_error(monkeypatch):
    import importlib.util

    grid, raw = _frame()
    real = importlib.util.find_spec
    monkeypatch.setattr(backend_mod.importlib.util, "find_spec",
                        lambda n, *a: None if n in ("cupy", "torch") else real(n, *a))
    with pytest.raises(ReconInputError, match="cuda requested but CuPy/PyTorch with CUDA "
                                              "is not installed: pip install"):
        reconstruct(grid, raw, iterations=5, device="cuda")


def test_recon_psf_grid_with_device_runs_there_or_exits_2(tmp_path, monkeypatch, capsys):
    import importlib.util
    import json

    from instrument.cli import main
    from tests.instrument.test_reconstruct_grid import _grid_run

    psfs = _grid_run(tmp_path / "grid.zarr")
    np.save(tmp_path / "raw.npy", (100 * (psfs[0] + 0.7 * psfs[8]) + 5.0).astype(np.float32))
    argv = ["recon", "--psf-grid", str(tmp_path / "grid.zarr"), "--raw",
            str(tmp_path / "raw.npy"), "--model", "local", "--iterations", "20"]
    with monkeypatch.context() as m:  # no GPU library: exit 2 naming what is missing
        real = importlib.util.find_spec
        m.setattr(backend_mod.importlib.util, "find_spec",
                  lambda n, *a: None if n in ("cupy", "torch") else real(n, *a))
        assert main([*argv, "--device", "cuda", "--out", str(tmp_path / "x")]) == 2
        assert "pip install 'diffuserlab[gpu]'" in capsys.readouterr().err
        assert not list(tmp_path.glob("x*"))
    standin = _stand_in(monkeypatch, "array-api-strict")
    for device in ("cpu", "cuda"):
        out = tmp_path / device
        assert main([*argv, "--device", device, "--out", str(out), "--metrics-json",
                     f"{out}.json"]) == 0
    cpu, gpu = (json.loads((tmp_path / f"{d}.json").read_text()) for d in ("cpu", "cuda"))
    assert cpu["device"] == "cpu (numpy)" and gpu["device"] == standin.label
    import tifffile

    a, b = (tifffile.imread(tmp_path / f"{d}.tif") for d in ("cpu", "cuda"))
    assert np.abs(a - b).max() <= 1e-4 * np.abs(a).max()

"""The hologram optimiser's generic path (:mod:`recon.cgh.xp_optimize`,
:mod:`recon.cgh.xp_display`) against its NumPy path, on every backend present.

Under ``array-api-strict`` (the standard and nothing more), PyTorch on the CPU, and
CuPy / PyTorch on a CUDA GPU when one is visible (skipped otherwise, with the reason).

Tolerances. One loss and gradient evaluation agree to 1.4e-7 relative (loss) and
4.9e-7 of the gradient's peak, measured on every loss with one and two planes: float32
rounding of the FFTs and of sums taken in another order (numba's float64 row
accumulators against the backend's float32 reductions). After 5 iterations the fields
(unit modulus) differ by up to 7.1e-6, with the same backtracking decisions. The tests
allow 1e-5 on an evaluation and 1e-4 on the fields (14-20x the measured). A wrong term
moves far more: without the mean-matching constant the gradient moves by 0.32 of its
peak (:func:`test_a_wrong_term_is_caught_by_the_tolerance`).
"""

from __future__ import annotations

import numpy as np
import pytest

from recon.backend import to_numpy
from recon.cgh import IntensityLoss, ScatteringDisplay, loss_and_gradient, optimize_hologram
from recon.cgh.scattering_display import field_from_phase
from recon.errors import ReconInputError

from .test_backends import GENERIC, _backend
from .test_device import _gpu_usable, no_gpu

xs = pytest.importorskip("array_api_strict")

EVAL_TOL = 1e-5
FIELD_TOL = 1e-4
LOSSES = {"l2": IntensityLoss.l2, "frequency": IntensityLoss.frequency,
          "spatial": IntensityLoss.spatial, "l2-no-mean": lambda: IntensityLoss.l2(False)}


def on(backend, a):
    return backend.xp.asarray(np.ascontiguousarray(a), device=backend.device)


def _problem(planes=(0.0,)):
    d = ScatteringDisplay((12, 16), 3, mask_seed=2, planes_mm=planes)
    rng = np.random.default_rng(0)
    shape = d.grid_shape if len(planes) == 1 else (len(planes), *d.grid_shape)
    target = rng.random(shape).astype(np.float32) ** 2
    s = field_from_phase(rng.uniform(-np.pi, np.pi, d.slm_shape))
    return d, target, s


def _is_backend_array(backend, a) -> bool:
    return not isinstance(a, np.ndarray) and type(a).__module__.split(".")[0] == (
        backend.xp.__name__.split(".")[-1] if backend.name != "array-api-strict"
        else "array_api_strict")


@pytest.mark.parametrize("name", GENERIC)
@pytest.mark.parametrize("loss", sorted(LOSSES))
@pytest.mark.parametrize("planes", [(0.0,), (0.0, 25.0)], ids=["1 plane", "2 planes"])
def test_loss_and_gradient_match_the_numpy_path(name, loss, planes):
    backend = _backend(name)
    d, target, s = _problem(planes)
    ref_l, ref_g = loss_and_gradient(d, s, target, LOSSES[loss]())
    val, g = loss_and_gradient(d, on(backend, s), target, LOSSES[loss]())
    assert _is_backend_array(backend, g)  # computed there, not on the NumPy path
    g = np.asarray(to_numpy(g))
    assert g.dtype == np.complex64 and g.shape == d.slm_shape
    assert val == pytest.approx(ref_l, rel=EVAL_TOL)
    assert np.abs(g - ref_g).max() <= EVAL_TOL * np.abs(ref_g).max()


def test_a_wrong_term_is_caught_by_the_tolerance():
    """Without the mean-matching constant (``match_mean=False`` drops it) the gradient
    moves by far more than the tolerance: a dropped term would fail the test above."""
    backend = _backend("array-api-strict")
    d, target, s = _problem()
    _, ref_g = loss_and_gradient(d, s, target, IntensityLoss.frequency())
    _, g = loss_and_gradient(d, on(backend, s), target, IntensityLoss.frequency(
        match_mean=False))
    assert np.abs(np.asarray(to_numpy(g)) - ref_g).max() > 100 * EVAL_TOL * np.abs(ref_g).max()


@pytest.mark.parametrize("name", GENERIC)
@pytest.mark.parametrize("case", ["frequency-one-step", "l2-random", "spatial-complex",
                                  "frequency-2-planes"])
def test_a_few_iterations_give_the_same_hologram(name, case):
    backend = _backend(name)
    loss, init, slm = {"frequency-one-step": ("frequency", "one-step", "phase"),
                       "l2-random": ("l2", "random", "phase"),
                       "spatial-complex": ("spatial", "one-step", "complex"),
                       "frequency-2-planes": ("frequency", "one-step", "phase")}[case]
    d, target, _ = _problem((0.0, 25.0) if "planes" in case else (0.0,))
    seen = []

    def callback(it, field, value):
        seen.append(_is_backend_array(backend, field))

    ref = optimize_hologram(d, target, LOSSES[loss](), 5, init=init, slm=slm, seed=3,
                            checkpoints=(2,))
    res = optimize_hologram(d, on(backend, target), LOSSES[loss](), 5, init=init, slm=slm,
                            seed=3, checkpoints=(2,), callback=callback)
    assert seen == [True] * 5  # the iterates live on the backend
    assert res.params["device"].endswith(f"({backend.name})")
    assert res.params["device"] != ref.params["device"] == "cpu (numpy)"
    assert isinstance(res.field, np.ndarray) and res.field.dtype == np.complex64
    assert res.history.extra["backtracks"] == ref.history.extra["backtracks"]
    assert res.history.extra["ffts"] == ref.history.extra["ffts"]
    assert res.loss == pytest.approx(ref.loss, rel=FIELD_TOL)
    assert res.history.objective == pytest.approx(ref.history.objective, rel=FIELD_TOL)
    assert np.abs(res.field - ref.field).max() <= FIELD_TOL * np.abs(ref.field).max()
    assert np.abs(res.checkpoints[2] - ref.checkpoints[2]).max() <= FIELD_TOL
    np.testing.assert_allclose(res.phase, np.angle(res.field), atol=1e-6)
    if slm == "phase":
        np.testing.assert_allclose(np.abs(res.field), 1.0, atol=1e-5)


def test_an_array_start_and_cpu_fallback_of_auto():
    """``init`` as a phase map runs on the device too; ``device="auto"`` without a GPU
    is the NumPy path for a NumPy target."""
    backend = _backend("array-api-strict")
    d, target, s = _problem()
    phase = np.angle(s)
    ref = optimize_hologram(d, target, IntensityLoss.frequency(), 3, init=phase)
    res = optimize_hologram(d, on(backend, target), IntensityLoss.frequency(), 3,
                            init=on(backend, phase))
    assert np.abs(res.field - ref.field).max() <= FIELD_TOL
    if not _gpu_usable():
        auto = optimize_hologram(d, target, IntensityLoss.frequency(), 3, init=phase,
                                 device="auto")
        assert auto.params["device"] == "cpu (numpy)"
        np.testing.assert_array_equal(auto.field, ref.field)


def test_the_generic_path_checks_the_device_memory_first(monkeypatch):
    import recon.cgh.xp_optimize as opt
    from recon.cgh.xp_optimize import memory_bytes

    backend = _backend("torch-cpu")
    d, target, _ = _problem((0.0, 25.0))
    needed = memory_bytes(d.slm_shape, d.k, 2)
    assert needed == memory_bytes(d.slm_shape, d.k, 1) + d.grid_shape[0] * d.grid_shape[1] * 44
    monkeypatch.setattr(opt, "free_device_bytes", lambda b: needed - 1)
    with pytest.raises(ReconInputError, match=r"16 x 12 SLM at 9x with 2 plane\(s\) needs "
                       r"0\.\d\d GiB on cpu \(torch\).*smaller SLM, factor or fewer planes"):
        optimize_hologram(d, on(backend, target), IntensityLoss.frequency(), 2)
    monkeypatch.setattr(opt, "free_device_bytes", lambda b: needed)
    assert optimize_hologram(d, on(backend, target), IntensityLoss.frequency(), 2).iterations


def test_memory_estimate_scales_with_slm_factor_and_planes():
    from recon.cgh.xp_optimize import memory_bytes

    full = memory_bytes((540, 960), 4, 1)
    assert 0.5 * 2**30 < full < 1.5 * 2**30  # ~130 bytes per grid sample of 2160 x 3840
    assert memory_bytes((540, 960), 6, 1) > 2 * full
    assert memory_bytes((540, 960), 4, 3) > 1.5 * full


def test_the_generic_path_refuses_bad_input():
    backend = _backend("array-api-strict")
    d, target, s = _problem()
    with pytest.raises(ReconInputError, match="double=True is for the NumPy path"):
        loss_and_gradient(d, on(backend, s), target, double=True)
    bad = target.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ReconInputError, match="target contains NaN"):
        optimize_hologram(d, on(backend, bad), IntensityLoss.l2(), 2)
    with pytest.raises(ReconInputError, match="SLM field has shape"):
        loss_and_gradient(d, on(backend, s[:4]), target)
    with pytest.raises(ReconInputError, match="device 'tpu' is not one of"):
        optimize_hologram(d, target, IntensityLoss.l2(), 2, device="tpu")


@no_gpu
def test_an_unusable_cuda_request_names_what_is_missing():
    d, target, _ = _problem()
    with pytest.raises(ReconInputError, match="cuda requested but"):
        optimize_hologram(d, target, IntensityLoss.l2(), 2, device="cuda")


@pytest.mark.parametrize("name", GENERIC)
def test_the_display_model_and_its_adjoint_on_every_backend(name):
    """:class:`XpDisplay` gives :class:`ScatteringDisplay`'s adjoint (centred frame) and
    its raw-frame fields and back-projection are adjoint to each other, per plane, with a
    real mask plane and a complex (Fresnel) one."""
    from recon.cgh.xp_display import XpDisplay

    backend = _backend(name)
    d, _, s = _problem((0.0, 25.0))
    xd = XpDisplay(d, backend)
    rng = np.random.default_rng(7)
    y = (rng.standard_normal((2, *d.grid_shape))
         + 1j * rng.standard_normal((2, *d.grid_shape))).astype(np.complex64)
    ref = d.adjoint(y)
    got = np.asarray(to_numpy(xd.adjoint(on(backend, y))))
    assert np.abs(got - ref).max() <= EVAL_TOL * np.abs(ref).max()
    fields = xd.fields(on(backend, s))
    for p in range(2):
        fwd = np.asarray(to_numpy(fields[p])).astype(np.complex128)
        back = np.asarray(to_numpy(xd.back(on(backend, y[p]), p))).astype(np.complex128)
        lhs, rhs = np.vdot(fwd, y[p]), np.vdot(s, back)
        assert abs(lhs - rhs) <= EVAL_TOL * abs(lhs)
        # |fft2(m U s)|^2 is the centred intensity, ifftshift-ed
        np.testing.assert_allclose(np.abs(fwd) ** 2, np.fft.ifftshift(
            d.intensity(s)[p]), rtol=1e-4, atol=1e-4 * d.intensity(s)[p].max())

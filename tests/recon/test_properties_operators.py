"""Properties of the forward models and their adjoints for random shapes: the
dot-product test <A x, y> = <x, A^T y> (Eq. 3.8; the display's exact adjoint,
Eq. 7.11-7.12), the power-iteration Lipschitz bound, the fused data term, and
one-line :class:`~recon.errors.ReconInputError` for arrays that are not real data."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from recon.cgh import ScatteringDisplay
from recon.errors import ReconInputError
from recon.operators import ConvolutionOperator, PixelErasure
from recon.volume import VolumeConvolutionOperator

from .test_properties_common import (
    FAST,
    MEDIUM,
    NOT_INTEGERS,
    assert_refused,
    bad_arrays,
    not_counts,
)

SIDES = st.integers(2, 24)


def _gap(forward, adjoint, shape_in, shape_out, seed, dtype=np.float32) -> float:
    """|<A x, y> - <x, A^T y>| / (||A x|| ||y|| + ||x|| ||A^T y||), in float64."""
    rng = np.random.default_rng(seed)

    def draw(shape):
        a = rng.standard_normal(shape)
        if np.dtype(dtype).kind == "c":
            a = a + 1j * rng.standard_normal(shape)
        return a.astype(dtype)

    x, y = draw(shape_in), draw(shape_out)
    ax, aty = forward(x), adjoint(y)
    assert ax.shape == tuple(shape_out) and aty.shape == tuple(shape_in)
    ax, aty = ax.astype(np.complex128), aty.astype(np.complex128)
    lhs = np.vdot(y.astype(np.complex128), ax)
    rhs = np.vdot(aty, x.astype(np.complex128))
    scale = (np.linalg.norm(ax) * np.linalg.norm(y) + np.linalg.norm(x) * np.linalg.norm(aty))
    return abs(lhs - rhs) / scale


@st.composite
def convolution_operators(draw):
    """A ConvolutionOperator of random sensor shape, PSF, weights and padding."""
    h, w = draw(SIDES), draw(SIDES)
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    psf = rng.random((h, w)) * (rng.random((h, w)) < 0.5)
    psf[h // 2, w // 2] = 1.0
    weights = draw(st.sampled_from([None, "random", "mask"]))
    if weights == "random":
        weights = rng.random((h, w))
    elif weights == "mask":
        weights = (rng.random((h, w)) > 0.3).astype(np.float32)
    extra = draw(st.tuples(st.integers(0, 5), st.integers(0, 5)))
    padded = draw(st.sampled_from([None, (2 * h - 1 + extra[0], 2 * w - 1 + extra[1])]))
    return ConvolutionOperator(psf.astype(np.float32), weights, padded)


@MEDIUM
@given(op=convolution_operators(), seed=st.integers(0, 1000))
def test_convolution_passes_the_dot_product_test(op, seed):
    assert _gap(op.forward, op.adjoint, op.shape_in, op.shape_out, seed) < 1e-5


@FAST
@given(op=convolution_operators(), seed=st.integers(0, 1000))
def test_erasure_composed_with_convolution_passes_the_dot_product_test(op, seed):
    mask = PixelErasure.random(op.sensor_shape, 0.5, seed)
    composed = mask @ op
    assert _gap(composed.forward, composed.adjoint, op.shape_in, op.shape_out, seed) < 1e-5
    assert _gap(mask.forward, mask.adjoint, mask.shape_in, mask.shape_out, seed) < 1e-6


@FAST
@given(op=convolution_operators(), seed=st.integers(0, 1000))
def test_fused_data_term_is_loss_and_adjoint_of_residual(op, seed):
    rng = np.random.default_rng(seed)
    x = rng.random(op.shape_in).astype(np.float32)
    b = rng.random(op.shape_out).astype(np.float32)
    loss, grad = op.data_term(x, b)
    r = op.forward(x).astype(np.float64) - b
    assert loss == pytest.approx(0.5 * float(np.vdot(r, r)), rel=1e-4)
    ref = op.adjoint(r.astype(np.float32))
    np.testing.assert_allclose(grad, ref, atol=1e-4 * float(np.abs(ref).max()) + 1e-6)


@FAST
@given(op=convolution_operators(), seed=st.integers(0, 1000))
def test_lipschitz_bounds_every_rayleigh_quotient(op, seed):
    x = np.random.default_rng(seed).standard_normal(op.shape_in).astype(np.float32)
    ax = op.forward(x).astype(np.float64)
    assert op.lipschitz() >= float(np.vdot(ax, ax)) / float(np.vdot(x, x)) * (1 - 1e-5)


@FAST
@given(n_z=st.integers(1, 4), h=SIDES, w=SIDES, seed=st.integers(0, 1000),
       weighted=st.booleans())
def test_volume_operator_passes_the_dot_product_test(n_z, h, w, seed, weighted):
    rng = np.random.default_rng(seed)
    stack = rng.random((n_z, h, w)).astype(np.float32) + 0.01
    weights = rng.random((h, w)) if weighted else None
    op = VolumeConvolutionOperator(stack, sensor_weights=weights)
    assert _gap(op.forward, op.adjoint, op.shape_in, op.shape_out, seed) < 1e-5


@FAST
@given(ny=st.integers(1, 12), nx=st.integers(1, 12), k=st.integers(1, 3),
       planes=st.sampled_from([(0.0,), (0.0, 0.5), (-1.0, 0.0, 2.0)]),
       mask=st.sampled_from([None, "clear", "complex"]), seed=st.integers(0, 1000))
def test_scattering_display_passes_the_dot_product_test(ny, nx, k, planes, mask, seed):
    if mask == "complex":
        rng = np.random.default_rng(seed)
        mask = np.exp(2j * np.pi * rng.random((ny * k, nx * k)))
    d = ScatteringDisplay((ny, nx), k, mask=mask, mask_seed=seed, planes_mm=planes)
    assert _gap(d.forward, d.adjoint, d.shape_in, d.shape_out, seed, np.complex64) < 1e-5


@FAST
@given(ny=st.integers(1, 12), nx=st.integers(1, 12), k=st.integers(1, 3),
       seed=st.integers(0, 1000))
def test_scattering_display_conserves_energy(ny, nx, k, seed):
    """sum |y_z|^2 = sum mask_energy |s|^2 on every plane (F_c unitary)."""
    d = ScatteringDisplay((ny, nx), k, mask_seed=seed, planes_mm=(0.0, 1.0))
    rng = np.random.default_rng(seed)
    s = (rng.standard_normal((ny, nx)) + 1j * rng.standard_normal((ny, nx)))
    energy = float(np.sum(d.mask_energy * np.abs(s) ** 2))
    for plane in d.intensity(s.astype(np.complex64)):
        assert float(plane.sum(dtype=np.float64)) == pytest.approx(energy, rel=1e-4)


@pytest.mark.parametrize("where", ["psf", "weights", "forward", "adjoint", "mask", "stack"])
@FAST
@given(name=st.sampled_from(["complex", "object", "str", "ragged"]))
def test_non_real_arrays_are_refused(where, name):
    bad = bad_arrays()[name]
    psf = np.ones((16, 16), np.float32)
    op = ConvolutionOperator(psf)
    call = {"psf": lambda: ConvolutionOperator(bad),
            "weights": lambda: ConvolutionOperator(psf, sensor_weights=bad),
            "forward": lambda: op.forward(bad),
            "adjoint": lambda: op.adjoint(bad),
            "mask": lambda: PixelErasure(bad),
            "stack": lambda: VolumeConvolutionOperator(bad)}[where]
    with pytest.raises(ReconInputError) as info:
        call()
    assert_refused(info)


@FAST
@given(data=st.data(), argument=st.sampled_from(["shape", "fraction", "seed"]))
def test_random_erasure_refuses_bad_arguments(data, argument):
    kwargs = {"shape": (8, 8), "erased_fraction": 0.5, "seed": 0}
    if argument == "shape":
        kwargs["shape"] = data.draw(st.one_of(
            st.tuples(NOT_INTEGERS, st.integers(1, 8)),
            st.tuples(st.integers(-5, 0), st.integers(1, 8)),
            st.sampled_from([8, "ab", (8,), None])))
        name = "shape"
    elif argument == "fraction":
        kwargs["erased_fraction"] = data.draw(st.one_of(
            st.floats(1.0, 1e9), st.floats(max_value=-1e-9),
            st.sampled_from([float("nan"), "0.5", None, True])))
        name = "erased fraction"
    else:
        kwargs["seed"] = data.draw(not_counts(0))
        name = "seed"
    with pytest.raises(ReconInputError) as info:
        PixelErasure.random(**kwargs)
    assert_refused(info, name)


@pytest.mark.parametrize(("which", "minimum"), [("power_iterations", 1), ("seed", 0)])
@FAST
@given(data=st.data())
def test_lipschitz_refuses_bad_counts(which, minimum, data):
    op = ConvolutionOperator(np.ones((8, 8), np.float32))
    with pytest.raises(ReconInputError) as info:
        op.lipschitz(**{which: data.draw(not_counts(minimum))})
    assert_refused(info, which)


@FAST
@given(padded=st.one_of(st.tuples(NOT_INTEGERS, st.integers(16, 40)),
                        st.tuples(st.integers(1, 14), st.integers(16, 40)),
                        st.sampled_from([32, "ab", (32,), (32, 32, 32)])))
def test_convolution_refuses_bad_padding(padded):
    with pytest.raises(ReconInputError) as info:
        ConvolutionOperator(np.ones((8, 8), np.float32), padded_shape=padded)
    assert_refused(info, "padded")

"""Properties of the hologram entry points that take user numbers: the
:class:`~recon.cgh.ScatteringDisplay` constructor and ``check_slm``, and the
optimisers (:func:`~recon.cgh.optimize_hologram`, :func:`~recon.cgh.one_step_hologram`):
valid random problems give a feasible SLM field and a finite loss; every invalid
argument is a one-line :class:`~recon.errors.ReconInputError` naming it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from recon.cgh import ScatteringDisplay, one_step_hologram, optimize_hologram
from recon.errors import ReconInputError

from .test_properties_common import (
    FAST,
    NOT_INTEGERS,
    NOT_POSITIVE,
    assert_refused,
    bad_arrays,
    not_counts,
)

DISPLAY = ScatteringDisplay((4, 4), 2)
TARGET = np.random.default_rng(0).random(DISPLAY.grid_shape)


@FAST
@given(ny=st.integers(1, 10), nx=st.integers(1, 10), k=st.integers(1, 3),
       numpy_ints=st.booleans(), slm=st.sampled_from(["phase", "complex"]),
       init=st.sampled_from(["one-step", "random"]), iterations=st.integers(1, 4),
       seed=st.integers(0, 1000))
def test_optimiser_gives_feasible_field(ny, nx, k, numpy_ints, slm, init, iterations, seed):
    cast = np.int64 if numpy_ints else int
    d = ScatteringDisplay((cast(ny), cast(nx)), cast(k), mask_seed=seed)
    target = np.random.default_rng(seed).random(d.grid_shape) + 0.01
    res = optimize_hologram(d, target, steps=cast(iterations), init=init, slm=slm,
                            seed=cast(seed))
    assert res.field.shape == (ny, nx) and res.field.dtype == np.complex64
    assert np.all(np.isfinite(res.field)) and math.isfinite(res.loss)
    amp = np.abs(res.field)
    if slm == "phase":
        np.testing.assert_allclose(amp, 1.0, atol=1e-5)
    else:
        assert amp.max() <= 1.0 + 1e-5
    assert 0 <= res.iterations <= iterations


@pytest.mark.parametrize(("argument", "values"), [
    ("slm_shape", st.one_of(st.tuples(NOT_INTEGERS, st.integers(1, 4)),
                            st.tuples(st.integers(-3, 0), st.integers(1, 4)),
                            st.sampled_from([4, "ab", (4,), (2, 2, 2)]))),
    ("k", not_counts(1)),
    ("mask_seed", not_counts(0)),
    ("slm_pitch_um", NOT_POSITIVE),
    ("wavelength_nm", NOT_POSITIVE),
    ("focal_length_mm", NOT_POSITIVE),
    ("planes_mm", st.sampled_from([(), (0.0, math.nan), (math.inf,), "0", ("a", "b"),
                                   [[0.0, 1.0]], (0.0, 1j)])),
])
@FAST
@given(data=st.data())
def test_display_constructor_refuses_bad_numbers(argument, values, data):
    kwargs = {"slm_shape": (4, 4), "k": 2, argument: data.draw(values)}
    with pytest.raises(ReconInputError) as info:
        ScatteringDisplay(**kwargs)
    # the mask seed is checked where the mask is drawn, by the mask model ("seed")
    assert_refused(info, "seed" if argument == "mask_seed" else argument)


@FAST
@given(name=st.sampled_from(sorted(bad_arrays((4, 4)))))
def test_check_slm_refuses_bad_fields(name):
    bad = bad_arrays((4, 4))[name]
    if name == "complex":  # a complex field of the right shape is what it takes
        bad = bad[:, :3]
    with pytest.raises(ReconInputError) as info:
        DISPLAY.check_slm(bad)
    assert_refused(info, "SLM field")


@pytest.mark.parametrize(("argument", "values"), [
    ("steps", not_counts(1)),
    ("seed", not_counts(0)),
    ("step_scale", NOT_POSITIVE),
    ("step_growth", st.one_of(st.floats(max_value=1 - 1e-9),
                              st.sampled_from([math.nan, math.inf, "2", None, True]))),
    ("max_backtracks", not_counts(0)),
    ("checkpoints", st.one_of(st.lists(not_counts(1), min_size=1, max_size=2), st.just(5))),
])
@FAST
@given(data=st.data())
def test_optimiser_refuses_bad_numbers(argument, values, data):
    kwargs = {"steps": 2, argument: data.draw(values)}
    with pytest.raises(ReconInputError) as info:
        optimize_hologram(DISPLAY, TARGET, **kwargs)
    assert_refused(info, argument.rstrip("s") if argument == "checkpoints" else argument)


@FAST
@given(seed=not_counts(0))
def test_one_step_refuses_bad_seed(seed):
    with pytest.raises(ReconInputError) as info:
        one_step_hologram(DISPLAY, TARGET, seed=seed)
    assert_refused(info, "seed")


@pytest.mark.parametrize("where", ["target", "init"])
@FAST
@given(name=st.sampled_from(sorted(bad_arrays(DISPLAY.grid_shape))))
def test_optimiser_refuses_bad_arrays(where, name):
    shape = DISPLAY.grid_shape if where == "target" else DISPLAY.slm_shape
    bad = bad_arrays(shape)[name]
    if where == "init" and name == "complex":
        bad = bad[:, :3]  # complex is a valid start; the wrong shape is not
    kwargs = {"target": TARGET, where: bad}
    with pytest.raises(ReconInputError) as info:
        optimize_hologram(DISPLAY, steps=2, **kwargs)
    assert_refused(info, where)

"""Properties of :func:`recon.reconstruct_volume` (3D FISTA and ADMM): the documented
volume for valid random stacks, one-line :class:`~recon.errors.ReconInputError` for
every invalid argument, and a result in measurement units."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import recon
from recon.errors import ReconInputError
from recon.volume.api import METHODS

from .test_properties_common import (
    DTYPES,
    FAST,
    NOT_WEIGHTS,
    assert_refused,
    bad_arrays,
    not_counts,
    random_array,
)

STACK = random_array((2, 16, 16), np.float64, 5) + 0.05
RAW = random_array((16, 16), np.float64, 6)
DEPTHS = [10.0, 20.0]


@st.composite
def volume_problems(draw, max_side: int = 32):
    """A PSF stack (n_z, H, W) of sparse dots, depths in any order, a raw image."""
    n_z = draw(st.integers(1, 3))
    h, w = draw(st.integers(8, max_side)), draw(st.integers(8, max_side))
    dtype = np.dtype(draw(st.sampled_from(DTYPES)))
    seed = draw(st.integers(0, 2**16))
    rng = np.random.default_rng(seed)
    stack = 0.02 * rng.random((n_z, h, w))
    for k in range(n_z):
        stack[k, rng.integers(0, h, 5), rng.integers(0, w, 5)] = 1.0
    depths = draw(st.lists(st.floats(1.0, 1e3), min_size=n_z, max_size=n_z, unique=True))
    raw = random_array((h, w), dtype, seed + 1)
    if dtype.kind in "ui":
        stack = (stack * 0.9 * np.iinfo(dtype).max).astype(dtype)
    return stack.astype(dtype), depths, raw


@pytest.mark.parametrize("method", METHODS)
@FAST
@given(problem=volume_problems(), bin_factor=st.integers(1, 2), iterations=st.integers(1, 3),
       dark=st.sampled_from(["auto", "none", 0.0]))
def test_valid_inputs_give_documented_volume(method, problem, bin_factor, iterations, dark):
    stack, depths, raw = problem
    rec = recon.reconstruct_volume(stack, depths, raw, method=method, iterations=iterations,
                                   bin_factor=bin_factor, dark=dark)
    assert rec.volume.shape == (len(depths), raw.shape[0] // bin_factor,
                                raw.shape[1] // bin_factor)
    assert rec.volume.dtype == np.float32
    assert np.all(np.isfinite(rec.volume)) and rec.volume.min() >= 0.0
    assert rec.depths_mm == sorted(depths)
    assert rec.info["iterations"] == iterations


@pytest.mark.parametrize("method", METHODS)
@FAST
@given(problem=volume_problems(max_side=20), scale=st.floats(1e-3, 1e3))
def test_volume_is_in_measurement_units(method, problem, scale):
    stack, depths, raw = problem
    # float data: an integer stack would fix the raw's full scale (2**bits - 1)
    stack, raw = stack.astype(np.float64), raw.astype(np.float64)
    ref = recon.reconstruct_volume(stack, depths, raw, method=method, iterations=3,
                                   dark="none").volume
    got = recon.reconstruct_volume(stack, depths, raw * scale, method=method, iterations=3,
                                   dark="none").volume
    np.testing.assert_allclose(got / scale, ref, rtol=1e-3,
                               atol=1e-4 * float(np.abs(ref).max()) + 1e-30)


@pytest.mark.parametrize(("argument", "values"), [
    ("iterations", not_counts(1)),
    ("bin_factor", not_counts(1)),
    ("tv", NOT_WEIGHTS),
    ("l1", NOT_WEIGHTS),
    ("dark", st.sampled_from(["auto-ish", math.nan, math.inf, True, [1.0], "3"])),
])
@FAST
@given(data=st.data())
def test_invalid_numbers_are_refused_naming_them(argument, values, data):
    kwargs = {"iterations": 2, argument: data.draw(values)}
    with pytest.raises(ReconInputError) as info:
        recon.reconstruct_volume(STACK, DEPTHS, RAW, method="fista", **kwargs)
    assert_refused(info, {"bin_factor": "bin"}.get(argument, argument))


@pytest.mark.parametrize("which", ["stack", "raw"])
@FAST
@given(name=st.sampled_from(sorted(bad_arrays())))
def test_invalid_arrays_are_refused(which, name):
    if which == "stack":
        args = (bad_arrays((2, 16, 16))[name], DEPTHS, RAW)
    else:
        args = (STACK, DEPTHS, bad_arrays()[name])
    with pytest.raises(ReconInputError) as info:
        recon.reconstruct_volume(*args, method="admm", iterations=2)
    assert_refused(info)


@FAST
@given(depths=st.one_of(
    st.lists(st.floats(1, 100), min_size=0, max_size=1),
    st.lists(st.floats(1, 100), min_size=3, max_size=4),
    st.sampled_from([None, 3.0, "ab", [1.0, math.nan], [5.0, 5.0], [[1.0, 2.0]]])))
def test_invalid_depths_are_refused(depths):
    with pytest.raises(ReconInputError) as info:
        recon.reconstruct_volume(STACK, depths, RAW, method="fista", iterations=2)
    assert_refused(info, "depth")


@FAST
@given(dh=st.integers(-4, 4), dw=st.integers(-4, 4), plane=st.integers(0, 1))
def test_mismatched_shapes_and_empty_planes_are_refused(dh, dw, plane):
    if dh == dw == 0:  # same size: an all-zero plane instead
        stack = STACK.copy()
        stack[plane] = 0.0
        raw = RAW
    else:
        stack, raw = STACK, random_array((16 + dh, 16 + dw), np.float64, 7)
    with pytest.raises(ReconInputError) as info:
        recon.reconstruct_volume(stack, DEPTHS, raw, method="admm", iterations=2)
    assert_refused(info, "PSF")

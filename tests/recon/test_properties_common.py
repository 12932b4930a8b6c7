"""Shared strategies of the property-based tests (``test_properties_*.py``) and the
properties of :mod:`recon.validate`, the argument checks every entry point uses.

Arrays are drawn as a shape, a dtype and a seed and filled with numpy's generator:
hypothesis then shrinks the shape and the seed, and a test costs microseconds to
draw instead of one hypothesis draw per pixel.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from recon import validate
from recon.errors import ReconInputError

#: Settings of every property: deterministic, no per-example deadline (numba and the
#: first FFT plan of a shape are slow once), small example counts for a 2-core runner.
FAST = settings(max_examples=25, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])
MEDIUM = settings(FAST, max_examples=40)

DTYPES = (np.float32, np.float64, np.uint8, np.uint16)

#: Values no integer count (iterations, bin factor, seed, ...) accepts, whatever its minimum.
NOT_INTEGERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).filter(
        lambda v: not (math.isfinite(v) and v == int(v))),
    st.booleans(),
    st.text(max_size=3),
    st.none(),
    st.just([2]),
    st.just(2.0),
    st.just(np.float64(3.0)),
)

#: Values no non-negative finite weight (tv, l1, ...) accepts.
NOT_WEIGHTS = st.one_of(
    st.floats(max_value=-1e-12),
    st.sampled_from([math.nan, math.inf, -math.inf, True, False, "0.1", "x", [0.1], (1,)]),
)

#: Values no positive finite number (step scale, pitch, ...) accepts.
NOT_POSITIVE = st.one_of(
    st.floats(max_value=0.0),
    st.sampled_from([math.nan, math.inf, True, "1", [1.0]]),
)


def integers_below(minimum: int):
    """Integers (Python and numpy) below ``minimum``: refused by a count >= minimum."""
    return st.integers(-10**6, minimum - 1).flatmap(
        lambda n: st.sampled_from([n, np.int64(n)]))


def not_counts(minimum: int):
    """Anything an integer count >= ``minimum`` refuses."""
    return st.one_of(NOT_INTEGERS, integers_below(minimum))


def random_array(shape, dtype, seed: int, low: float = 0.0, high: float = 1.0) -> np.ndarray:
    """Uniform values in [low, high) (integer dtypes: scaled to 5..95 % of the range,
    clear of saturation), as ``dtype``."""
    rng = np.random.default_rng(seed)
    u = rng.random(shape)
    dtype = np.dtype(dtype)
    if dtype.kind in "ui":
        top = float(np.iinfo(dtype).max)
        return (top * (0.05 + 0.9 * u)).astype(dtype)
    return (low + (high - low) * u).astype(dtype)


@st.composite
def image_pairs(draw, min_side: int = 8, max_side: int = 48, colour: bool = True):
    """A PSF and a raw image of one random (H, W) or (H, W, 3) shape and dtype.

    The PSF is a few bright random dots on a low floor (a diffuser PSF's sparse
    caustics), the raw image uniform; both in the dtype's counts.
    """
    h = draw(st.integers(min_side, max_side))
    w = draw(st.integers(min_side, max_side))
    channels = draw(st.sampled_from([None, 3])) if colour else None
    dtype = draw(st.sampled_from(DTYPES))
    seed = draw(st.integers(0, 2**16))
    shape = (h, w) if channels is None else (h, w, channels)
    raw = random_array(shape, dtype, seed)
    rng = np.random.default_rng(seed + 1)
    psf = 0.02 * rng.random((h, w))
    psf[rng.integers(0, h, 6), rng.integers(0, w, 6)] = 1.0
    if np.dtype(dtype).kind in "ui":
        psf = (psf * 0.9 * np.iinfo(dtype).max).astype(dtype)
    else:
        psf = psf.astype(dtype)
    return psf, raw


def bad_arrays(shape=(16, 16)):
    """Arrays no image entry point accepts, by name: wrong rank, non-real or object
    dtype, NaN/inf, empty, strings and ragged lists."""
    good = random_array(shape, np.float64, 0) + 0.1
    nan = good.copy()
    nan[1, 2] = np.nan
    inf = good.copy()
    inf[0, 0] = np.inf
    return {
        "1-D": good.ravel(),
        "4-D": good[None, None] if len(shape) == 2 else good[None],
        "complex": good.astype(np.complex128),
        "object": good.astype(object),
        "all-NaN": np.full(shape, np.nan),
        "one NaN": nan,
        "one inf": inf,
        "empty": np.zeros((0, *shape[1:])),
        "str": "image.tif",
        "ragged": [[1.0, 2.0], [3.0]],
    }


def assert_refused(excinfo, *names: str) -> None:
    """The error is one line and names every one of ``names`` (case-insensitive)."""
    msg = str(excinfo.value)
    assert msg and "\n" not in msg, f"message is not one line: {msg!r}"
    for name in names:
        assert name.lower() in msg.lower(), f"{name!r} not named in {msg!r}"


def assert_call_refused(call, value, *names: str) -> None:
    """``call(value)`` raises a one-line ReconInputError naming every one of ``names``."""
    with pytest.raises(ReconInputError) as info:
        call(value)
    assert_refused(info, *names)


def case_id(value) -> str:
    """pytest id of a ``(call, name, values)`` case: the argument name."""
    return value if isinstance(value, str) else ""


# --------------------------------------------------------------------- recon.validate


@FAST
@given(value=not_counts(1))
def test_as_int_refuses_non_counts(value):
    with pytest.raises(ReconInputError) as info:
        validate.as_int(value, "iterations", 1)
    assert_refused(info, "iterations", ">= 1")


@FAST
@given(value=st.integers(0, 10**6), numpy=st.booleans())
def test_as_int_accepts_integers_as_int(value, numpy):
    got = validate.as_int(np.int64(value) if numpy else value, "seed", 0)
    assert got == value and type(got) is int


@FAST
@given(value=NOT_WEIGHTS)
def test_nonneg_weight_refuses(value):
    with pytest.raises(ReconInputError) as info:
        validate.nonneg_weight(value, "tv")
    assert_refused(info, "tv weight")


@FAST
@given(value=st.floats(0.0, 1e6) | st.integers(0, 100))
def test_nonneg_weight_accepts_real_numbers(value):
    assert validate.nonneg_weight(value, "tv") == float(value)


@FAST
@given(value=NOT_POSITIVE)
def test_positive_refuses(value):
    with pytest.raises(ReconInputError) as info:
        validate.positive(value, "step_scale")
    assert_refused(info, "step_scale")


@FAST
@given(value=st.one_of(st.sampled_from([math.nan, math.inf, True, "2", None]),
                       st.floats(-1e6, -1e-9), st.floats(1.0 + 1e-9, 1e6)))
def test_finite_float_bounds(value):
    with pytest.raises(ReconInputError) as info:
        validate.finite_float(value, "erase", lo=0.0, hi=1.0)
    assert_refused(info, "erase")


@FAST
@given(name=st.sampled_from(sorted(bad_arrays())))
def test_float_array_refuses(name):
    with pytest.raises(ReconInputError) as info:
        validate.float_array(bad_arrays()[name], "psf", ndims=(2,))
    assert_refused(info, "psf")


@FAST
@given(value=st.one_of(
    st.tuples(st.integers(max_value=0), st.integers(1, 9)),
    st.tuples(st.floats(allow_nan=True), st.integers(1, 9)),
    st.tuples(st.booleans(), st.integers(1, 9)),
    st.sampled_from([(3,), (1, 2, 3), 5, "ab", None])))
def test_as_shape2_refuses(value):
    with pytest.raises(ReconInputError) as info:
        validate.as_shape2(value, "slm_shape")
    assert_refused(info, "slm_shape")

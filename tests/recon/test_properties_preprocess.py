"""Properties of :mod:`recon.preprocess` (validation, dark level, binning, the pair):
binning preserves the flux of the part it keeps, dark subtraction is exact in float32,
the prepared pair has the documented shapes, sign and dtype, and every invalid input
is a one-line :class:`~recon.errors.ReconInputError` naming it."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from recon.errors import ReconInputError
from recon.preprocess import (
    SaturationWarning,
    box_bin,
    dark_level,
    normalize,
    prepare_pair,
    saturation_fraction,
    subtract_dark,
    validate_measurement,
    validate_psf,
)

from .test_properties_common import (
    DTYPES,
    FAST,
    MEDIUM,
    assert_refused,
    bad_arrays,
    image_pairs,
    not_counts,
    random_array,
)


@st.composite
def images(draw, min_side: int = 1, max_side: int = 48):
    """A random (H, W) or (H, W, C) image of any supported dtype."""
    shape = (draw(st.integers(min_side, max_side)), draw(st.integers(min_side, max_side)))
    shape += draw(st.sampled_from([(), (1,), (3,)]))
    return random_array(shape, draw(st.sampled_from(DTYPES)), draw(st.integers(0, 2**16)),
                        low=-1.0, high=2.0)


@MEDIUM
@given(image=images(), factor=st.integers(1, 6))
def test_box_bin_keeps_the_flux_of_what_it_keeps(image, factor):
    if factor > min(image.shape[:2]):
        with pytest.raises(ReconInputError) as info:
            box_bin(image, factor)
        assert_refused(info, "bin factor")
        return
    out = box_bin(image, factor)
    h, w = image.shape[0] // factor, image.shape[1] // factor
    assert out.shape == (h, w, *image.shape[2:]) and out.dtype == np.float32
    kept = image[: h * factor, : w * factor].astype(np.float64)
    total = kept.sum(axis=(0, 1))
    np.testing.assert_allclose(out.sum(axis=(0, 1), dtype=np.float64) * factor**2, total,
                               rtol=1e-5, atol=1e-5 * float(np.abs(kept).sum()) + 1e-9)
    assert out.min() >= kept.min() - 1e-3 * abs(kept.min()) - 1e-6  # block means
    assert out.max() <= kept.max() + 1e-3 * abs(kept.max()) + 1e-6


@FAST
@given(factor=not_counts(1))
def test_box_bin_refuses_bad_factors(factor):
    with pytest.raises(ReconInputError) as info:
        box_bin(np.ones((8, 8)), factor)
    assert_refused(info, "bin factor")


@pytest.mark.parametrize("function", [box_bin, dark_level, subtract_dark, saturation_fraction,
                                      validate_psf, validate_measurement])
@FAST
@given(name=st.sampled_from(["1-D", "4-D", "complex", "object", "empty", "str", "ragged"]))
def test_image_functions_refuse_what_is_not_an_image(function, name):
    args = {box_bin: (2,), subtract_dark: (1.0,)}.get(function, ())
    with pytest.raises(ReconInputError) as info:
        function(bad_arrays()[name], *args)
    assert_refused(info)


@pytest.mark.parametrize("function", [validate_psf, validate_measurement])
@FAST
@given(name=st.sampled_from(["all-NaN", "one NaN", "one inf"]))
def test_validation_refuses_nan_and_inf(function, name):
    with pytest.raises(ReconInputError) as info:
        function(bad_arrays()[name])
    assert_refused(info, "NaN/inf")


@FAST
@given(image=images(), kind=st.sampled_from(["scalar", "frame", "vector"]),
       seed=st.integers(0, 1000))
def test_subtract_dark_is_exact(image, kind, seed):
    rng = np.random.default_rng(seed)
    if kind == "vector" and image.ndim == 3:
        dark = rng.random(image.shape[2]).astype(np.float32)
    elif kind == "frame":
        dark = rng.random(image.shape).astype(np.float32)
    else:
        dark = float(rng.random())
    out = subtract_dark(image, dark)
    assert out.shape == image.shape and out.dtype == np.float32
    np.testing.assert_array_equal(out, image.astype(np.float32) - np.float32(dark)
                                  if np.ndim(dark) == 0 else image.astype(np.float32) - dark)
    clipped = subtract_dark(image, dark, clip_negative=True)
    np.testing.assert_array_equal(clipped, np.maximum(out, 0))


@FAST
@given(dark=st.one_of(st.sampled_from([math.nan, math.inf, "abc", [[1.0, 2.0], [3.0]]]),
                      st.tuples(st.integers(1, 7), st.integers(1, 7)).filter(
                          lambda s: s != (8, 8)).map(np.ones)))
def test_subtract_dark_refuses_bad_dark(dark):
    with pytest.raises(ReconInputError) as info:
        subtract_dark(np.ones((8, 8)), dark)
    assert_refused(info, "dark")


@FAST
@given(image=images(min_side=6), value=st.floats(-100, 100))
def test_dark_level_of_a_flat_region_is_its_value(image, value):
    flat = np.full(image.shape, value)
    level = dark_level(flat)
    assert np.allclose(level, value, rtol=1e-6, atol=1e-6)
    assert np.shape(level) == (() if image.ndim == 2 else (image.shape[2],))


@MEDIUM
@given(pair=image_pairs(), bin_factor=st.integers(1, 4),
       dark=st.sampled_from([None, "none", 0.0]))
def test_prepare_pair_gives_documented_pair(pair, bin_factor, dark):
    psf, raw = pair
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SaturationWarning)
        out = prepare_pair(psf, raw, bin_factor=bin_factor, dark=dark)
    h, w = raw.shape[0] // bin_factor, raw.shape[1] // bin_factor
    assert out.raw.shape == (h, w, *raw.shape[2:]) and out.psf.shape == (h, w, *psf.shape[2:])
    assert out.psf.dtype == np.float32 and out.raw.dtype == np.float32
    assert out.psf.min() >= 0 and out.psf.sum() > 0
    assert np.all(np.isfinite(out.raw))
    assert out.info["bin_factor"] == bin_factor
    assert 0.0 <= out.info["saturated_fraction_raw"] <= 1.0


@pytest.mark.parametrize(("argument", "values"), [
    ("bin_factor", not_counts(1)),
    ("warn_saturation", st.one_of(st.floats(1.0 + 1e-9, 1e9), st.floats(max_value=-1e-9),
                                  st.sampled_from([math.nan, "0.1", True]))),
    ("full_scale", st.one_of(st.floats(max_value=0.0),
                             st.sampled_from([math.nan, math.inf, "4095", True]))),
    ("dark", st.sampled_from(["auto", True, math.nan, "x", np.ones((3, 3))])),
])
@FAST
@given(data=st.data())
def test_prepare_pair_refuses_bad_arguments(argument, values, data):
    psf = random_array((16, 16), np.float64, 1) + 0.1
    with pytest.raises(ReconInputError) as info:
        prepare_pair(psf, psf, **{argument: data.draw(values)})
    assert_refused(info, {"bin_factor": "bin factor"}.get(argument, argument))


@FAST
@given(psf=st.sampled_from(["zeros", "negative", "dark"]))
def test_prepare_pair_refuses_psf_without_signal(psf):
    flat = np.full((16, 16), 5.0)
    psf = {"zeros": np.zeros((16, 16)), "negative": -flat, "dark": flat}[psf]
    with pytest.raises(ReconInputError) as info:
        prepare_pair(psf, flat)  # "dark": the dark corner level takes all of it
    assert_refused(info, "PSF")


@FAST
@given(image=images(), mode=st.sampled_from(["l2", "max", "sum"]))
def test_normalize_scale_recovers_the_image(image, mode):
    data = image.astype(np.float64)
    if not np.any(data) or (mode == "sum" and not data.sum() > 0):
        with pytest.raises(ReconInputError):
            normalize(image, mode)
        return
    scaled, scale = normalize(image, mode)
    assert scaled.dtype == np.float32 and scale > 0
    np.testing.assert_allclose(scaled.astype(np.float64) * scale, data, rtol=1e-5,
                               atol=1e-6 * float(np.abs(data).max()))

"""Properties of :func:`recon.reconstruct` for every method of :data:`recon.solvers.SOLVERS`:
valid random inputs give the documented shape, dtype and sign; every invalid argument
is a one-line :class:`~recon.errors.ReconInputError` naming it; the result is in
measurement units (equivariant to the scale of the raw image, invariant to the scale
of the PSF)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import recon
from recon.api import solver_options
from recon.errors import DivergenceError, ReconInputError
from recon.preprocess import SaturationWarning
from recon.solvers import SOLVERS, AdmmPenalty

from .test_properties_common import (
    FAST,
    NOT_POSITIVE,
    NOT_WEIGHTS,
    assert_refused,
    bad_arrays,
    image_pairs,
    not_counts,
    random_array,
)

METHODS = list(SOLVERS)
PSF = random_array((16, 16), np.float64, 1) + 0.05
# above the PSF's "dark corner" (a random PSF has none): a raw with light to image
RAW = random_array((16, 16), np.float64, 2) + 1.0


def _reconstruct(*args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SaturationWarning)
        return recon.reconstruct(*args, **kwargs)


@pytest.mark.parametrize("method", METHODS)
@FAST
@given(pair=image_pairs(), bin_factor=st.integers(1, 3), iterations=st.integers(1, 4),
       dark=st.sampled_from([None, "none"]))
def test_valid_inputs_give_documented_image(method, pair, bin_factor, iterations, dark):
    psf, raw = pair
    out = _reconstruct(psf, raw, method, iterations=iterations, bin_factor=bin_factor,
                       dark=dark)
    h, w = raw.shape[0] // bin_factor, raw.shape[1] // bin_factor
    assert out.image.shape == (h, w, *raw.shape[2:])
    assert out.image.dtype == np.float32 and out.estimate.dtype == np.float32
    assert out.estimate.shape[:2] == out.operator.padded_shape
    assert np.all(np.isfinite(out.image)) and np.all(np.isfinite(out.estimate))
    if SOLVERS[method].iterative:  # "non-negative for the iterative methods"
        assert out.image.min() >= 0.0
    assert out.info["iterations"] == (iterations if SOLVERS[method].iterative else 1)
    assert len(out.results) == (1 if raw.ndim == 2 else raw.shape[2])


@pytest.mark.parametrize("method", METHODS)
@FAST
@given(pair=image_pairs(max_side=32, colour=False), scale=st.floats(1e-3, 1e3))
def test_image_is_in_measurement_units(method, pair, scale):
    """Raw x c gives image x c; PSF x c changes nothing (the PSF is normalised to unit
    sum). Without dark subtraction, which would not scale with the raw image."""
    psf, raw = (a.astype(np.float64) for a in pair)
    ref = _reconstruct(psf, raw, method, iterations=3, dark="none").image
    tol = 1e-4 * float(np.abs(ref).max()) + 1e-30
    scaled = _reconstruct(psf, raw * scale, method, iterations=3, dark="none").image
    np.testing.assert_allclose(scaled / scale, ref, rtol=1e-3, atol=tol)
    psf_scaled = _reconstruct(psf * scale, raw, method, iterations=3, dark="none").image
    np.testing.assert_allclose(psf_scaled, ref, rtol=1e-3, atol=tol)


@pytest.mark.parametrize(("argument", "values"), [
    ("iterations", not_counts(1)),
    ("bin_factor", not_counts(1)),
    ("seed", not_counts(0)),
    ("tv", NOT_WEIGHTS),
    ("erase", st.one_of(st.floats(1.0, 1e9), st.floats(max_value=-1e-9),
                        st.sampled_from([float("nan"), float("inf"), "0.5", True, None]))),
])
@pytest.mark.parametrize("method", METHODS)
@FAST
@given(data=st.data())
def test_invalid_numbers_are_refused_naming_them(method, argument, values, data):
    kwargs = {"iterations": 2, argument: data.draw(values)}
    with pytest.raises(ReconInputError) as info:
        _reconstruct(PSF, RAW, method, **kwargs)
    assert_refused(info, argument)  # "erase" is in "erased fraction" too


@pytest.mark.parametrize("which", ["psf", "raw"])
@pytest.mark.parametrize("preprocess", [True, False])
@FAST
@given(name=st.sampled_from(sorted(bad_arrays())))
def test_invalid_arrays_are_refused(which, preprocess, name):
    bad = bad_arrays()[name]
    psf, raw = (bad, RAW) if which == "psf" else (PSF, bad)
    with pytest.raises(ReconInputError) as info:
        _reconstruct(psf, raw, "wiener", preprocess=preprocess)
    assert_refused(info, "PSF" if which == "psf" else "measurement")


@FAST
@given(zero=st.sampled_from(["zeros", "negative"]), preprocess=st.booleans())
def test_psf_without_signal_is_refused(zero, preprocess):
    psf = np.zeros((16, 16)) if zero == "zeros" else -PSF
    with pytest.raises(ReconInputError) as info:
        _reconstruct(psf, RAW, "admm", iterations=2, preprocess=preprocess)
    assert_refused(info, "PSF")


@FAST
@given(h=st.integers(8, 24), w=st.integers(8, 24), dh=st.integers(-3, 3),
       dw=st.integers(-3, 3), preprocess=st.booleans())
def test_shape_mismatch_names_both_shapes(h, w, dh, dw, preprocess):
    if dh == dw == 0:
        dh = 1
    psf = random_array((h, w), np.float64, 3) + 0.1
    raw = random_array((h + dh, w + dw), np.float64, 4)
    with pytest.raises(ReconInputError) as info:
        _reconstruct(psf, raw, "fista", iterations=2, preprocess=preprocess)
    assert_refused(info, str(psf.shape), str(raw.shape))


@pytest.mark.parametrize("method", METHODS)
@FAST
@given(option=st.sampled_from(["step_scale", "penalty", "regularization", "momentum",
                               "bogus"]))
def test_options_a_method_does_not_take_are_refused(method, option):
    if option in solver_options(method):
        return
    with pytest.raises(ReconInputError) as info:
        _reconstruct(PSF, RAW, method, iterations=2, **{option: 1.0})
    assert_refused(info, option, method)


@pytest.mark.parametrize(("method", "option"), [
    ("wiener", "regularization"), ("gd", "step_scale"), ("fista", "step_scale"),
    ("gd", "lipschitz"), ("fista", "lipschitz")])
@FAST
@given(value=NOT_POSITIVE)
def test_invalid_solver_options_are_refused(method, option, value):
    with pytest.raises(ReconInputError) as info:
        _reconstruct(PSF, RAW, method, iterations=2, **{option: value})
    assert_refused(info, option)


@FAST
@given(mu=st.one_of(NOT_POSITIVE, NOT_POSITIVE.map(lambda v: (1e-3, v, 1e-3)),
                    st.sampled_from([(1e-3, 1e-3), "abc", (1, 2, 3, 4)])))
def test_invalid_admm_penalties_are_refused(mu):
    with pytest.raises(ReconInputError) as info:
        _reconstruct(PSF, RAW, "admm", iterations=2, penalty=AdmmPenalty(mu=mu))
    assert_refused(info, "mu")


@FAST
@given(name=st.sampled_from(["complex", "object", "str", "ragged", "one NaN", "1-D"]))
def test_invalid_erasure_masks_are_refused(name):
    with pytest.raises(ReconInputError) as info:
        _reconstruct(PSF, RAW, "fista", iterations=2, erasure_mask=bad_arrays()[name])
    assert_refused(info, "erasure mask")


@pytest.mark.parametrize("method", [m for m in METHODS if SOLVERS[m].iterative])
@FAST
@given(tv=st.floats(1e2, 1e30))
def test_huge_tv_gives_an_image_or_a_divergence_naming_tv(method, tv):
    """The divergence check compares with the zero image's objective, which a TV term
    this large exceeds; then the one-line message must point at the TV weight."""
    try:
        out = _reconstruct(PSF, RAW, method, iterations=5, tv=tv)
    except DivergenceError as exc:
        msg = str(exc)
        assert "\n" not in msg and "TV" in msg
        return
    assert np.all(np.isfinite(out.image)) and out.image.min() >= 0.0

"""Properties of the numeric entry points of the lensless camera model
(:class:`recon.optics.lensless.LenslessModel`): physical PSFs (non-negative, at most the
aperture's solid angle over 4 pi), scenes rendered linearly in radiance, and one-line
:class:`~recon.errors.ReconInputError` for invalid numbers and arrays.

The forward model the solvers use with these PSFs, and its adjoint, is
:class:`recon.operators.ConvolutionOperator` (dot-product tests in
``test_properties_operators.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from recon.errors import ReconInputError
from recon.optics.lensless import LenslessModel, default_geometry

from .test_properties_common import (
    FAST,
    NOT_POSITIVE,
    assert_call_refused,
    assert_refused,
    bad_arrays,
    case_id,
    not_counts,
)

MODEL = LenslessModel(default_geometry(), rays_per_pixel=1.0)
SLOW = settings(FAST, max_examples=10)


@SLOW
@given(x=st.floats(-1.0, 1.0), y=st.floats(-1.0, 1.0), z=st.floats(20.0, 200.0))
def test_psf_is_a_physical_power_fraction(x, y, z):
    psf = MODEL.psf((x, y, z), 1)
    assert psf.shape == MODEL.geometry.sensor_shape and np.all(np.isfinite(psf))
    assert psf.min() >= 0.0 and psf.sum() > 0.0
    aw, ah = MODEL.geometry.aperture_mm  # solid angle <= area / z^2 (r >= z, cos <= 1)
    assert psf.sum() <= aw * ah / (4 * math.pi * z * z) * (1 + 1e-6)


@settings(SLOW, max_examples=6)
@given(seed=st.integers(0, 1000), scale=st.floats(1e-3, 1e3), z=st.floats(25.0, 60.0))
def test_render_is_linear_in_radiance(seed, scale, z):
    scene = np.random.default_rng(seed).random((6, 8))
    ref = MODEL.render(scene, z, 4.0, 1, patches=1)
    assert ref.shape == MODEL.geometry.sensor_shape and ref.min() >= 0.0
    np.testing.assert_allclose(MODEL.render(scene * scale, z, 4.0, 1, patches=1) / scale, ref,
                               rtol=1e-4, atol=1e-6 * float(ref.max()))


@pytest.mark.parametrize(("call", "name", "values"), [
    (lambda v: LenslessModel(MODEL.geometry, v), "rays_per_pixel", NOT_POSITIVE),
    (lambda v: MODEL.magnification(v), "z_mm", NOT_POSITIVE),
    (lambda v: MODEL.psf((0.0, 0.0, v)), "source", NOT_POSITIVE),
    (lambda v: MODEL.psf((0.0, 0.0, 30.0), v), "oversample", not_counts(1)),
    (lambda v: MODEL.render(np.ones((4, 4)), v, 4.0), "z_mm", NOT_POSITIVE),
    (lambda v: MODEL.render(np.ones((4, 4)), 30.0, v), "field of view", NOT_POSITIVE),
    (lambda v: MODEL.render(np.ones((4, 4)), 30.0, 4.0, 1, v), "patches", not_counts(1)),
    (lambda v: MODEL.brightness(0.0, 0.0, 30.0, v), "samples", not_counts(1)),
    (lambda v: default_geometry(seed=v), "seed", not_counts(0)),
], ids=case_id)
@FAST
@given(data=st.data())
def test_invalid_numbers_are_refused_naming_them(call, name, values, data):
    assert_call_refused(call, data.draw(values), name)


@pytest.mark.parametrize("where", ["scene", "points"])
@FAST
@given(name=st.sampled_from(["complex", "object", "str", "ragged", "one NaN", "1-D", "empty"]))
def test_invalid_arrays_are_refused(where, name):
    bad = bad_arrays((4, 4))[name]
    with pytest.raises(ReconInputError) as info:
        if where == "scene":
            MODEL.render(bad, 30.0, 4.0, 1)
        else:
            MODEL.render_points(bad, [1.0])
    assert_refused(info)

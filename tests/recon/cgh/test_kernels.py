"""The hologram optimiser's residual kernels (recon/cgh/_kernels.py) against numpy."""

from __future__ import annotations

import numpy as np

from recon.cgh import _kernels


def _fields(shape=(7, 5), seed=0):
    rng = np.random.default_rng(seed)
    za, zb = ((rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)
              for _ in range(2))
    return za, zb, rng.random(shape).astype(np.float32)


def test_residual_and_combine_residual_match_numpy_and_each_other():
    za, zb, target = _fields()
    a, b, sigma = np.float32(0.3), np.float32(-1.2), np.float32(0.7)
    z = np.empty_like(za)
    out_c = np.empty(za.shape, np.float32)
    rr_c, ri_c = _kernels.combine_residual(a, za, b, zb, z, target, sigma, out_c)
    want_z = a * za + b * zb
    inten = np.abs(want_z) ** 2
    want = sigma * inten - target
    np.testing.assert_allclose(z, want_z, rtol=1e-6)
    np.testing.assert_allclose(out_c, want, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose((rr_c, ri_c), (np.sum(want ** 2), np.sum(want * inten)),
                               rtol=1e-5)
    out_r = np.empty_like(out_c)
    z_before = z.copy()
    assert _kernels.residual(z, target, sigma, out_r) == (rr_c, ri_c)
    np.testing.assert_array_equal(out_r, out_c)
    np.testing.assert_array_equal(z, z_before)  # residual leaves the field alone


def test_the_two_residuals_are_one_compiled_kernel():
    assert hasattr(_kernels._residual_pass, "py_func")
    assert not hasattr(_kernels.residual, "py_func")
    assert not hasattr(_kernels.combine_residual, "py_func")

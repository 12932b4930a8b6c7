"""ScatteringDisplay: adjoint, the box upsampling and centred FFT of Eq. 7.8/7.15,
Fresnel planes (Eq. 7.20 vs 7.22), the bench's mask, and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recon.cgh import ScatteringDisplay, field_from_phase, random_binary_mask
from recon.errors import ReconInputError
from recon.optics.holo_display import MaskModel


def _rand_c(rng, shape):
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)


def _reference_forward(s, mask, k):
    """Eq. 7.8 with Eq. 7.15 in plain numpy: kron upsampling, centred unitary FFT."""
    x = np.kron(s.astype(np.complex128), np.ones((k, k))) * mask
    return np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(x), norm="ortho"))


@pytest.mark.parametrize("planes", [(0.0,), (0.0, 0.4, -0.7)])
@pytest.mark.parametrize("shape,k", [((6, 8), 3), ((5, 7), 2), ((4, 4), 1)])
def test_adjoint(shape, k, planes):
    rng = np.random.default_rng(3)
    d = ScatteringDisplay(shape, k, mask_seed=2, planes_mm=planes, focal_length_mm=20.0)
    s = _rand_c(rng, d.shape_in)
    y = _rand_c(rng, d.shape_out)
    lhs = np.vdot(y.astype(np.complex128), d.forward(s).astype(np.complex128))
    rhs = np.vdot(d.adjoint(y).astype(np.complex128), s.astype(np.complex128))
    assert abs(lhs - rhs) <= 1e-5 * abs(lhs)
    assert d.ffts_per_apply == len(planes)


def test_forward_is_box_upsampling_mask_and_centred_fft():
    rng = np.random.default_rng(0)
    d = ScatteringDisplay((5, 6), 3, mask_seed=4)
    s = _rand_c(rng, d.slm_shape)
    ref = _reference_forward(s, d.mask.astype(np.float64), 3)
    np.testing.assert_allclose(d.forward(s), ref, atol=2e-5 * np.abs(ref).max())
    np.testing.assert_allclose(d.intensity(s), np.abs(ref) ** 2, rtol=1e-4,
                               atol=1e-5 * (np.abs(ref) ** 2).max())


def test_unit_modulus_gives_mean_intensity_one_and_a_flat_plane_wave_focuses():
    d = ScatteringDisplay((8, 10), 2, mask="clear")
    s = np.ones(d.slm_shape, np.complex64)
    inten = d.intensity(s)
    assert inten.mean() == pytest.approx(1.0, rel=1e-5)
    # a flat field through a clear mask is the zero order, at the grid centre
    assert np.unravel_index(np.argmax(inten), inten.shape) == (8, 10)
    assert inten.max() == pytest.approx(inten.sum(), rel=1e-5)  # all power in one sample


def test_mask_is_the_bench_model_mask():
    mm = MaskModel((6, 9), 16.0, k=4, q=1, seed=11, margin=0)
    m = random_binary_mask((6, 9), 4, seed=11)
    np.testing.assert_array_equal(m, mm.model)
    assert set(np.unique(m)) == {-1.0, 1.0}
    assert abs(m.mean()) < 0.15  # random +-1
    d = ScatteringDisplay((6, 9), 4, mask_seed=11)
    np.testing.assert_array_equal(d.mask, m)
    assert d.expansion == 16 and d.mask_pitch_um == 4.0
    np.testing.assert_array_equal(d.mask_energy, np.full((6, 9), 16.0, np.float32))


def test_fresnel_plane_equals_propagating_the_image_field():
    """Eq. 7.22 (quadratic phase on the SLM) equals Eq. 7.20 (P_z F{s m})."""
    rng = np.random.default_rng(5)
    z, f, lam = 0.3, 20.0, 532.0
    d = ScatteringDisplay((6, 8), 2, mask_seed=1, planes_mm=(0.0, z), focal_length_mm=f,
                          wavelength_nm=lam)
    s = _rand_c(rng, d.slm_shape).astype(np.complex128)
    y = d.forward(s)
    gy, gx = d.grid_shape
    u_mm = d.mask_pitch_um * 1e-3
    uy = (np.arange(gy) - gy // 2) * u_mm
    ux = (np.arange(gx) - gx // 2) * u_mm
    h = np.exp(1j * math.pi * z * (uy[:, None] ** 2 + ux[None, :] ** 2) / (lam * 1e-6 * f * f))

    def fc(a):
        return np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(a), norm="ortho"))

    def ifc(a):
        return np.fft.fftshift(np.fft.ifft2(np.fft.ifftshift(a), norm="ortho"))

    # P_z{y0} = F^-1{h F{y0}}: with the centred unitary DFT, F{F{x}} is x reflected,
    # and h(u) = h(-u), so this is F{h x}
    yz = ifc(h * fc(y[0]))
    np.testing.assert_allclose(y[1], yz, atol=1e-4 * np.abs(yz).max())
    # defocus changes the intensity but not the total power
    assert not np.allclose(np.abs(y[1]), np.abs(y[0]), rtol=0.05)
    assert np.sum(np.abs(y[1]) ** 2) == pytest.approx(np.sum(np.abs(y[0]) ** 2), rel=1e-4)


def test_native_window_and_no_mask():
    d = ScatteringDisplay((6, 8), 3)
    rows, cols = d.native_window
    assert (rows.stop - rows.start, cols.stop - cols.start) == (6, 8)
    assert (rows.start + 3, cols.start + 4) == (9, 12)  # centred on the zero order
    nd = ScatteringDisplay.no_mask((6, 8))
    assert nd.k == 1 and nd.grid_shape == (6, 8) and np.all(nd.mask == 1)


def test_field_from_phase():
    p = np.array([[0.0, math.pi / 2], [math.pi, -math.pi / 2]])
    f = field_from_phase(p)
    assert f.dtype == np.complex64
    np.testing.assert_allclose(f, [[1, 1j], [-1, -1j]], atol=1e-6)


@pytest.mark.parametrize("kwargs,msg", [
    (dict(slm_shape=(0, 4)), "slm_shape"),
    (dict(k=0), "k"),
    (dict(k=2.5), "k"),
    (dict(mask=np.ones((3, 3))), "mask grid"),
    (dict(mask=np.full((8, 8), np.nan)), "NaN"),
    (dict(mask="frosted"), "clear"),
    (dict(planes_mm=(0.0, float("inf"))), "finite"),
    (dict(slm_pitch_um=-1), "positive"),
])
def test_bad_construction(kwargs, msg):
    args = dict(slm_shape=(4, 4), k=2)
    args.update(kwargs)
    with pytest.raises(ReconInputError, match=msg):
        ScatteringDisplay(args.pop("slm_shape"), args.pop("k"), **args)


def test_bad_fields():
    d = ScatteringDisplay((4, 4), 2)
    with pytest.raises(ReconInputError, match="shape"):
        d.forward(np.ones((3, 4)))
    with pytest.raises(ReconInputError, match="NaN"):
        d.forward(np.full((4, 4), np.nan))
    with pytest.raises(ReconInputError, match="shape"):
        d.adjoint(np.ones((4, 4)))
    with pytest.raises(ReconInputError, match="real"):
        field_from_phase(np.ones(3, complex))

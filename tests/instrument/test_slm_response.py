"""The virtual bench's physical SLM response: nonlinear, scaled with wavelength, used
by the holography model and unknown to the SLM driver (whose LUT stays linear)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.slm import linear_lut
from instrument.devices.slm_response import SlmPhaseResponse
from instrument.devices.virtual_bench import VirtualBench


def test_default_response_is_smooth_monotone_nonlinear_and_scales_with_wavelength():
    r = SlmPhaseResponse.nonlinear()
    at532 = r.lut_rad(532.0)
    assert at532[0] == 0 and at532[-1] == pytest.approx(2.1 * math.pi)
    assert np.all(np.diff(at532) > 0)
    assert np.abs(at532 - linear_lut()).max() > 0.5  # far from what the software assumes
    np.testing.assert_allclose(r.lut_rad(633.0), at532 * 532 / 633)
    np.testing.assert_array_equal(SlmPhaseResponse.linear().lut_rad(633.0), linear_lut())


@pytest.mark.parametrize("bad", [np.zeros(255), np.r_[np.arange(255.0), 0.0],
                                 np.r_[np.arange(255.0), np.nan]])
def test_bad_tables_and_wavelengths_are_refused(bad):
    with pytest.raises(ValueError, match="256 finite, non-decreasing"):
        SlmPhaseResponse(tuple(bad))
    with pytest.raises(ValueError, match="wavelength"):
        SlmPhaseResponse.nonlinear().lut_rad(0.0)
    with pytest.raises(ValueError, match="gamma"):
        SlmPhaseResponse.nonlinear(gamma=-1)


def test_virtual_bench_renders_through_the_true_response_not_the_drivers_lut():
    with VirtualBench(seed=1) as vb:
        np.testing.assert_array_equal(vb.slm.lut_rad, linear_lut())
        np.testing.assert_allclose(vb.hologram.slm.lut_array,
                                   SlmPhaseResponse.nonlinear().lut_rad(vb.slm.wavelength_nm))
    with VirtualBench(seed=1, slm_response=SlmPhaseResponse.linear()) as vb:
        np.testing.assert_array_equal(vb.hologram.slm.lut_array, linear_lut())
    with pytest.raises(ValueError, match="not both"):
        VirtualBench(hologram=object(), slm_response=SlmPhaseResponse.linear())
    with pytest.raises(ValueError, match="transmission"):
        VirtualBench(nd_filter_transmission=0.0)


def test_nd_filter_attenuates_what_the_camera_sees():
    with VirtualBench(seed=1) as vb:
        vb.set_branch("holography")
        vb.slm.show_image(np.full(vb.slm.resolution, 40, np.uint8))
        bright = vb.irradiance(vb.camera).sum()
        vb.prompt("insert_nd_filter", "ND in")
        assert vb.irradiance(vb.camera).sum() == pytest.approx(0.01 * bright)
        vb.prompt("remove_nd_filter", "ND out")
        assert vb.irradiance(vb.camera).sum() == pytest.approx(bright)

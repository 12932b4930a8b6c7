"""The lateral PSF grid: registered shifts follow m = d/z, the Nyquist check."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from calibration_routines.psf_grid import PsfGridPlan
from instrument.acquisition.plan import PlanError
from instrument.acquisition.runner import Runner
from instrument.runs.runstore import RunStore
from recon.analysis import normalized_correlation


@pytest.mark.parametrize("mode, kw", [("leds", {}), ("stage", {"spacing_mm": 1.5, "z_mm": 40.0})])
def test_registered_shifts_follow_the_magnification(vb, tmp_path, mode, kw):
    plan = PsfGridPlan.for_bench(vb, mode=mode, n=3, frames_per_point=2,
                                 falloff_sigma_deg=20.0, **kw)
    result = Runner(vb).run(plan, tmp_path / f"{mode}.zarr")
    assert result.status == "complete", result.error
    s = result.summary
    d, z = vb.geometry.d_mm, plan.params["z_mm"]
    assert s["magnification_expected"] == pytest.approx(d / z)
    # measured: within 0.2 % (leds, z = 50 mm) and 0.15 % (stage, z = 40 mm)
    assert s["magnification_fit"] == pytest.approx(d / z, rel=0.01)
    assert s["shift_residual_px"] < 0.2
    pitch = vb.geometry.sensor_pitch_um * 1e-3
    pos = np.asarray(s["positions_mm"])
    ref = pos[np.argmin(np.hypot(*pos.T))]
    expected = -(d / z) * (pos - ref)[:, ::-1] / pitch  # (dy, dx) px, inverted image
    np.testing.assert_allclose(s["shifts_px"], expected, atol=0.3)
    assert s["nyquist"]["checked"] and s["nyquist"]["ok"]
    store = RunStore.open(tmp_path / f"{mode}.zarr")
    registered, attrs = store.product("psf_grid_registered")
    raw, _ = store.product("psf_grid")
    c = attrs["reference_index"]
    for k, shift in enumerate(attrs["shifts_px"]):
        if k == c:
            continue
        # registration aligns the caustics (Eq. 5.2) where the shifted PSF has data;
        # what remains is the spatial variance (measured 0.88-0.98)
        valid = ndimage.shift(np.ones(raw[k].shape), -np.asarray(shift), order=0) > 0.5
        assert normalized_correlation(registered[k][valid], registered[c][valid]) > 0.85
        assert normalized_correlation(raw[k][valid], raw[c][valid]) < 0.2
    assert vb.state["pinhole_installed"] and vb.led_array.lit() == {}


def test_nyquist_check_flags_a_sparse_grid_and_reports_unchecked(vb):
    sparse = PsfGridPlan.for_bench(vb, mode="leds", n=3, led_step=7, falloff_sigma_deg=5.0)
    check = sparse.nyquist_check()
    assert check["checked"] and not check["ok"]
    assert check["grid_spacing_mm"] > check["nyquist_spacing_mm"]
    plain = PsfGridPlan.for_bench(vb, mode="leds", n=2)
    assert plain.nyquist_check()["checked"] is False


def test_grid_outside_the_travel_or_array_is_refused(vb):
    with pytest.raises(PlanError, match="travel"):
        PsfGridPlan.for_bench(vb, mode="stage", n=5, spacing_mm=20.0)
    # 20 mm at z = 40 mm shifts the PSF by 20 * 8.9 / 40 = 4.45 mm, the sensor is
    # 256 x 320 px of 13 um: half heights 1.66 mm, so at most 20 * 1.66 / 4.45 mm
    with pytest.raises(PlanError, match=r"4.45 mm along y.*at most 7.48 mm"):
        PsfGridPlan.for_bench(vb, mode="stage", n=3, spacing_mm=20.0)
    with pytest.raises(PlanError, match="no LED"):
        PsfGridPlan.for_bench(vb, mode="leds", n=9, led_step=8)
    with pytest.raises(PlanError, match="mode"):
        PsfGridPlan(mode="cloud", positions_mm=[(0, 0), (1, 0)], z_mm=40, d_mm=8.9,
                    pitch_mm=0.013)

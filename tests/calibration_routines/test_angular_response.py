"""The angular-response plan on the virtual bench: the measured pixel fall-off and
its 20 % cutoff match the simulated ones, the diffuser comes back, positions beyond
the stage travel are refused, and the field of view follows Eq. 3.12.

Tolerances: sigma within 1 % of the simulated one (the virtual bench's bare-sensor
model is exact up to noise and the 16 x 16 px window; measured about 0.05 %); the
fitted cutoff within 1 deg of ``sigma sqrt(2 ln 5)``; the cutoff read off the data
within 1.5 deg (linear interpolation between samples 10 deg apart overestimates
the crossing of the convex Gaussian tail by about 0.7 deg).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from calibration_routines.angular_response import (
    AXIS_CODES,
    AngularResponsePlan,
    reachable_range_mm,
)
from instrument.acquisition.plan import PLAN_TYPES, PlanError, plan_from_record
from instrument.acquisition.runner import Runner
from instrument.devices.virtual_bench import VirtualBench
from instrument.runs.runstore import RunStore
from recon.analysis import fov_half_angle_deg

CUTOFF_FACTOR = math.sqrt(2.0 * math.log(5.0))
FAST = {"n_angles": 11, "frames_per_point": 2}


def _bench(falloff_sigma_deg: float = 20.0, seed: int = 1) -> VirtualBench:
    """A virtual bench with the given pixel fall-off."""
    return VirtualBench(seed=seed, falloff_sigma_deg=falloff_sigma_deg)


def _run(vb: VirtualBench, path, **params):
    with vb:
        plan = AngularResponsePlan.for_bench(vb, **params)
        result = Runner(vb).run(plan, path)
        lit = vb.led_array.lit()
    return plan, result, lit


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    vb = _bench()
    path = tmp_path_factory.mktemp("angular") / "ar.zarr"
    plan, result, lit = _run(vb, path, **FAST)
    return vb, plan, result, lit, path


def test_measured_falloff_matches_the_simulated_sigma_and_cutoff(default_run):
    vb, plan, result, lit, path = default_run
    assert result.status == "complete", result.error
    truth = vb.geometry.falloff_sigma_deg
    assert truth == 20.0
    for axis in ("x", "y"):
        fit = result.summary["axes"][axis]
        assert fit["sigma_deg"] == pytest.approx(truth, rel=0.01)
        assert abs(fit["cutoff_deg"] - truth * CUTOFF_FACTOR) < 1.0
        assert abs(fit["cutoff_measured_deg"] - truth * CUTOFF_FACTOR) < 1.5
        assert fit["amplitude"] == pytest.approx(1.0, abs=0.02)


def test_diffuser_back_leds_off_and_the_product_is_complete(default_run):
    vb, plan, result, lit, path = default_run
    assert vb.state["diffuser_installed"] and vb.state["pinhole_installed"]
    assert lit == {}
    store = RunStore.open(path)
    table, attrs = store.product("angular_response")
    n = 2 * FAST["n_angles"]
    assert table.shape == (n, 4) and table.dtype == np.float64
    assert attrs["columns"] == ["axis_code", "angle_deg", "intensity_normalised", "corrected"]
    assert set(table[:, 0]) == {AXIS_CODES["x"], AXIS_CODES["y"]}
    np.testing.assert_allclose(table[: n // 2, 1], np.linspace(-50, 50, FAST["n_angles"]))
    # the cos^3 correction only raises oblique points; normal incidence is ~1
    theta = np.radians(table[:, 1])
    np.testing.assert_allclose(table[:, 3], table[:, 2] / np.cos(theta) ** 3)
    assert table[:, 3].max() == pytest.approx(1.0)
    # the stage went where the plan said: x = (z + d) tan(theta)
    coords = store.coords_table()
    x = coords["source_stage.x"][store.frame_range(0).start]
    assert x == pytest.approx(-(10.0 + 8.9) * math.tan(math.radians(50.0)))
    json.dumps(result.summary)


def test_field_of_view_follows_eq_3_12(default_run):
    vb, plan, result, lit, path = default_run
    geo = vb.config.geometry
    pitch = geo.sensor_pixel_pitch_um * 1e-3
    rows, cols = geo.sensor_shape_px
    widths = {"x": (cols * pitch, geo.aperture_mm[0]), "y": (rows * pitch, geo.aperture_mm[1])}
    for axis, (sensor, psf) in widths.items():
        fit = result.summary["axes"][axis]
        expect = fov_half_angle_deg(fit["cutoff_deg"], beta_deg=0.0, sensor_width_mm=sensor,
                                    psf_width_mm=psf, d_mm=geo.diffuser_sensor_distance_mm)
        assert fit["fov_half_angle_deg"] == pytest.approx(expect)
        assert 0 < fit["fov_half_angle_deg"] <= fit["cutoff_deg"]
        geometric = math.degrees(math.atan((sensor + psf) / (2 * 8.9)))
        assert fit["geometric_limit_deg"] == pytest.approx(geometric)
        # the default bench's sensor accepts wider angles than its geometry passes
        assert fit["fov_limited_by"] == "geometry"
    assert 10 < result.summary["axes"]["y"]["fov_half_angle_deg"] < \
        result.summary["axes"]["x"]["fov_half_angle_deg"] < 30
    assert result.summary["beta_measured"] is False


def test_a_narrower_falloff_is_measured_too(tmp_path):
    vb = _bench(falloff_sigma_deg=10.0, seed=4)
    _, result, _ = _run(vb, tmp_path / "narrow.zarr", axes=["x"], max_angle_deg=40.0, **FAST)
    assert result.status == "complete", result.error
    assert set(result.summary["axes"]) == {"x"}
    fit = result.summary["axes"]["x"]
    assert fit["sigma_deg"] == pytest.approx(10.0, rel=0.01)
    assert abs(fit["cutoff_deg"] - 10.0 * CUTOFF_FACTOR) < 1.0
    # a cutoff of 17.9 deg is below the geometric 21.0 deg: the sensor limits the FoV
    assert fit["fov_limited_by"] == "sensor cutoff"
    assert fit["fov_half_angle_deg"] == pytest.approx(fit["cutoff_deg"])


def test_positions_beyond_the_stage_travel_are_refused():
    with VirtualBench(seed=1) as vb:
        reach = reachable_range_mm(vb.source_stage)
        assert reach["x"] == (-25.0, 25.0)
        # (10 + 8.9) tan(60 deg) = 32.7 mm > 25 mm
        with pytest.raises(PlanError, match="lower max_angle_deg to 52.9 deg"):
            AngularResponsePlan.for_bench(vb, max_angle_deg=60.0)
        with pytest.raises(PlanError, match="in front of the diffuser"):
            AngularResponsePlan.for_bench(vb, z_mm=-5.0)
        with pytest.raises(PlanError, match="z range"):
            AngularResponsePlan.for_bench(vb, z_mm=300.0)
        # soft limits and backlash narrow the reach
        vb.source_stage.limits = {"y": (-10.0, 10.0)}
        vb.source_stage.backlash = {"x": 1.0}
        reach = reachable_range_mm(vb.source_stage)
        assert reach["x"] == (-24.0, 25.0) and reach["y"] == (-10.0, 10.0)
        with pytest.raises(PlanError, match="along y"):
            AngularResponsePlan.for_bench(vb)
        AngularResponsePlan.for_bench(vb, axes=["x"])


def test_parameters_are_json_and_rebuild_the_plan():
    with VirtualBench(seed=1) as vb:
        plan = AngularResponsePlan.for_bench(vb, n_angles=5)
    assert PLAN_TYPES["angular-response"] is AngularResponsePlan
    params = json.loads(json.dumps(plan.params))
    again = plan_from_record("angular-response", params)
    assert [p.coords for p in again.points()] == [p.coords for p in plan.points()]
    assert len(plan.points()) == 10 and plan.params["d_mm"] == 8.9
    assert plan.params["psf_width_mm"] == {"x": 2.67, "y": 2.11}
    assert plan.params["sensor_width_mm"] == pytest.approx({"x": 4.16, "y": 3.328})


@pytest.mark.parametrize("bad, match", [
    ({"axes": ["z"]}, "axes"), ({"n_angles": 2}, "at least 3"),
    ({"max_angle_deg": 90.0}, "max_angle_deg"), ({"frames_per_point": 0}, "frames_per_point"),
    ({"d_mm": 0.0}, "d_mm"), ({"psf_width_mm": {"x": 1.0}}, "psf_width_mm"),
])
def test_bad_parameters_are_refused(bad, match):
    with pytest.raises(PlanError, match=match):
        AngularResponsePlan(**{"d_mm": 8.9, **bad})

"""holo_bench: the mask retracted and put back whatever happens; the holography
branch and the ND filter for far-field measurements."""

from __future__ import annotations

import numpy as np
import pytest

from calibration_routines.holo_bench import (
    far_field_setup,
    holography_branch,
    retract_distance_mm,
    retracted_mask,
)
from drivers.errors import StageTimeoutError
from instrument.acquisition.plan import PlanError
from instrument.devices.bench import Bench

POSE = {"x": 0.02, "y": -0.01, "z": 0.05, "tip": 0.1, "tilt": -0.1, "rotation": 0.5}


@pytest.fixture
def holo(vb):
    vb.set_branch("holography")
    vb.mask_stage.move_to(POSE)
    return vb


def _zero_order_share(vb):
    vb.slm.show_image(np.zeros(vb.slm.resolution, np.uint8))
    img = vb.irradiance(vb.camera)
    return float(img.max() / img.sum())


def test_retract_distance_is_footprint_plus_overhang_and_clearance(vb):
    assert retract_distance_mm(vb) == pytest.approx(120 * 8e-3 + 0.1 + 0.25)
    assert retract_distance_mm(vb, "y", overhang_mm=0, clearance_mm=0) == pytest.approx(
        96 * 8e-3)
    with pytest.raises(PlanError, match="'x' or 'y'"):
        retract_distance_mm(vb, "z")


def test_retracted_mask_clears_the_footprint_and_returns(holo):
    scattered = _zero_order_share(holo)
    with retracted_mask(holo) as out:
        assert holo.mask_stage.positions() == pytest.approx(out.retracted_pose)
        assert out.shift_mm == pytest.approx(1.31) and out.axis == "x"
        assert _zero_order_share(holo) > 0.999  # clear substrate: one unscattered spot
    assert scattered < 0.05
    assert holo.mask_stage.positions() == pytest.approx(POSE)
    assert out.home_pose == pytest.approx(POSE)


def test_retracted_mask_returns_the_stage_on_error(holo):
    with pytest.raises(RuntimeError, match="inside"), retracted_mask(holo, axis="y"):
        assert holo.mask_stage.position("y") == pytest.approx(POSE["y"] + 1.118)
        raise RuntimeError("inside the block")
    assert holo.mask_stage.positions() == pytest.approx(POSE)


def test_retraction_goes_the_other_way_near_the_limit_or_refuses(holo):
    holo.mask_stage.move_to({"x": 4.5})
    with retracted_mask(holo) as out:
        assert out.shift_mm == pytest.approx(-1.31)
    holo.mask_stage.limits = {"x": (3.0, 5.0)}
    holo.mask_stage.move_to({"x": 4.0})
    with pytest.raises(PlanError, match="cannot retract"), retracted_mask(holo):
        pass
    assert holo.mask_stage.position("x") == 4.0
    with pytest.raises(PlanError, match="distance_mm"), retracted_mask(holo, distance_mm=-1):
        pass
    with pytest.raises(PlanError, match="cannot retract the mask"), \
            retracted_mask(holo, stage="no_such_stage"):
        pass


def test_failed_return_is_noted_on_the_original_error(holo, monkeypatch):
    stage = holo.mask_stage
    with pytest.raises(RuntimeError) as info, retracted_mask(holo):
        def stuck(*args, **kwargs):
            raise StageTimeoutError(stage.device_id, "motion not finished", "check it")
        monkeypatch.setattr(stage, "move_to", stuck)
        raise RuntimeError("camera failed")
    assert "could not return" in " ".join(info.value.__notes__)


def test_far_field_setup_inserts_the_nd_filter_and_restores_everything(vb):
    vb.mask_stage.move_to(POSE)
    assert vb.branch == "lensless"
    with pytest.raises(KeyError), far_field_setup(vb):
        assert vb.branch == "holography" and vb.state["nd_filter_installed"]
        assert vb.mask_stage.position("x") == pytest.approx(POSE["x"] + 1.31)
        raise KeyError("boom")
    assert vb.branch == "lensless" and not vb.state["nd_filter_installed"]
    assert vb.mask_stage.positions() == pytest.approx(POSE)


def test_holography_branch_is_a_no_op_on_a_real_bench():
    bench = Bench({})
    with holography_branch(bench):
        pass

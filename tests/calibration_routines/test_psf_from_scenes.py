"""calibrate psf-from-scenes: from files (a run recon takes) and on the simulated bench
(the display shows the scenes, the virtual bench images them through the diffuser)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from calibration_routines._common import CALIBRATION_EXPOSURE, signal_minus_dark
from calibration_routines.psf_from_scenes import (
    MAX_RANDOM,
    RECIPE_IMAGES,
    PsfFromScenesPlan,
    display_gray,
    pattern_block_px,
)
from instrument.acquisition.exposure import autoexpose
from instrument.acquisition.plan import PlanError
from instrument.cli import main
from instrument.devices.bench_setup import load_bench
from instrument.devices.virtual_bench import DisplayScene, VirtualBench
from instrument.runs.runstore import RunStore
from recon.analysis import normalized_correlation
from recon.early_stop import EarlyStop, psf_identity
from recon.scenes import BUNDLED, load_scene

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "bench-simulated.toml"


def _small_bench(tmp_path) -> Path:
    """The simulated bench at 64 x 80 pixels of 39 um (three quarters of its field):
    fast; its SLM, the display, with pixels of 40 um (a 4.8 mm panel, at 20 mm 55
    sensor pixels wide: scenes with detail on the sensor grid)."""
    text = EXAMPLE.read_text().replace("[256, 320]", "[64, 80]").replace(
        "pixel_pitch_um = 13.0", "pixel_pitch_um = 39.0").replace(
        "pixel_pitch_um = 8.0", "pixel_pitch_um = 40.0")
    path = tmp_path / "bench-small.toml"
    path.write_text(text)
    return path


def test_the_display_is_a_scene_of_the_imaging_branch(tmp_path):
    """What the display shows reaches the camera through the diffuser, and a new
    pattern gives a new image (not the render cache's old one)."""
    with VirtualBench(load_bench(_small_bench(tmp_path))) as vb:
        vb.set_scene(DisplayScene(20.0, "slm"))
        shape = vb.slm.resolution
        vb.slm.show_image(np.zeros(shape, np.uint8))
        dark = vb.irradiance(vb.camera).copy()
        vb.slm.show_image(np.full(shape, 255, np.uint8))
        bright = vb.irradiance(vb.camera).copy()
        vb.slm.show_image((load_scene("camera", shape) * 255).astype(np.uint8))
        scene = vb.irradiance(vb.camera).copy()
    assert not np.any(dark) and bright.sum() > 0
    assert 0 < scene.sum() < bright.sum()


def test_calibrate_on_the_simulated_bench_recovers_its_psf(tmp_path, capsys):
    """With its defaults (12 random binary patterns, the bench file's 4 frames a
    scene) the PSF correlates >= 0.95 with the ray-traced on-axis PSF at the display's
    depth: the PSF the simulator renders the display's centre with (its 3 x 3 regions
    of the local convolution model change the estimate by 0.002; 0.963 measured).
    Before, 4 photographs and the scenes placed half a pixel off the axis gave 0.77."""
    bench = _small_bench(tmp_path)
    out = tmp_path / "scenes.zarr"
    code = main(["calibrate", "psf-from-scenes", str(bench), "--simulate", "--z-mm", "20",
                 "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    psf, attrs = RunStore.open(out).product("psf_stack")
    assert psf.shape == (1, 64, 80) and attrs["depths_mm"] == [20.0] and psf.min() >= 0
    with VirtualBench(load_bench(bench)) as vb:
        truth = vb.psf((0.0, 0.0, 20.0))
    correlation = normalized_correlation(psf[0], truth)
    assert correlation >= 0.95
    # half a pixel off, the scene's centring against the PSF's, and it falls well below
    for shift in ((0.5, 0.0), (0.0, 0.5)):
        moved = ndimage.shift(truth, shift, order=3, mode="constant")
        assert normalized_correlation(psf[0], moved) < correlation - 0.05
    summary = RunStore.open(out).attrs["summary"]
    assert set(summary["held_out_residual"]) == {f"random-{k}" for k in range(12)}
    # the recipe is fitted on photographs shown after the patterns, not on the patterns
    recipe = EarlyStop.load(out)
    assert recipe.pairs == tuple(BUNDLED[:RECIPE_IMAGES])
    assert recipe.psf_sha256 == psf_identity(psf[0]) and recipe.errors.shape[-1] == 4
    capsys.readouterr()
    assert main(["runs", "verify", str(out)]) == 0
    assert "intact" in capsys.readouterr().out


def test_the_patterns_are_binary_blocks_of_about_one_sensor_pixel(tmp_path):
    """Random patterns (reproducible from their names) in blocks of one object-grid
    cell on the display (39 um pixels at 20 mm over 8.9 mm: 88 um, 2 display pixels
    of 40 um), half white; photographs on request; counts out of range refused."""
    with VirtualBench(load_bench(_small_bench(tmp_path))) as vb:
        plan = PsfFromScenesPlan.for_bench(vb, z_mm=20.0)
        photos = PsfFromScenesPlan.for_bench(vb, z_mm=20.0, images=3, patterns="photographs")
        for kwargs, words in [({"images": MAX_RANDOM + 1}, "from 2 to 256"),
                              ({"recipe_images": 1}, "--recipe-images 1"),
                              ({"images": 9, "patterns": "photographs", "recipe_images": 4},
                               "from 2 to 3"),
                              ({"images": 13, "patterns": "photographs"}, "from 2 to 12"),
                              ({"patterns": "stripes"}, "--patterns 'stripes'")]:
            with pytest.raises(PlanError, match=re.escape(words)):
                PsfFromScenesPlan.for_bench(vb, z_mm=20.0, **kwargs)
    assert plan.params["scene_names"] == [f"random-{k}" for k in range(12)]
    assert photos.params["scene_names"] == ["camera", "astronaut", "coffee"]
    assert plan.params["recipe_scenes"] == list(BUNDLED[:RECIPE_IMAGES])
    assert photos.params["recipe_scenes"] == []  # fitted on the photographs themselves
    assert len(plan.points()) == 12 + RECIPE_IMAGES
    assert plan.block_px() == pattern_block_px(20.0, 8.9, 0.039, 40.0) == 2
    gray = display_gray("random-5", (96, 120), 2)
    assert gray.dtype == np.uint8 and set(np.unique(gray)) == {0, 255}
    np.testing.assert_array_equal(gray, display_gray("random-5", (96, 120), 2))
    assert not np.array_equal(gray, display_gray("random-6", (96, 120), 2))
    blocks = gray.reshape(48, 2, 60, 2)
    assert np.all(blocks == blocks[:, :1, :, :1])  # constant over each 2 x 2 block
    assert 0.45 < (gray > 0).mean() < 0.55
    with pytest.raises(PlanError, match="random-<k>"):
        PsfFromScenesPlan(scene_names=["random-1", "random-x"], z_mm=20.0,
                          display_shape=(96, 120), display_pitch_um=40.0, d_mm=8.9,
                          pitch_mm=0.039)


def test_the_built_in_display_at_100_mm_is_bright_enough_to_auto_expose():
    """The built-in bench's display (a 0.96 mm SLM) at 100 mm showing a random
    pattern reaches the calibration's auto-exposure target (40-80 % of full scale)
    well inside the bench file's exposure cap of 1 s. Before, at the radiance of a lit
    scene, its peak was 2-3 % of full scale at the 1 s cap (ExposureError)."""
    with VirtualBench(load_bench(EXAMPLE)) as vb:
        vb.set_scene(DisplayScene(100.0, "slm"))
        plan = PsfFromScenesPlan.for_bench(vb, z_mm=100.0, images=2, recipe_images=0)
        vb.slm.show_image(display_gray("random-0", vb.slm.resolution, plan.block_px()))
        a, bounds = CALIBRATION_EXPOSURE, vb.config.calibration.exposure_bounds_s
        result = autoexpose(vb.camera, target=a.target, tolerance=a.tolerance,
                            bounds_s=tuple(bounds))
    assert bounds[1] == 1.0 and result.exposure_s <= 0.5 * bounds[1]
    assert abs(result.peak_fraction - a.target) <= a.tolerance


def test_calibrate_at_100_mm_exposes_each_scene_brightly_without_a_cap_warning(
        tmp_path, capsys):
    """The simulated calibration at 100 mm (2 patterns, 1 frame, the small bench):
    no exposure warning in the run and each scene's dark-subtracted peak at 40 % of
    full scale or more, exposed under half the 1 s cap (before: 0.43 at the cap)."""
    out = tmp_path / "far.zarr"
    code = main(["calibrate", "psf-from-scenes", str(_small_bench(tmp_path)), "--simulate",
                 "--z-mm", "100", "--images", "2", "--recipe-images", "0", "--frames", "1",
                 "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    store = RunStore.open(out)
    assert not store.attrs.get("warnings")
    for point in range(store.n_points):
        _, exposure_s, peak = signal_minus_dark(store, point, "scene", "dark")
        assert peak >= 0.4 and exposure_s <= 0.5

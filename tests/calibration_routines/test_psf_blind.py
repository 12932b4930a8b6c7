"""``diffuserlab calibrate psf-blind`` (Sec. 5.4) on the virtual microscope's bead slide."""

from pathlib import Path

import numpy as np
import pytest

from calibration_routines import PsfBlindPlan
from instrument.cli import main
from instrument.devices.bench_setup import load_bench
from instrument.devices.virtual_bench import VirtualBench
from instrument.processing.reconstruct_grid import load_psf_grid
from instrument.runs.runstore import RunStore

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "bench-microscope.toml"


def _small_bench(tmp_path) -> Path:
    """The microscope binned 16 x 16 (68 x 120 at 46.4 um): the same optics, fast."""
    text = EXAMPLE.read_text().replace("[135, 240]", "[68, 120]").replace(
        "pixel_pitch_um = 23.2", "pixel_pitch_um = 46.4")
    path = tmp_path / "bench-microscope-small.toml"
    path.write_text(text)
    return path


def test_plan_takes_darks_then_the_slide_at_random_offsets(tmp_path):
    with VirtualBench(load_bench(_small_bench(tmp_path))) as vb:
        plan = PsfBlindPlan.for_bench(vb, n_images=3, z_mm=2.4, grid=3, node_spacing_mm=0.5,
                                      exposure_s=2e-3, seed=4)
    points = plan.points()
    assert [p.tags[0] for p in points] == ["dark", "beads", "beads", "beads"]
    offsets = np.array(plan.params["offsets_mm"])
    assert offsets.shape == (3, 2) and np.abs(offsets).max() <= 0.5
    again = PsfBlindPlan.for_bench(vb, n_images=3, z_mm=2.4, grid=3, node_spacing_mm=0.5,
                                   exposure_s=2e-3, seed=4)
    assert again.params == plan.params  # seeded: a resumed run rebuilds the same plan


@pytest.mark.slow
def test_calibrate_psf_blind_writes_a_grid_recon_can_use(tmp_path, capsys):
    """About a minute on 2 shared cores (tracing the slide's beads, 3 rounds)."""
    bench = _small_bench(tmp_path)
    out = tmp_path / "blind.zarr"
    code = main(["calibrate", "psf-blind", str(bench), "--simulate", "--z-mm", "2.4",
                 "--node-spacing-mm", "0.5", "--exposure-s", "2e-3", "--images", "3",
                 "--grid", "3", "--frames", "1", "--rounds", "3", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    store = RunStore.open(out)
    images, _ = store.product("bead_images")
    assert images.shape == (3, 68, 120) and images.max() > 0  # the slide moved: 3 images
    assert not np.allclose(images[0], images[1])
    grid = load_psf_grid(out)
    assert grid.grid_shape == (3, 3) and grid.z_mm == 2.4 and grid.d_mm == 3.8
    summary = store.attrs["summary"]
    assert summary["misfit_psfs"][-1] < summary["misfit_objects"][0]

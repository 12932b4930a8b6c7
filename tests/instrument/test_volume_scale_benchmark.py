"""``diffuserlab benchmark volume-scale`` at a small size: the generated problem, the
figures it reports, and its single-process and 2-worker runs agreeing.

The seed-size run (2048 x 2048 x 128, ~17 GB) is for the command line; here 64 x 64
x 8 checks that the generated stack is what the solvers read (a per-plane Zarr store
in a temporary directory, gone afterwards), that the peak memory, FFT floor and
bytes per worker are reported, and that the sharded run equals the single process.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from instrument.benchmarks.volume_scale import run_volume_scale, volume_scale_table
from instrument.benchmarks.volume_scale_scenes import (
    BEAD_LIGHT_512,
    axial_resolution_planes,
    bead_light,
    objects_at_depth,
    scene_objects,
    stack_depths_mm,
    write_psf_store,
)
from instrument.cli import main
from recon.errors import ReconInputError
from recon.io import load_image
from recon.sample import PSF_FILE, data_dir


def test_generated_stack_is_depth_scaled(tmp_path):
    zarr = pytest.importorskip("zarr")
    scale, depths = write_psf_store(str(tmp_path / "s.zarr"), load_image(data_dir() / PSF_FILE),
                                    96, 6)
    store = zarr.open_array(str(tmp_path / "s.zarr"), mode="r")
    assert store.shape == (6, 96, 96) and store.chunks == (1, 96, 96)
    sums = np.array([float(store[k].sum(dtype=np.float64)) for k in range(6)])
    assert scale == pytest.approx(np.sqrt(np.sum(sums**2)), rel=1e-6)
    assert np.all(np.diff(depths) > 0) and np.all(np.diff(sums) < 0)  # farther: dimmer
    np.testing.assert_allclose(depths, stack_depths_mm(96, 6))
    # a farther plane is the nearer one shrunk: its light sits closer to the centre
    c = np.arange(96) - 47.5
    r = np.hypot(*np.meshgrid(c, c, indexing="ij"))
    spread = [float((store[k] * r).sum() / store[k].sum()) for k in (0, 5)]
    assert spread[1] < spread[0]


def test_objects_at_depth_scores_the_truth():
    objects = scene_objects(128, 8, beads=4, extended=2, seed=3)
    vol = np.zeros((8, 128, 128), np.float32)
    for o in objects:
        vol[o.plane, int(round(o.row)), int(round(o.col))] = 1.0
    assert objects_at_depth(vol, objects)["found"] == len(objects)
    moved = vol[::-1].copy()  # every object moved to the mirrored plane
    far = [o for o in objects if abs((7 - o.plane) - o.plane) > 1]
    assert objects_at_depth(moved, objects)["found"] <= len(objects) - len(far)


def _light_shares(n: int, light: float | None = None) -> float:
    """The beads' share of the scene's light at sensor side ``n``."""
    rng = np.random.default_rng(0)
    objects = scene_objects(n, 8, light=light)
    light = {"bead": 0.0, "other": 0.0}
    for o in objects:
        light["bead" if o.kind == "bead" else "other"] += float(o.patch(rng)[0].sum())
    return light["bead"] / (light["bead"] + light["other"])


def test_the_scene_is_the_same_at_every_sensor_size():
    """A bead keeps its share of the scene's light as the sensor is sampled more finely
    (the discs' radii grow with n, so a bead's light grows as n^2); with the fixed light
    of earlier runs the beads' share fell about 16-fold from 512 to 2048."""
    assert bead_light(512) == BEAD_LIGHT_512 and bead_light(2048) == 16 * BEAD_LIGHT_512
    shares = [_light_shares(n) for n in (512, 1024, 2048)]
    assert max(shares) / min(shares) < 1.25, shares
    fixed = [_light_shares(n, BEAD_LIGHT_512) for n in (512, 2048)]
    assert fixed[0] == pytest.approx(shares[0]) and fixed[1] < fixed[0] / 5
    # the light changes nothing else: same kinds, planes and positions
    a, b = scene_objects(512, 8), scene_objects(512, 8, light=3.0)
    assert [(o.kind, o.plane, o.row, o.col, o.radius) for o in a] == [
        (o.kind, o.plane, o.row, o.col, o.radius) for o in b]
    assert {o.light for o in b} == {3.0}
    for bad in (0.0, -1.0, float("nan"), "bright"):
        with pytest.raises(ReconInputError, match="light must be"):
            scene_objects(512, 8, light=bad)


def test_objects_within_one_resolution_take_its_planes_as_slack():
    objects = scene_objects(128, 8, beads=4, extended=2, seed=3)
    vol = np.zeros((8, 128, 128), np.float32)
    for o in objects:  # every object two planes off (nearer where it can)
        vol[o.plane - 2 if o.plane >= 2 else o.plane + 2, int(round(o.row)),
            int(round(o.col))] = 1.0
    r = objects_at_depth(vol, objects, resolution_planes=[2.5] * 8)
    assert r["found"] == 0 and r["found_within_resolution"] == len(objects)
    assert sum(v[0] for v in r["by_kind_within_resolution"].values()) == len(objects)
    r = objects_at_depth(vol, objects, resolution_planes=[1.5] * 8)
    assert r["found_within_resolution"] == 0
    assert "found_within_resolution" not in objects_at_depth(vol, objects)


def test_one_axial_resolution_spans_more_planes_on_a_finer_stack(tmp_path):
    """The stack's planes are a fixed rim shift apart while the caustic's lines widen
    with the sensor, so a larger sensor puts more planes in one resolution; the near
    planes are resolved more coarsely in 1/z than the far ones (Eq. 4.7)."""
    zarr = pytest.importorskip("zarr")
    psf = load_image(data_dir() / PSF_FILE)
    spans = []
    for n, n_z in ((128, 8), (256, 16)):
        _, depths = write_psf_store(str(tmp_path / f"{n}.zarr"), psf, n, n_z)
        ax = axial_resolution_planes(zarr.open_array(str(tmp_path / f"{n}.zarr"), mode="r"),
                                     depths)
        assert len(ax["planes"]) == n_z and [m["plane"] for m in ax["measured"]] == [
            0, n_z // 2, n_z - 1][:len(ax["measured"])]
        steps = [m["step_per_mm"] for m in ax["measured"]]
        assert steps[0] > steps[-1] > 0
        spans.append(float(np.median(ax["planes"])))
    assert spans[1] > 1.3 * spans[0]


@pytest.mark.filterwarnings("error::RuntimeWarning")  # a stack with repeated depths is said
def test_single_and_sharded_runs_agree(tmp_path):
    one = run_volume_scale(sensor=64, planes=8, iterations=3, workers=0,
                           save_estimate=str(tmp_path / "x.npy"), announce=lambda s: None)
    assert 0 < one["peak_rss_bytes"] and 0 < one["memory_estimate_bytes"]
    assert one["fft_floor_seconds"] > 0 and one["ratio_to_fft_floor"] > 0
    assert one["bytes_moved_per_worker_per_iteration"] == [0.0]
    two = run_volume_scale(sensor=64, planes=8, iterations=3, workers=2, worker_memory="1GB",
                           compare_with=str(tmp_path / "x.npy"), announce=lambda s: None)
    assert two["relative_difference_to"]["relative"] < 1e-5
    sensor = 4 * 64 * 64
    # partial image up, residual down, 3 boundary planes between the two slabs
    assert two["bytes_moved_per_worker_per_iteration"] == [5 * sensor, 5 * sensor]
    assert len(two["peak_rss_bytes_per_worker"]) == 2
    text = volume_scale_table(two)
    assert "LocalCluster of 2 workers" in text and "relative difference" in text


def test_command_writes_its_figures(tmp_path, capsys):
    out = tmp_path / "vs.json"
    assert main(["benchmark", "volume-scale", "--sensor", "48", "--planes", "4",
                 "--iterations", "2", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "estimated peak memory" in text and "x the streamed FFT floor" in text
    figures = json.loads(out.read_text())
    assert figures["planes"] == 4 and figures["bead_light"] == pytest.approx(bead_light(48))
    assert main(["benchmark", "volume-scale", "--planes", "1"]) == 2
    assert main(["benchmark", "volume-scale", "--bead-light", "0"]) == 2
    assert "--bead-light 0.0: give a positive light" in capsys.readouterr().err

"""``diffuserlab recon-run --psf-grid``: a neuron video recorded on the virtual diffuser
microscope, reconstructed in batch with the local convolution model, and its ΔF/F."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from calibration_routines import PsfGridPlan
from instrument.acquisition.runner import Runner
from instrument.acquisition.video import record_video
from instrument.cli import main
from instrument.devices.bench_scenes import scene_depth_and_scale, video_scene_for_bench
from instrument.devices.bench_setup import load_bench
from instrument.devices.virtual_bench import VirtualBench
from instrument.runs.runstore import RunStore
from recon.analysis import delta_f_over_f
from recon.io import load_image

from .test_batch import assert_same_frame

BENCH = Path(__file__).resolve().parents[2] / "examples" / "bench-microscope.toml"
BIN = 3  # 45 x 80 frames
FRAMES = 30


@pytest.fixture(scope="module")
def scheduler():
    """Address of a two-worker local dask cluster."""
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0", host="127.0.0.1") as c:
        yield c.scheduler_address


@pytest.fixture(scope="module")
def microscope_video(tmp_path_factory):
    """A 30-frame, 10 fps neuron video and a 3 x 3 PSF grid at the neurons' depth, both
    from the virtual microscope; the scene and the geometry for the truth."""
    d = tmp_path_factory.mktemp("microscope")
    with VirtualBench(load_bench(BENCH), seed=2) as vb:
        scene = dataclasses.replace(video_scene_for_bench("neurons", vb, seed=3), n_cells=6,
                                    spike_rate_hz=0.6, duration_s=4.0)
        vb.led_array.all_off()
        vb.set_scene(scene)
        vb.prerender([0.0])
        record_video(vb, d / "neurons.zarr", frames=FRAMES, fps=10.0, exposure_s=0.01,
                     shard_frames=16, simulated={"scene": "neurons",
                                                 "dark_offset_dn": vb.camera.dark_offset_dn})
        vb.set_scene(None)  # then the calibration: the bead on the stage, lit by the LEDs
        plan = PsfGridPlan.for_bench(vb, mode="stage", n=3, spacing_mm=0.6, z_mm=scene.z_mm,
                                     frames_per_point=1)
        Runner(vb).run(plan, d / "grid.zarr")
        geometry = vb.geometry
    return d, scene, geometry


def test_microscope_scenes_sit_in_its_calibrated_range_and_field():
    with VirtualBench(load_bench(BENCH)) as vb:
        z, scale = scene_depth_and_scale(vb)
        cells = video_scene_for_bench("neurons", vb).positions_mm
        flow = video_scene_for_bench("beads-flow", vb)
    assert 1.7 < z < 3.0 and 0.5 < scale < 1.0
    assert np.abs(cells[:, 0]).max() < 0.65 and np.all(cells[:, 2] == z)
    assert flow.z_mm == z and flow.period_s == pytest.approx(4.0)  # same renders a period
    with VirtualBench() as vb:  # the default bench keeps the scene classes' defaults
        assert scene_depth_and_scale(vb) == (20.0, 1.0)


@pytest.mark.slow
def test_dff_of_a_microscope_neuron_video_with_the_local_model(microscope_video, scheduler,
                                                               capsys):
    """Each active cell's ΔF/F (20th-percentile baseline, Fig. 6.5b) from the batch's
    local-model frames correlates with its true trace above 0.9 (measured: 0.98 to
    0.999 over the six cells); the product stores the model and a background per
    frame. 24 s on 2 idle cores, 1.5 to 2 minutes on busy ones (recording, 3 x 3
    calibration, 30 frames), hence slow; test_batch_grid_frames_equal_recon_psf_grid_of_each_frame
    covers the batch path in the default run."""
    d, scene, g = microscope_video
    run = str(d / "neurons.zarr")
    argv = ["recon-run", run, "--psf-grid", str(d / "grid.zarr"), "--model", "local",
            "--bin", str(BIN), "--iterations", "30", "--scheduler", scheduler, "--dff", "20"]
    assert main(argv) == 0
    assert "local model (9 convolutions per apply" in capsys.readouterr().out
    store = RunStore.open(run)
    movie, attrs = store.product("recon_grid_local")
    background, _ = store.product("recon_grid_local_background")
    dff, _ = store.product("recon_grid_local_dff")
    assert attrs["model"] == "local" and attrs["background"] == "estimate"
    assert movie.shape == background.shape == dff.shape == (FRAMES, 135 // BIN, 240 // BIN)
    assert background.mean() > 0
    # each cell's image: the lensless inversion u = -m x (Eq. 3.1) on the binned grid
    m = g.d_mm / scene.z_mm
    pitch = g.sensor_pitch_um * 1e-3 * BIN
    rows, cols = movie.shape[1:]
    spots = [(round((rows - 1) / 2 - y * m / pitch), round((cols - 1) / 2 - x * m / pitch))
             for x, y, _ in scene.positions_mm]
    traces = np.stack([movie[:, r - 1:r + 2, c - 1:c + 2].mean(axis=(1, 2)) for r, c in spots],
                      axis=1)
    recovered, _ = delta_f_over_f(traces, 20)
    table = store.coords_table()
    truth = scene.dff_traces(list(table["device_timestamp_s"] + 0.5 * table["exposure_s"]))
    active = [i for i in range(scene.n_cells) if truth[:, i].max() > 0.3]
    assert len(active) >= 4
    corr = [np.corrcoef(recovered[:, i], truth[:, i])[0, 1] for i in active]
    assert min(corr) > 0.9, corr


def test_capture_video_records_the_neurons_on_the_microscope_twin(tmp_path, capsys):
    """``capture video BENCH --simulate --scene neurons`` on the microscope: the cells,
    placed at its calibrated depths, light the sensor well inside its range."""
    out = tmp_path / "n.zarr"
    assert main(["capture", "video", str(BENCH), "--simulate", "--scene", "neurons",
                 "--frames", "3", "--fps", "10", "--out", str(out)]) == 0
    assert "complete: 3 frames" in capsys.readouterr().out
    store = RunStore.open(out)
    peak = max(float(store.frame(i).image.max()) for i in range(3))
    dark = store.attrs["simulated"]["dark_offset_dn"]
    assert store.frame_shape == (135, 240) and 500 < peak - dark < 4095 - dark


def _video_run(path, frames, dark=10.0):
    """A run store holding ``frames`` (n, rows, cols) plus a dark level, as recorded."""
    from instrument.acquisition.recorder import VIDEO_COORDS

    n = len(frames)
    store = RunStore.create(path, plan_name="video", plan_params={"frames": n}, points=[{}],
                            frame_tags=[["video"] * n], frame_shape=frames.shape[1:],
                            frame_dtype=np.uint16, coord_names=list(VIDEO_COORDS),
                            shard_frames=4, compressor="none")
    rows = np.zeros((n, len(VIDEO_COORDS)))
    rows[:, 0] = np.arange(n)
    store.write_frames(0, np.round(frames + dark).astype(np.uint16), rows)
    store.update_attrs(simulated={"dark_offset_dn": dark})
    return path


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """The two-part-model grid of test_reconstruct_grid (40 x 48, 3 x 3 nodes) and a
    six-frame run of two sources at corner nodes whose brightness changes."""
    from .test_reconstruct_grid import _grid_run

    d = tmp_path_factory.mktemp("grid")
    psfs = _grid_run(d / "grid.zarr")
    a, b = np.linspace(1, 3, 6), np.linspace(2, 1, 6)
    frames = 400 * (a[:, None, None] * psfs[0] + b[:, None, None] * psfs[8])
    _video_run(d / "v.zarr", frames)
    _video_run(d / "other.zarr", np.full((2, 24, 24), 50.0))
    return d


def test_batch_grid_frames_equal_recon_psf_grid_of_each_frame(synthetic, scheduler, tmp_path,
                                                              capsys):
    """recon-run --psf-grid stores, per frame, what recon --psf-grid makes of that
    frame (same model, background, weight and dark level), and the background too."""
    d = synthetic
    run = str(d / "v.zarr")
    argv = ["recon-run", run, "--psf-grid", str(d / "grid.zarr"), "--model", "local",
            "--iterations", "30", "--scheduler", scheduler]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "local model (9 convolutions per apply" in out and "backgrounds in" in out
    store = RunStore.open(run)
    movie, attrs = store.product("recon_grid_local")
    background, _ = store.product("recon_grid_local_background")
    assert attrs["psf_grid"] == str(d / "grid.zarr") and attrs["dark"] == 10.0
    for i in (0, 5):
        np.save(tmp_path / "raw.npy", store.frame(i).image.astype(np.float32))
        assert main(["recon", "--psf-grid", str(d / "grid.zarr"), "--raw",
                     str(tmp_path / "raw.npy"), "--model", "local", "--iterations", "30",
                     "--dark", "10", "--out", str(tmp_path / f"f{i}"),
                     "--overwrite"]) == 0
        assert_same_frame(movie[i], load_image(tmp_path / f"f{i}.tif"))
        assert_same_frame(background[i], load_image(tmp_path / f"f{i}_background.tif"))
    assert main(argv) == 0  # resumed: nothing left to do
    assert "0 frames reconstructed, 6 already done" in capsys.readouterr().out
    assert main([*argv, "--background", "none"]) == 2
    assert "other settings (background differ)" in capsys.readouterr().err
    assert main([*argv, "--background", "none", "--overwrite", "--frames", "0:2"]) == 0
    assert store.product_info("recon_grid_local")["planes_done"] == 2


@pytest.mark.parametrize("extra, words", [
    (["--psf", "x.npy", "--psf-grid", "{grid}"], "--psf (a PSF) or --psf-grid"),
    ([], "--psf (a PSF) or --psf-grid (a psf-grid run), not both"),
    (["--psf-grid", "{grid}", "--run", "{other}"],
     "calibrated on a 40x48 sensor but the run's frames are 24x24"),
    (["--psf-grid", "{grid}", "--psf-grid", "{grid}"], "give one --psf-grid run"),
    (["--psf-grid", "{run}"], "not a psf-grid run"),
    (["--psf-grid", "{grid}", "--pca-k", "2"], "--pca-k 2 goes with --model pca"),
    (["--psf-grid", "{grid}", "--depth", "2"], "drop --depth"),
    (["--psf-grid", "{grid}", "--early-stop", "{grid}"], "a --psf-grid run has none"),
])
def test_recon_run_psf_grid_refusals_in_one_line(synthetic, capsys, extra, words):
    d = synthetic
    run = d / "v.zarr"
    if "--run" in extra:
        run = d / "other.zarr"
        extra = extra[:-2]
    argv = [a.format(grid=d / "grid.zarr", run=d / "v.zarr") for a in extra]
    assert main(["recon-run", str(run), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("diffuserlab: error:") and "\n" not in err and words in err, err

"""Batch reconstruction of a recorded run on dask (instrument.processing.batch, recon-run): each
frame equals recon.reconstruct of that frame exactly, an interrupted batch keeps its
frames and the next call does only the rest, a scheduler address works, ΔF/F of the
simulated neurons follows the truth, and bad input is one line."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

import recon
from instrument.acquisition.video import record_video
from instrument.cli import main
from instrument.devices.video_scenes import BeadFlowScene, NeuronFieldScene
from instrument.devices.virtual_bench import VirtualBench
from instrument.processing.batch import check_workers, parse_frames, reconstruct_run
from instrument.runs.runstore import RunStore, RunStoreError
from recon.io import load_image
from recon.options import ReconOptions


def assert_same_frame(batch: np.ndarray, single: np.ndarray) -> None:
    """A batch frame equals the single-frame reconstruction to float32 rounding.

    Bit for bit on the development machine; a worker process whose BLAS or thread layout sums in
    another order (dask sets OMP/OpenBLAS threads to 1 in its workers) can differ by a
    few units in the last place, amplified by the iterations (seen: 8e-6 of a 2.8 peak).
    """
    assert batch.shape == single.shape and batch.dtype == single.dtype
    np.testing.assert_allclose(batch, single, rtol=0, atol=1e-5 * float(np.abs(single).max()))


OPTIONS = {"method": "admm", "iterations": 8, "bin_factor": 2}


def _options(**values) -> ReconOptions:
    """The batch's reconstruction options as Python callers build them."""
    return ReconOptions.validated(values, front="python")


@pytest.fixture(scope="module")
def cluster():
    from dask.distributed import LocalCluster

    c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                     dashboard_address=":0", host="127.0.0.1")
    yield c
    c.close()


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """A 12-frame bead video from the virtual bench (simulated clock) and its PSF."""
    d = tmp_path_factory.mktemp("batch")
    with VirtualBench(seed=0) as vb:
        vb.led_array.all_off()
        vb.set_scene(BeadFlowScene(seed=0, time_step_s=0.05))
        h = vb.psf((0.0, 0.0, BeadFlowScene().z_mm))
        offset = vb.camera.dark_offset_dn
        record_video(vb, d / "v.zarr", frames=12, fps=20.0, shard_frames=4)
    psf = (h / h.max() * 4000.0 + offset).astype(np.float32)
    np.save(d / "psf.npy", psf)
    return d, psf


def test_batch_equals_single_frame_reconstruction_and_resumes(video, cluster, tmp_path):
    import shutil

    d, psf = video
    run = tmp_path / "v.zarr"
    shutil.copytree(d / "v.zarr", run)
    cancel = threading.Event()
    seen = []

    def progress(p):
        seen.append(p)
        if p["done"] >= 3:
            cancel.set()

    first = reconstruct_run(run, psf, _options(**OPTIONS), scheduler=cluster.scheduler_address,
                            cancel=cancel, on_progress=progress)
    assert first["cancelled"] and 3 <= first["reconstructed"] < 12
    store = RunStore.open(run)
    done = store.product_frames_done("recon_admm")
    assert done.sum() == first["reconstructed"] and store.lock_owner() is None
    # a run moved (or copied) elsewhere resumes its batch (before: "other settings")
    run = Path(shutil.move(run, tmp_path / "moved" / "v.zarr"))
    store = RunStore.open(run)
    second = reconstruct_run(run, psf, _options(**OPTIONS), scheduler=cluster.scheduler_address)
    assert second["skipped"] == done.sum() and second["reconstructed"] == 12 - done.sum()
    data, attrs = RunStore.open(run).product("recon_admm")
    assert data.shape == (12, 128, 160) and attrs["iterations"] == 8
    assert f"recon-run {run} " in attrs["resume_hint"]
    for i in (0, 7, 11):
        frame = store.frame(i).image
        expect = recon.reconstruct(psf, frame, **OPTIONS).image
        assert_same_frame(data[i], expect)
    # other settings are refused while the product exists; --overwrite replaces it
    with pytest.raises(RunStoreError, match="iterations differ"):
        reconstruct_run(run, psf, _options(**{**OPTIONS, "iterations": 9}),
                        scheduler=cluster.scheduler_address)


def test_recon_run_cli_equals_recon_cli_on_the_same_frame(video, tmp_path, capsys):
    import shutil

    import tifffile

    d, _ = video
    run = tmp_path / "v.zarr"
    shutil.copytree(d / "v.zarr", run)
    assert main(["recon-run", str(run), "--psf", str(d / "psf.npy"), "--method", "fista",
                 "--iterations", "6", "--bin", "2", "--frames", "2:5", "--workers", "1",
                 "--dff", "20"]) == 0
    out = capsys.readouterr().out
    assert "recon_fista: 3 frames reconstructed, 0 already done" in out
    tifffile.imwrite(tmp_path / "raw.tif", RunStore.open(run).frame(3).image)
    assert main(["recon", "--psf", str(d / "psf.npy"), "--raw", str(tmp_path / "raw.tif"),
                 "--method", "fista", "--iterations", "6", "--bin", "2",
                 "--out", str(tmp_path / "one")]) == 0
    single = load_image(tmp_path / "one.tif")
    store = RunStore.open(run)
    assert_same_frame(store.product_frame("recon_fista", 3), single)
    assert store.product_frames_done("recon_fista").tolist() == [0, 0, 1, 1, 1] + [0] * 7
    dff, attrs = store.product("recon_fista_dff")
    assert dff.shape == (3, 128, 160) and attrs["percentile"] == 20


def test_recon_run_takes_the_prior_and_records_it(video, tmp_path, capsys):
    """``--prior`` reaches every frame's ADMM and the product's settings: a frame equals
    ``recon`` with the same prior."""
    import shutil

    import tifffile

    d, _ = video
    run = tmp_path / "v.zarr"
    shutil.copytree(d / "v.zarr", run)
    argv = ["--psf", str(d / "psf.npy"), "--method", "admm", "--tv", "1e-3", "--prior",
            "wavelet", "--iterations", "6", "--bin", "2"]
    assert main(["recon-run", str(run), *argv, "--frames", "3:4", "--workers", "1"]) == 0
    store = RunStore.open(run)
    assert store.product_attrs("recon_admm")["prior"] == "wavelet"
    tifffile.imwrite(tmp_path / "raw.tif", store.frame(3).image)
    assert main(["recon", *argv, "--raw", str(tmp_path / "raw.tif"),
                 "--out", str(tmp_path / "one")]) == 0
    assert_same_frame(store.product_frame("recon_admm", 3), load_image(tmp_path / "one.tif"))


@pytest.mark.parametrize("argv, words", [
    (["--frames", "5:2"], "selects no frame"),
    (["--frames", "x"], "give A:B"),
    (["--iterations", "0"], "--iterations 0"),
    (["--dff", "120"], "--dff 120"),
    (["--workers", "0"], "--workers 0"),
])
def test_recon_run_refuses_bad_options_in_one_line(video, capsys, argv, words):
    d, _ = video
    assert main(["recon-run", str(d / "v.zarr"), "--psf", str(d / "psf.npy"), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("diffuserlab: error:") and "\n" not in err and words in err


def test_recon_run_refuses_a_psf_of_another_shape(video, tmp_path, capsys):
    d, _ = video
    np.save(tmp_path / "small.npy", np.ones((32, 32), np.float32))
    assert main(["recon-run", str(d / "v.zarr"), "--psf", str(tmp_path / "small.npy")]) == 2
    assert "frames are 256x320" in capsys.readouterr().err


def test_parse_frames():
    assert parse_frames(None, 5) == range(5)
    assert parse_frames("1:3", 5) == range(1, 3)
    assert parse_frames(":2", 5) == range(0, 2)
    assert parse_frames("-2:", 5) == range(3, 5)


@pytest.mark.slow
def test_dff_of_recorded_neurons_follows_the_truth(cluster, tmp_path):
    """A 10 fps neuron video recorded through record_video, reconstructed by the batch
    with the on-axis PSF; each active cell's ΔF/F trace (20th-percentile baseline,
    Fig. 6.5b) correlates with its true trace above 0.8."""
    scene = NeuronFieldScene(n_cells=6, spike_rate_hz=0.4, tau_s=0.6, duration_s=8.0, seed=3)
    with VirtualBench(seed=2) as vb:
        vb.led_array.all_off()
        vb.set_scene(scene)
        on_axis = vb.psf((0.0, 0.0, scene.z_mm))
        cells = [vb.psf(tuple(p)) for p in scene.positions_mm]
        offset = vb.camera.dark_offset_dn
        record_video(vb, tmp_path / "n.zarr", frames=60, fps=10.0, exposure_s=0.1,
                     shard_frames=16)
    scale = 4000.0 / on_axis.max()
    psf = on_axis * scale + offset
    out = reconstruct_run(tmp_path / "n.zarr", psf, _options(method="admm", iterations=30),
                          dark=offset, scheduler=cluster.scheduler_address,
                          dff_percentile=20.0)
    store = RunStore.open(tmp_path / "n.zarr")
    movie, _ = store.product(out["product"])
    dff, _ = store.product(out["dff_product"])
    # where each cell lands in the reconstruction: reconstruct its own PSF
    spots = [np.unravel_index(np.argmax(recon.reconstruct(psf, h * scale + offset,
                                                          method="admm", iterations=30,
                                                          dark=offset).image), movie.shape[1:])
             for h in cells]
    # mid-exposure times (instrument.devices.video_scenes.frame_time_s)
    table = store.coords_table()
    truth = scene.dff_traces(list(table["device_timestamp_s"] + 0.5 * table["exposure_s"]))
    traces = np.stack([movie[:, r - 1:r + 2, c - 1:c + 2].mean(axis=(1, 2)) for r, c in spots],
                      axis=1)
    from recon.analysis import delta_f_over_f

    recovered, _ = delta_f_over_f(traces, 20)
    active = [i for i in range(scene.n_cells) if truth[:, i].max() > 0.3]
    assert len(active) >= 4
    for i in active:
        assert np.corrcoef(recovered[:, i], truth[:, i])[0, 1] > 0.8
    assert dff.shape == movie.shape


@pytest.mark.parametrize("workers, n_frames, expected", [
    (None, 100, 8),  # default: one per core
    (None, 3, 3),  # ... at most one per frame
    (6, 2, 2),  # more workers than frames: one per frame
    (8, 100, 8),
    (1, 1, 1),
])
def test_workers_are_bounded_by_the_frames_and_the_cores(monkeypatch, workers, n_frames,
                                                          expected):
    monkeypatch.setattr("os.cpu_count", lambda: 8)
    assert check_workers(workers, n_frames) == expected


@pytest.mark.parametrize("workers, words", [
    (9, "this machine has 8 cores"), (1_000_000, "give at most 8"), (0, ">= 1"),
    (-1, ">= 1"), (2.5, "whole number"), (True, "whole number")])
def test_workers_beyond_the_machine_are_refused(monkeypatch, workers, words):
    monkeypatch.setattr("os.cpu_count", lambda: 8)
    with pytest.raises(RunStoreError, match=words):
        check_workers(workers, 2)


def test_recon_run_refuses_a_dark_frame_of_another_shape_before_any_work(video, tmp_path,
                                                                         capsys):
    """Before: the batch started, made its product and failed in the first frame."""
    import shutil

    from tests.faults.helpers import tree

    d, _ = video
    run = Path(shutil.copytree(d / "v.zarr", tmp_path / "v.zarr"))
    np.save(tmp_path / "dark.npy", np.full((32, 40), 100.0, np.float32))
    before = tree(tmp_path)
    assert main(["recon-run", str(run), "--psf", str(d / "psf.npy"), "--dark",
                 str(tmp_path / "dark.npy"), "--workers", "1", "--method", "wiener"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("diffuserlab: error:") and "\n" not in err, err
    assert "dark frame is 32x40 but the frames of --psf" in err and "are 256x320" in err
    assert tree(tmp_path) == before


def test_a_dark_frame_is_named_and_the_batch_goes_on(video, tmp_path, capsys):
    """Before: the batch stopped at the first dark frame of the video without naming it."""
    import shutil

    d, _ = video
    run = Path(shutil.copytree(d / "v.zarr", tmp_path / "v.zarr"))
    store = RunStore.open(run, "r+")
    dark = np.full(store.frame_shape, 100, store.frame_dtype)  # the lens cap on
    store.write_frame(5, dark, {})
    assert main(["recon-run", str(run), "--psf", str(d / "psf.npy"), "--method", "wiener",
                 "--bin", "2", "--workers", "1"]) == 1
    out, err = capsys.readouterr()
    assert "failed:   frame 5 (point 0): the raw is constant" in out, out
    assert "11 frames reconstructed" in out
    assert "1 frame(s) could not be reconstructed" in err and "Traceback" not in err
    done = RunStore.open(run).product_frames_done("recon_wiener")
    assert done.sum() == 11 and not done[5]

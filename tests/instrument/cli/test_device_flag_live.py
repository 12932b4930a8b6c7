"""``--device cpu|cuda|auto`` on ``capture live``, ``capture video --live-recon`` and
``recon-run``: an unusable device exits 2 with the message before the bench is opened,
a file is read or written; a usable one (here PyTorch's CPU backend standing in for
the GPU) reaches the live reconstructor and the batch's solves."""

from __future__ import annotations

import numpy as np
import pytest

import instrument.cli.capture as capture_cli
import instrument.processing.batch
import recon
import recon.backend
import recon.live
from instrument.cli import main
from instrument.runs.runstore import RunStore
from recon.operators import ConvolutionOperator
from tests.instrument.cli.test_capture import psf_path  # noqa: F401 (the fixture)
from tests.recon.test_device import _stand_in, no_gpu


def _torch_for_cuda(monkeypatch):
    """``device="cuda"`` resolves to PyTorch's CPU backend everywhere it is resolved."""
    standin = _stand_in(monkeypatch, "torch-cpu")
    for mod in (recon.backend, recon.live):
        monkeypatch.setattr(mod, "resolve_device", lambda d: standin)
    return standin


def _no_bench(*args, **kwargs):
    raise AssertionError("the bench was opened")


@no_gpu
@pytest.mark.parametrize("argv", [
    ["capture", "live", "--simulate", "--psf", "missing.npy", "--preview-png", "p.png"],
    ["capture", "video", "--simulate", "--frames", "3", "--out", "v.zarr", "--live-recon",
     "admm:3", "--psf", "missing.npy"],
    ["recon-run", "missing.zarr", "--psf", "missing.npy"],
])
def test_cuda_without_a_gpu_exits_2_before_anything_is_opened(monkeypatch, tmp_path, capsys,
                                                              argv):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(capture_cli, "_open", _no_bench)
    assert main([*argv, "--device", "cuda"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("diffuserlab: error:") and "cuda requested but" in err
    assert "missing" not in err  # refused before any file is read
    assert list(tmp_path.iterdir()) == []  # and before any is written


def test_capture_video_takes_device_only_with_live_recon(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(capture_cli, "_open", _no_bench)
    assert main(["capture", "video", "--simulate", "--frames", "3", "--out",
                 str(tmp_path / "v.zarr"), "--device", "auto"]) == 2
    assert "--device go with --live-recon" in capsys.readouterr().err
    assert not (tmp_path / "v.zarr").exists()


def test_recon_run_reconstructs_a_psf_grid_on_the_device(monkeypatch, tmp_path, capsys):
    """``recon-run --psf-grid --device cuda``: each frame's grid solve runs on the device
    (PyTorch's CPU backend standing in) and equals the CPU's within float32 rounding."""
    from dask.distributed import Client, LocalCluster

    import recon.spatial.api
    import recon.spatial.device as grid_device
    from tests.instrument.test_batch_grid import _video_run
    from tests.instrument.test_reconstruct_grid import _grid_run

    psfs = _grid_run(tmp_path / "grid.zarr")
    a = np.linspace(1, 3, 2)
    _video_run(tmp_path / "v.zarr", 400 * (a[:, None, None] * psfs[0] + psfs[8]))
    standin = _torch_for_cuda(monkeypatch)
    monkeypatch.setattr(recon.spatial.api, "resolve_device", lambda d: standin)
    solves = []
    solve_grid_on = grid_device.solve_grid_on

    def spy(backend, *args, **kwargs):
        solves.append(backend.label)
        return solve_grid_on(backend, *args, **kwargs)

    def in_process(workers, scheduler, timeout_s):  # threads: the stand-in reaches them
        cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                               dashboard_address=":0")
        return Client(cluster, timeout=timeout_s), cluster

    monkeypatch.setattr(grid_device, "solve_grid_on", spy)
    monkeypatch.setattr(recon.spatial.api, "solve_grid_on", spy)
    monkeypatch.setattr(instrument.processing.batch, "_client", in_process)
    argv = ["recon-run", str(tmp_path / "v.zarr"), "--psf-grid", str(tmp_path / "grid.zarr"),
            "--model", "local", "--iterations", "20"]
    assert main([*argv, "--device", "cuda"]) == 0
    assert solves == ["cpu (torch, generic path)"] * 2
    on_device = RunStore.open(tmp_path / "v.zarr").product("recon_grid_local")[0]
    monkeypatch.undo()
    assert main([*argv, "--overwrite", "--workers", "1"]) == 0
    cpu = RunStore.open(tmp_path / "v.zarr").product("recon_grid_local")[0]
    assert np.abs(on_device - cpu).max() <= 1e-4 * np.abs(cpu).max()


def test_capture_live_reconstructs_on_the_device_it_is_given(monkeypatch, psf_path,  # noqa: F811
                                                            capsys):
    standin = _torch_for_cuda(monkeypatch)
    built = []
    original = recon.live.LiveReconstructor.__init__

    def spy(self, *args, **kwargs):
        original(self, *args, **kwargs)
        built.append(self)

    monkeypatch.setattr(recon.live.LiveReconstructor, "__init__", spy)
    assert main(["capture", "live", "--simulate", "--psf", str(psf_path), "--method", "admm:2",
                 "--seconds", "2", "--threads", "1", "--device", "cuda"]) == 0
    out = capsys.readouterr().out
    assert f"on {standin.label}" in out.splitlines()[0]
    status = [line for line in out.splitlines() if "reconstructed" in line][-1]
    assert "errors 0" in status and int(status.split("reconstructed ")[1].split(",")[0]) >= 2
    (live,) = built
    assert live.backend is standin and type(live.state.x).__module__ == "torch"


def _run(path, psf, n=3):
    """A recorded run of ``n`` frames of a moving scene through ``psf`` (dark 100 DN)."""
    rng = np.random.default_rng(0)
    op = ConvolutionOperator(psf - 100.0)
    scene = np.zeros(op.padded_shape, np.float32)
    scene[30:45, 40:55] = 1.0
    store = RunStore.create(path, plan_name="video", plan_params={},
                            points=[{"t": float(k)} for k in range(n)],
                            frame_tags=[["frame"]] * n, frame_shape=psf.shape,
                            frame_dtype=np.uint16, coord_names=["exposure_s"])
    for i in range(n):
        frame = op.forward(np.roll(scene, 3 * i, axis=1)) * 3000 + 100
        store.write_frame(i, (frame + rng.normal(0, 5, psf.shape)).astype(np.uint16),
                          {"exposure_s": 0.01})
    store.update_attrs(status="complete")


def test_recon_run_solves_on_the_device_in_one_worker(monkeypatch, tmp_path, capsys):
    from dask.distributed import Client, LocalCluster

    import recon.solvers.device as device_mod

    _torch_for_cuda(monkeypatch)
    rng = np.random.default_rng(1)
    psf = np.full((40, 48), 100.0, np.float32)
    psf[rng.integers(8, 32, 40), rng.integers(8, 40, 40)] += 2000 * rng.random(40)
    np.save(tmp_path / "psf.npy", psf)
    _run(tmp_path / "v.zarr", psf)
    asked, solves = [], []

    def in_process(workers, scheduler, timeout_s):  # threads: the stand-in reaches them
        asked.append(workers)
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=False,
                               dashboard_address=":0")
        return Client(cluster, timeout=timeout_s), cluster

    solve_on = device_mod.solve_on

    def spy(backend, *args, **kwargs):
        solves.append(backend.label)
        return solve_on(backend, *args, **kwargs)

    monkeypatch.setattr(instrument.processing.batch, "_client", in_process)
    monkeypatch.setattr(device_mod, "solve_on", spy)
    options = {"method": "admm", "iterations": 8, "tv": 1e-3}
    assert main(["recon-run", str(tmp_path / "v.zarr"), "--psf", str(tmp_path / "psf.npy"),
                 "--method", "admm", "--tv", "1e-3", "--iterations", "8", "--device",
                 "cuda"]) == 0
    out = capsys.readouterr().out
    assert "one local worker, device cuda" in out and "3 frames reconstructed" in out
    assert asked == [1]  # one worker per GPU unless --workers
    assert solves == ["cpu (torch, generic path)"] * 3
    monkeypatch.undo()  # the reference on the CPU's NumPy path
    store = RunStore.open(tmp_path / "v.zarr")
    for i in range(3):
        cpu = recon.reconstruct(psf, store.frame(i).image, **options).image
        got = store.product_frame("recon_admm", i)
        assert np.abs(got - cpu).max() <= 1e-4 * np.abs(cpu).max()
    assert solves == ["cpu (torch, generic path)"] * 3

"""3D FISTA sharded by plane slabs over dask workers (instrument.processing.volume_shards).

On a LocalCluster of two worker processes the sharded solve must equal the
in-memory 3D FISTA (relative 1e-5), count the bytes each worker moves (only
sensor-sized images: far less than a slab), and stop with one clear error naming the
worker and its planes when a worker is killed mid-solve -- through ``recon3d
--scheduler`` too, where nothing may be written. ``recon3d --memory-limit`` runs the
streamed solver in one process and says so.
"""

from __future__ import annotations

import json
import math
import os
import signal

import numpy as np
import pytest

import recon
from instrument.cli import main
from instrument.processing.volume_shards import (
    ShardedSlabs,
    ShardLostError,
    local_cluster,
    sharded_fista3d,
)
from recon.auto.noise import NoiseModel
from recon.volume import fista3d
from recon.volume.slab import VolumeSlab
from recon.volume.streamed import LocalSlabs
from recon.volume.streamed_auto import auto_streamed
from tests.instrument.cli.test_recon3d import DEPTHS, bead_problem, normalized_bead_problem
from tests.recon.volume.test_memory_plan import bead_limit, bead_plans, fix_baseline


@pytest.fixture(scope="module")
def cluster():
    client, cl = local_cluster(2, "1GB")
    yield client
    client.close()
    cl.close()


@pytest.fixture(scope="module")
def problem():
    return normalized_bead_problem()


def _kill_worker_of_slab(client, slab: int, after: int):
    """``on_iteration`` that SIGKILLs the worker process of slab ``slab`` after
    iteration ``after``."""
    def hook(k):
        if k == after:
            addr = sorted(client.scheduler_info()["workers"])[slab]
            pid = client.run(os.getpid, workers=[addr])[addr]
            os.kill(pid, signal.SIGKILL)
    return hook


def test_sharded_equals_in_memory_and_counts_bytes(cluster, problem):
    stack, scale, b, op, lip = problem
    ref = fista3d(op, b, iterations=20, tv=1e-3, l1=1e-4, lipschitz=lip)
    got = sharded_fista3d(cluster, stack, b, psf_scale=scale, support="padded",
                          iterations=20, tv=1e-3, l1=1e-4, lipschitz=lip)
    assert float(np.linalg.norm(got.x - ref.x) / np.linalg.norm(ref.x)) < 1e-5
    np.testing.assert_allclose(got.history.objective, ref.history.objective, rtol=1e-5)
    assert len(set(got.params["workers"])) == 2
    moved = got.params["bytes_moved_per_iteration"]
    plane = 4 * op.padded_shape[0] * op.padded_shape[1]
    sensor = 4 * op.sensor_shape[0] * op.sensor_shape[1]
    # per iteration: partial image up, residual down (sensor-sized) and the 3 boundary
    # planes between the two slabs (v and y of slab 1's first, v of slab 0's last)
    assert moved == [2 * sensor + 3 * plane] * 2


def test_sharded_automatic_weight_equals_the_single_process(cluster, problem):
    """The held-out path over slabs in two workers: the mask stays in the loop (only
    sensor images cross), the copies stay in the workers; the same choice and volume
    as the slabs in one process."""
    stack, scale, b, op, lip = problem
    noise = NoiseModel(1e-4, 1e-6, [])
    ref, ref_rec = auto_streamed(LocalSlabs([VolumeSlab(stack, 0, len(stack), scale)]), b,
                                 noise=noise, iterations=30)
    group = ShardedSlabs(cluster, stack, scale)
    try:
        got, rec = auto_streamed(group, b, noise=noise, iterations=30)
        moved = group.bytes_moved
    finally:
        group.close()
    assert rec["weight"] == ref_rec["weight"]
    assert [p["status"] for p in rec["weight_choice"]["path"]] == \
        [p["status"] for p in ref_rec["weight_choice"]["path"]]
    assert float(np.linalg.norm(got.x - ref.x) / np.linalg.norm(ref.x)) < 1e-5
    # per iteration the fixed weight's 5 sensor images (partial image, residual, 3
    # boundary planes) and, a window of 10 iterations apart, the held-out score's
    # partial images and the copies' names (measured: 5.19 in all); besides, the
    # stack's planes once and the estimate's once (at most 3 planes a slab)
    iterations = rec["weight_choice"]["path_iterations"] + \
        rec["weight_choice"]["final_iterations"]
    sensor = 4 * op.sensor_shape[0] * op.sensor_shape[1]
    assert all(m < iterations * 5.5 * sensor + 2 * 3 * sensor for m in moved)


def test_reconstruct_sharded_chooses_the_weight_over_the_workers(cluster):
    stack, raw = bead_problem()
    lines = []
    rec = recon.reconstruct_volume(stack, DEPTHS, raw, iterations=30, announce=lines.append,
                                   slab_group=lambda h, scale: ShardedSlabs(cluster, h, scale))
    auto = rec.info.auto[0]
    assert auto["weight"] == rec.info.tv and "sharded over the dask workers" in \
        rec.info.method_reason
    assert any("slabs' workers" in line and "4 copies of the iterates" in line
               for line in lines)
    mem = rec.metrics(floor_s=1.0)["memory"]
    assert mem["slabs_elsewhere"] and "path_copies_peak_bytes" not in mem
    assert rec.volume.shape == stack.shape


def test_sharded_from_a_zarr_store(cluster, problem, tmp_path):
    zarr = pytest.importorskip("zarr")
    stack, scale, b, op, lip = problem
    store = tmp_path / "psf.zarr"
    z = zarr.create_array(str(store), shape=stack.shape, chunks=(1, *stack.shape[1:]),
                          dtype="float32")
    z[:] = stack
    ref = fista3d(op, b, iterations=10, tv=1e-3, lipschitz=lip)
    got = sharded_fista3d(cluster, str(store), b, psf_scale=scale, support="padded",
                          iterations=10, tv=1e-3, lipschitz=lip)
    assert float(np.linalg.norm(got.x - ref.x) / np.linalg.norm(ref.x)) < 1e-5


def test_a_killed_worker_stops_the_solve_cleanly(problem):
    stack, scale, b, op, lip = problem
    client, cl = local_cluster(2, "1GB")
    try:
        with pytest.raises(ShardLostError) as err:
            sharded_fista3d(client, stack, b, psf_scale=scale, iterations=20, tv=1e-3,
                            lipschitz=lip, on_iteration=_kill_worker_of_slab(client, 1, 3))
        msg = str(err.value)
        assert "was lost at iteration 5" in msg and "planes 2..4" in msg
        assert "nothing was written" in msg
    finally:
        client.close()
        cl.close()


@pytest.fixture
def files(tmp_path):
    stack, raw = bead_problem()
    np.save(tmp_path / "stack.npy", stack)
    np.save(tmp_path / "raw.npy", (100.0 * raw).astype(np.float32))
    return tmp_path


def _recon3d(d, *extra):
    return main(["recon3d", "--psf-stack", str(d / "stack.npy"), "--depths",
                 ",".join(map(str, DEPTHS)), "--raw", str(d / "raw.npy"), "--method", "fista",
                 "--tv", "1e-4", "--iterations", "15", "--out", str(d / "v.tif"), *extra])


def test_recon3d_memory_limit_streams_and_says_so(files, capsys, monkeypatch):
    fix_baseline(monkeypatch)
    limit = bead_limit("streamed", None, "fista")
    assert _recon3d(files, "--memory-limit", str(limit), "--metrics-json",
                    str(files / "m.json")) == 0
    out = capsys.readouterr().out
    assert (f"more than the {limit / 1e9:.2f} GB given by --memory-limit: streamed 3D "
            "FISTA (planes transformed a chunk at a time") in out
    assert "estimated peak memory" in out and "peak memory" in out
    assert (files / "v.tif").exists()
    assert _recon3d(files, "--memory-limit", "lots", "--overwrite") == 2
    assert "--memory-limit 'lots'" in capsys.readouterr().err


def test_recon3d_below_every_plan_exits_2_and_writes_nothing(files, capsys, monkeypatch):
    """A limit below every plan: one line naming the smallest limit that would do, exit
    status 2, before any solve (nothing written)."""
    fix_baseline(monkeypatch)
    smallest = min(p["estimate_bytes"] for p in bead_plans(None, "fista"))
    assert _recon3d(files, "--memory-limit", str(smallest - 1), "--metrics-json",
                    str(files / "m.json")) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert f"give --memory-limit {math.ceil(smallest / 1e7) / 100:.2f}GB or more" in err
    assert "estimated peak memory" not in captured.out and not any(files.glob("v*"))
    assert not (files / "m.json").exists()


def test_recon3d_memory_limit_chooses_the_default_weight_streamed(files, capsys, monkeypatch):
    """``--tv`` left at its default (auto) on a problem that streams: the held-out path
    over the slabs chooses the weight, and the metrics record it."""
    fix_baseline(monkeypatch)
    assert main(["recon3d", "--psf-stack", str(files / "stack.npy"), "--depths",
                 ",".join(map(str, DEPTHS)), "--raw", str(files / "raw.npy"),
                 "--iterations", "15", "--out", str(files / "v.tif"), "--memory-limit",
                 str(bead_limit("streamed", "tv")),
                 "--metrics-json", str(files / "m.json")]) == 0
    out = capsys.readouterr().out
    assert "automatic tv weight: the held-out path of recon.auto over the slabs" in out
    assert "4 copies of the iterates" in out
    m = json.loads((files / "m.json").read_text())
    assert m["method"] == "fista" and m["memory_plan"]["streamed"]
    auto = m["auto"]
    assert auto["regulariser"] == "tv" and auto["weight"] == m["tv"]
    assert f"tv weight {auto['weight']:.3g}, planes kept" in out
    choice = auto["weight_choice"]
    assert choice["path"] and choice["stop_reason"] and "candidates_settled" in choice
    assert m["memory"]["path_copies_peak_bytes"] == m["memory"]["arrays"]["path_copies"]


def test_recon3d_sharded_lost_worker_writes_nothing(files, capsys, monkeypatch):
    import recon.volume.memory_plan as plan
    from recon.volume.streamed import slab_fista

    client, cl = local_cluster(2, "1GB")

    def with_kill(group, b, **kw):  # the solve recon3d runs, with a worker killed in it
        return slab_fista(group, b, on_iteration=_kill_worker_of_slab(client, 0, 2), **kw)

    monkeypatch.setattr(plan, "slab_fista", with_kill)
    try:
        assert _recon3d(files, "--scheduler", cl.scheduler_address) == 2
        err = capsys.readouterr().err
        assert "was lost at iteration 4" in err and "nothing was written" in err
        assert not any(files.glob("v*"))
    finally:
        client.close()
        cl.close()

"""One orientation for stored products: ``recon-run`` with a PSF and with a PSF grid
stores the frame where ``recon.reconstruct`` puts it (the model grid of Eq. 3.3), and
labels both products alike."""

from __future__ import annotations

import numpy as np
import pytest

import recon
from instrument.processing.batch import reconstruct_run
from instrument.processing.batch_grid import GridBatchModel
from instrument.runs.runstore import RunStore
from recon.io import DATA_ORIENTATION
from recon.options import ReconOptions
from recon.spatial.api import grid_model

from ..recon.test_front_door import SENSOR, _brightest, _grid, _psf, _raw, _truth
from .test_batch_grid import _video_run

DARK = 10.0


@pytest.fixture(scope="module")
def scheduler():
    """An in-process dask cluster of one worker thread (no process start-up)."""
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=":0") as c:
        yield c.scheduler_address


def test_stored_frames_of_a_psf_and_a_grid_agree_with_the_front_door(tmp_path, scheduler):
    psf = _psf()
    raw = _raw(psf, amplitude=4000.0)
    run = _video_run(tmp_path / "v.zarr", raw[None])
    frame = RunStore.open(run).frame(0).image.astype(np.float64)
    truth = _truth()
    psf_dn = 1000.0 * psf + DARK  # a PSF as captured: the dark level is subtracted from it too
    image = recon.reconstruct(psf_dn, frame, "fista", tv=0.0, iterations=150, dark=DARK)
    grid = _grid(psf)
    grid_image = recon.reconstruct(grid, frame, "fista", background="none", l1=0.0,
                                   iterations=150, dark=DARK, model="local")
    assert _brightest(image.image) == truth == _brightest(grid_image.image)

    options = ReconOptions.validated({"method": "fista", "tv": 0.0, "iterations": 150},
                                     front="python")
    reconstruct_run(run, psf_dn, options, dark=DARK, scheduler=scheduler, product="single")
    choice, op = grid_model(grid, model="local", bin_factor=1)
    model = GridBatchModel(grid, choice, op, "grid", "local", 1)
    options = ReconOptions.validated({"iterations": 150, "background": "none", "l1": 0.0},
                                     front="python")
    reconstruct_run(run, model, options, dark=DARK, scheduler=scheduler, product="grid")
    store = RunStore.open(run)
    single, single_attrs = store.product("single")
    gridded, grid_attrs = store.product("grid")
    assert single_attrs["orientation"] == grid_attrs["orientation"] == DATA_ORIENTATION
    assert single.shape[1:] == gridded.shape[1:] == SENSOR
    assert _brightest(single[0]) == truth == _brightest(gridded[0])
    np.testing.assert_allclose(single[0], image.image, rtol=1e-3, atol=1e-3 * image.image.max())

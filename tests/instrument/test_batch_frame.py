"""One batch task body (instrument.processing.batch_grid.reconstruct_run_frame): a stored frame
reconstructed as recon.reconstruct makes it, for the PSF batch and the PSF-grid batch."""

from __future__ import annotations

import numpy as np
import pytest

import instrument.processing.batch as batch
import recon
from instrument.processing.batch_grid import reconstruct_run_frame

from .test_batch_grid import _video_run


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    rng = np.random.default_rng(3)
    frames = 100.0 + 50.0 * rng.random((3, 24, 24))
    psf = np.zeros((24, 24), np.float32)
    psf[10:13, 9:14] = 1.0
    return str(_video_run(tmp_path_factory.mktemp("frame") / "v.zarr", frames)), psf


def test_a_stored_frame_is_reconstructed_as_recon_makes_it(run):
    path, psf = run
    from instrument.runs.runstore import RunStore

    raw = RunStore.open(path).frame(1).image
    want = recon.reconstruct(psf, raw, method="admm", iterations=4, tv=0.01).image
    got = reconstruct_run_frame(path, 1, psf, 1, method="admm", iterations=4, tv=0.01).image
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * float(np.abs(want).max()))
    as_float = reconstruct_run_frame(path, 1, psf, None, np.float64, method="admm",
                                     iterations=4, tv=0.01).image
    np.testing.assert_array_equal(
        as_float, recon.reconstruct(psf, raw.astype(np.float64), method="admm",
                                    iterations=4, tv=0.01).image)


def test_the_psf_batch_task_is_that_body(run, monkeypatch):
    path, psf = run
    calls = []

    def spy(*args, **keywords):
        calls.append((args, keywords))
        return reconstruct_run_frame(*args, **keywords)

    monkeypatch.setattr(batch, "reconstruct_run_frame", spy)
    index, image = batch.reconstruct_stored_frame(path, 2, psf, {"method": "admm",
                                                                 "iterations": 3, "tv": 0.01})
    assert index == 2 and image.dtype == np.float32 and len(calls) == 1
    assert calls[0][0][:2] == (path, 2)

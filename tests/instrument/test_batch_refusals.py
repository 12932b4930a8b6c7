"""A frame the batch refuses for its own data (no signal) is listed once, in the
operator's words, not also logged by the dask worker as a crash with a traceback
("Compute Failed"; issue 67)."""

from __future__ import annotations

import numpy as np

from instrument.cli import main
from instrument.runs.runstore import RunStore


def test_refused_frames_are_listed_without_a_workers_traceback(tmp_path, capfd):
    n, shape = 3, (64, 80)
    store = RunStore.create(tmp_path / "dim.zarr", plan_name="video", plan_params={},
                            points=[{"t": float(k)} for k in range(n)],
                            frame_tags=[["frame"]] * n, frame_shape=shape,
                            frame_dtype=np.uint16, coord_names=["exposure_s"])
    rng = np.random.default_rng(0)
    for i in range(n):  # the dark level and its noise: no light reached the sensor
        store.write_frame(i, (64 + rng.normal(0, 2, shape)).astype(np.uint16),
                          {"exposure_s": 0.01})
    store.update_attrs(status="complete")
    psf = np.full(shape, 64, np.float32)
    psf[30:34, 38:42] = 4000
    np.save(tmp_path / "psf.npy", psf)
    code = main(["recon-run", str(tmp_path / "dim.zarr"), "--psf", str(tmp_path / "psf.npy"),
                 "--dark", "64", "--workers", "1", "--method", "wiener"])
    out, err = capfd.readouterr()
    assert code == 1
    assert all(f"failed:   frame {i} (point {i}): the raw carries no signal" in out
               for i in range(n)), out
    assert "Compute Failed" not in err and "Traceback" not in err, err

"""``diffuserlab recon --psf-grid`` and ``recon3d --psf-grid`` on psf-grid run stores."""

import json

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from instrument.cli import main
from instrument.processing.reconstruct_grid import load_psf_grid
from instrument.runs.runstore import RunStore

SENSOR = (40, 48)
STEP_PX = 8  # node spacing on the sensor


def _psfs(seed, z_mm):
    """Unregistered PSFs of a 3 x 3 source raster: one sparse pattern shifted by the
    node offset, times a fall-off centred under the source, which lies on the other
    side of the axis (the two-part model, Eq. 5.1: the pattern moves by -m x, the
    fall-off's centre by +x)."""
    rng = np.random.default_rng(seed)
    base = np.zeros(SENSOR, np.float32)
    base[rng.integers(10, 30, 10), rng.integers(12, 36, 10)] = 1.0
    base = gaussian_filter(base, 0.6)
    yy, xx = np.mgrid[:SENSOR[0], :SENSOR[1]]
    psfs, positions, shifts = [], [], []
    for iy in (-1, 0, 1):
        for ix in (-1, 0, 1):
            dy, dx = iy * STEP_PX, ix * STEP_PX
            fall = np.exp(-((yy - 20 + 1.5 * dy) ** 2 + (xx - 24 + 1.5 * dx) ** 2)
                          / (2 * 14.0**2))
            psfs.append(np.roll(base, (dy, dx), axis=(0, 1)) * fall)
            positions.append((-ix * 0.4, -iy * 0.4))
            shifts.append((dy, dx))
    return np.stack(psfs), positions, shifts


def _grid_run(path, seed=0, z_mm=2.4):
    psfs, positions, shifts = _psfs(seed, z_mm)
    store = RunStore.create(path, plan_name="psf-grid",
                            plan_params={"mode": "stage", "z_mm": z_mm, "d_mm": 3.8,
                                         "positions_mm": positions},
                            points=[{"x_mm": x, "y_mm": y} for x, y in positions],
                            frame_tags=[("psf",)] * len(positions), frame_shape=SENSOR,
                            frame_dtype=np.uint16, coord_names=["x_mm", "y_mm"])
    registered = np.stack([np.roll(p, (-dy, -dx), axis=(0, 1))
                           for p, (dy, dx) in zip(psfs, shifts, strict=True)])
    attrs = {"positions_mm": positions, "z_mm": z_mm, "shifts_px": shifts, "units": "DN/s"}
    store.write_product("psf_grid", psfs, **attrs)
    store.write_product("psf_grid_registered", registered, **attrs)
    return psfs


def test_recon_with_a_psf_grid_finds_the_sources_and_the_background(tmp_path, capsys):
    psfs = _grid_run(tmp_path / "grid.zarr")
    grid = load_psf_grid(tmp_path / "grid.zarr")
    assert grid.grid_shape == (3, 3) and grid.z_mm == 2.4 and grid.d_mm == 3.8
    raw = 100 * (psfs[0] + 0.7 * psfs[8]) + 5.0  # two sources at corner nodes, offset 5
    np.save(tmp_path / "raw.npy", raw.astype(np.float32))
    out = tmp_path / "out" / "r"
    code = main(["recon", "--psf-grid", str(tmp_path / "grid.zarr"), "--raw",
                 str(tmp_path / "raw.npy"), "--model", "local", "--iterations", "200",
                 "--out", str(out), "--metrics-json", str(tmp_path / "m.json")])
    assert code == 0
    line = capsys.readouterr().out
    assert "local model (9 convolutions per apply" in line
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["model"]["label"] == "local" and m["n_kernels"] == 9
    import tifffile
    image = tifffile.imread(out.with_suffix(".tif"))
    top = np.argsort(image.ravel())[-2:]
    found = {tuple(int(v) for v in np.unravel_index(i, image.shape)) for i in top}
    assert found == {(20 - 8, 24 - 8), (20 + 8, 24 + 8)}
    background = tifffile.imread(tmp_path / "out" / "r_background.tif")
    assert background.mean() == pytest.approx(5.0, rel=0.1)
    # auto on a grid whose PSFs differ mainly by their fall-off
    code = main(["recon", "--psf-grid", str(tmp_path / "grid.zarr"), "--raw",
                 str(tmp_path / "raw.npy"), "--iterations", "20", "--background", "none",
                 "--out", str(tmp_path / "auto")])
    assert code == 0 and "model (" in capsys.readouterr().out


def test_recon_with_a_psf_grid_by_admm_two_part(tmp_path, capsys):
    """``--method admm --two-part``: TV ADMM on the grid's caustics, the weight chosen
    automatically and said, the brightness divided out; sources at their nodes."""
    psfs = _grid_run(tmp_path / "grid.zarr")
    raw = 100 * (psfs[0] + 0.7 * psfs[8])
    np.save(tmp_path / "raw.npy", raw.astype(np.float32))
    out = tmp_path / "out" / "r"
    base = ["recon", "--psf-grid", str(tmp_path / "grid.zarr"), "--raw",
            str(tmp_path / "raw.npy"), "--model", "local", "--iterations", "150",
            "--method", "admm", "--out", str(out)]
    assert main(base) == 2
    assert "background 'none'" in capsys.readouterr().err
    code = main([*base, "--background", "none", "--two-part", "--metrics-json",
                 str(tmp_path / "m.json")])
    assert code == 0
    printed = capsys.readouterr().out
    assert "tv weight" in printed and "hold-out cross-validation" in printed
    assert "two-part (brightness divided out): ADMM, TV" in printed
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["method"] == "admm" and m["two_part"] and m["tv"] == m["auto"]["weight"]["weight"]
    assert not (tmp_path / "out" / "r_background.tif").exists()
    import tifffile
    image = tifffile.imread(out.with_suffix(".tif"))
    top = np.argsort(image.ravel())[-2:]
    found = {tuple(int(v) for v in np.unravel_index(i, image.shape)) for i in top}
    assert found == {(20 - 8, 24 - 8), (20 + 8, 24 + 8)}


def test_recon3d_with_psf_grids_per_depth(tmp_path, capsys):
    near = _grid_run(tmp_path / "near.zarr", seed=1, z_mm=2.0)
    _grid_run(tmp_path / "far.zarr", seed=2, z_mm=2.8)
    np.save(tmp_path / "raw.npy", (100 * near[4]).astype(np.float32))
    code = main(["recon3d", "--psf-grid", str(tmp_path / "near.zarr"), "--psf-grid",
                 str(tmp_path / "far.zarr"), "--raw", str(tmp_path / "raw.npy"),
                 "--model", "pca", "--pca-k", "2", "--iterations", "150",
                 "--out", str(tmp_path / "v.tif"), "--metrics-json", str(tmp_path / "m.json")])
    assert code == 0
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["depths_mm"] == [2.0, 2.8] and m["n_kernels"] == 4
    import tifffile
    volume = tifffile.imread(tmp_path / "v.tif")
    assert volume.shape == (2, *SENSOR)
    assert np.unravel_index(np.argmax(volume), volume.shape) == (0, 20, 24)
    assert (tmp_path / "v_mip_xy.png").exists() and (tmp_path / "v_background.tif").exists()


def test_grid_options_refuse_bad_input(tmp_path, capsys):
    _grid_run(tmp_path / "grid.zarr")
    np.save(tmp_path / "raw.npy", np.ones((10, 10), np.float32))
    base = ["recon", "--raw", str(tmp_path / "raw.npy"), "--out", str(tmp_path / "x")]
    assert main(base) == 2
    assert "--psf-grid" in capsys.readouterr().err
    assert main([*base, "--psf-grid", str(tmp_path / "grid.zarr")]) == 2
    assert "differs from the PSF grid" in capsys.readouterr().err
    store = RunStore.create(tmp_path / "sweep.zarr", plan_name="psf-sweep", plan_params={},
                            points=[{"z_mm": 1.0}], frame_tags=[("psf",)], frame_shape=SENSOR,
                            frame_dtype=np.uint16, coord_names=["z_mm"])
    del store
    assert main([*base, "--psf-grid", str(tmp_path / "sweep.zarr")]) == 2
    assert "not a psf-grid run" in capsys.readouterr().err
    assert main([*base, "--psf-grid", str(tmp_path / "grid.zarr"), "--overwrite",
                 "--out", str(tmp_path / "raw.npy")]) == 2

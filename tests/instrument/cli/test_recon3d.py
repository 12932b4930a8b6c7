"""Tests of ``diffuserlab recon3d`` (instrument.cli.recon3d) on a small synthetic problem.

The PSF stack is caustic-like (smoothed noise thresholded at its 85th percentile in a
round aperture, magnified per depth about the centre as 1 + d/z scales it); the
measurement is the 3D forward model (Eq. 4.4) of a few beads plus a little noise.
The CLI is called through :func:`instrument.cli.main` (its error boundary gives the
exit statuses).
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
import tifffile
from scipy.ndimage import gaussian_filter, map_coordinates

import recon.volume
import recon.volume.api
from instrument.cli import main, recon3d
from recon.io import load_image
from recon.volume import VolumeConvolutionOperator, normalize_psf_stack

N = 48
DEPTHS = [float(z) for z in 1.0 / np.linspace(0.5, 0.1, 5)]  # 2 ... 10 mm, uniform in 1/z
SCALES = (1.0, 0.9, 0.8, 0.7, 0.6)
BEADS = [(1, 12, 30), (3, 30, 14), (3, 20, 22)]  # (plane, row, col) in the sensor FoV

HAS_ADMM = hasattr(recon.volume, "admm3d")


def caustic_stack(n: int = N, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    g = gaussian_filter(rng.standard_normal((2 * n, 2 * n)), 2.0)
    base = np.maximum(g - np.quantile(g, 0.85), 0.0)
    c = (n - 1) / 2
    ii, jj = np.mgrid[0:n, 0:n].astype(np.float64)
    planes = []
    for s in SCALES:
        h = map_coordinates(base, [(ii - c) / s + n, (jj - c) / s + n], order=1)
        planes.append(h * (np.hypot(ii - c, jj - c) < 0.3 * n * s))
    return (np.array(planes) / np.max(planes)).astype(np.float32)


def bead_problem() -> tuple[np.ndarray, np.ndarray]:
    """(stack, raw): the caustic stack and the forward model of BEADS with 1 % noise."""
    stack = caustic_stack()
    op = VolumeConvolutionOperator(stack)
    truth = np.zeros(op.shape_in, np.float32)
    top, left = op.offset
    for z, i, j in BEADS:
        truth[z, top + i, left + j] = 1.0
    raw = op.forward(truth)
    return stack, raw + 0.01 * raw.max() * np.random.default_rng(1).standard_normal(raw.shape)


def normalized_bead_problem() -> tuple:
    """(stack, scale, b, op, L): :func:`bead_problem` with its stack normalised, the
    raw scaled to a maximum of 1, the operator and its Lipschitz bound."""
    stack, raw = bead_problem()
    h, scale = normalize_psf_stack(stack)
    b = (raw / np.abs(raw).max()).astype(np.float32)
    op = VolumeConvolutionOperator(h)
    return stack, scale, b, op, op.lipschitz_bound()


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    """Files: stack.npy (no depths), stack.tif (depths in metadata), raw.npy."""
    d = tmp_path_factory.mktemp("recon3d")
    stack, raw = bead_problem()
    np.save(d / "stack.npy", stack)
    tifffile.imwrite(d / "stack.tif", stack, metadata={"depths_mm": DEPTHS},
                     photometric="minisblack")
    np.save(d / "raw.npy", (100.0 * raw).astype(np.float32))
    return d


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="diffuserlab")
    sub = p.add_subparsers(dest="command", required=True)
    recon3d.add_subcommands(sub)
    return p


def cli(*argv: str) -> int:
    return main(["recon3d", *map(str, argv)])


METHODS = ["fista", pytest.param("admm", marks=pytest.mark.skipif(
    not HAS_ADMM, reason="recon.volume.admm3d not available yet"))]


@pytest.mark.parametrize("method", METHODS)
def test_recon3d_tif_puts_the_brightest_voxel_on_a_bead_plane(problem, tmp_path, method,
                                                               capsys):
    out = tmp_path / "vol.tif"
    metrics_path = tmp_path / "m.json"
    status = cli("--psf-stack", problem / "stack.tif", "--raw", problem / "raw.npy",
                 "--method", method, "--iterations", 40, "--tv", 1e-4, "--l1", 1e-3,
                 "--dark", "none", "--out", out, "--metrics-json", metrics_path)
    assert status == 0
    assert f"{method}: 40 it, 5 planes of 48x48" in capsys.readouterr().out
    for view in ("xy", "xz", "yz"):
        assert (tmp_path / f"vol_mip_{view}.png").is_file()
    with tifffile.TiffFile(out) as tif:
        volume = tif.asarray()
        meta = tif.shaped_metadata[0]
    assert volume.shape == (5, N, N) and volume.dtype == np.float32
    assert np.allclose(meta["depths_mm"], DEPTHS)
    z, i, j = np.unravel_index(int(np.argmax(volume)), volume.shape)
    assert z in {b[0] for b in BEADS}
    assert min(abs(i - bi) + abs(j - bj) for bz, bi, bj in BEADS if bz == z) <= 2
    # the xy projection is a view turned upright (rows and columns flipped)
    mip = load_image(tmp_path / "vol_mip_xy.png").astype(float)
    xy = np.clip(volume.max(axis=0), 0, np.percentile(volume.max(axis=0), 99.9))
    turned, same = (float(np.corrcoef(mip.ravel(), c.ravel())[0, 1])
                    for c in (xy[::-1, ::-1], xy))
    assert turned > 0.99 and turned > same + 0.2, (turned, same)
    m = json.loads(metrics_path.read_text())
    for key in ("method", "iterations", "tv", "l1", "shape", "padded_shape", "depths_mm",
                "seconds_total", "seconds_per_iteration", "fft_floor_seconds",
                "ratio_to_fft_floor", "final_relative_residual", "objective", "data_residual",
                "output_volume", "output_mips", "dark_mode", "bin_factor", "plane_energy",
                "plane_peak", "depth_profile"):
        assert key in m, key
    assert m["method"] == method and m["iterations"] == 40
    assert m["shape"] == [5, N, N] and np.allclose(m["depths_mm"], DEPTHS)
    assert len(m["objective"]) == 40
    assert len(m["plane_energy"]) == 5
    assert m["depth_profile"]["peak_plane"] in {b[0] for b in BEADS}
    assert 0 < m["final_relative_residual"] < 0.5
    assert m["fft_floor_seconds"] > 0 and m["ratio_to_fft_floor"] > 0


def test_recon3d_npy_with_depths_to_zarr_with_binning_and_dark(problem, tmp_path):
    import zarr

    # the same stack with a dark pedestal on every plane and the raw image
    stack = np.load(problem / "stack.npy") * 1000.0 + 20.0
    np.save(tmp_path / "stack_dark.npy", stack.astype(np.float32))
    np.save(tmp_path / "raw_dark.npy", np.load(problem / "raw.npy") + 20.0)
    # depths given in reverse plane order: the CLI sorts the planes by depth
    rev = tmp_path / "stack_rev.npy"
    np.save(rev, stack[::-1].astype(np.float32))
    out = tmp_path / "vol.zarr"
    status = cli("--psf-stack", rev, "--depths", ",".join(map(str, DEPTHS[::-1])),
                 "--raw", tmp_path / "raw_dark.npy", "--method", "fista", "--iterations", 10,
                 "--bin", 2, "--dark", "auto", "--out", out, "--metrics-json",
                 tmp_path / "m.json")
    assert status == 0
    group = zarr.open_group(str(out), mode="r")  # an OME-Zarr image, the volume at 0
    arr = group["0"]
    assert arr.shape == (5, N // 2, N // 2)
    assert np.allclose(group.attrs["depths_mm"], DEPTHS)
    assert group.attrs["ome"]["multiscales"][0]["datasets"][0]["path"] == "0"
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["dark_mode"] == "auto" and m["dark_level"] == pytest.approx(20.0, abs=0.5)
    assert m["bin_factor"] == 2 and m["sensor_shape"] == [N // 2, N // 2]
    # writing again over the previous volume needs --overwrite; over a run store / other
    # dir it refuses even then
    again = ("--psf-stack", rev, "--depths", ",".join(map(str, DEPTHS[::-1])), "--raw",
             tmp_path / "raw_dark.npy", "--method", "fista", "--iterations", 2)
    assert cli(*again, "--out", out) == 2
    assert cli(*again, "--out", out, "--overwrite") == 0
    other = tmp_path / "other.zarr"
    zarr.open_group(str(other), mode="w", zarr_format=3)
    assert cli(*again, "--out", other, "--overwrite") == 2
    # --dark DARK_RUN (here a dark image), the form its help offers: subtracted pixel by
    # pixel from every plane and the raw
    np.save(tmp_path / "dark.npy", np.full((N, N), 20.0, np.float32))
    assert cli(*again, "--dark", tmp_path / "dark.npy", "--out", tmp_path / "d.tif",
               "--metrics-json", tmp_path / "d.json") == 0
    m = json.loads((tmp_path / "d.json").read_text())
    assert m["dark_mode"] == "frame" and m["dark_level"] == pytest.approx(20.0)


def test_recon3d_reads_a_run_store(problem, tmp_path):
    from instrument.runs.stacks import import_psf_stack

    run = tmp_path / "RUN.zarr"
    import_psf_stack(problem / "stack.npy", run, depths_mm=DEPTHS)
    assert cli("--psf-stack", run, "--raw", problem / "raw.npy", "--method", "fista",
               "--iterations", 5, "--out", tmp_path / "v.tif", "--metrics-json",
               tmp_path / "m.json") == 0
    m = json.loads((tmp_path / "m.json").read_text())
    assert np.allclose(m["depths_mm"], DEPTHS) and m["psf_stack"] == str(run)


def _bad(problem, tmp_path, **over) -> list[str]:
    args = {"--psf-stack": problem / "stack.tif", "--raw": problem / "raw.npy",
            "--method": "fista", "--iterations": 2, "--dark": "none",
            "--out": tmp_path / "v.tif"}
    args.update(over)
    return [str(x) for kv in args.items() if kv[1] is not None for x in kv]


@pytest.mark.parametrize("over,message", [
    ({"--psf-stack": "NPY"}, "carries no depths"),
    ({"--psf-stack": "NPY", "--depths": "1,2,3"}, "5 planes but 3 depths"),
    ({"--depths": "2,3,4,5,6"}, "records depths"),
    ({"--depths": "1,2"}, "records depths"),  # fewer than recorded (before: a ValueError)
    ({"--depths": "a,b"}, "not a comma-separated list"),
    ({"--raw": "SMALL"}, "differ in size"),
    ({"--method": "gd"}, "unknown method"),
    ({"--iterations": 0}, "iterations must be"),
    ({"--tv": -1}, "--tv -1.0 is outside its limits: TV weight must be >= 0"),
    ({"--dark": "dim"}, "--dark dim: no run store at"),  # a dark run or image: read
    ({"--out": "OUTPNG"}, "use a .tif/.tiff or .zarr"),
    ({"--bin": 100}, "larger than the image"),
    ({"--raw": "MISSING"}, "not found"),
])
def test_bad_input_exits_2_with_one_line(problem, tmp_path, capsys, over, message):
    np.save(tmp_path / "small.npy", np.ones((N // 2, N // 2), np.float32))
    subst = {"NPY": problem / "stack.npy", "SMALL": tmp_path / "small.npy",
             "OUTPNG": tmp_path / "v.png", "MISSING": tmp_path / "nope.npy"}
    over = {k: subst.get(v, v) if isinstance(v, str) else v for k, v in over.items()}
    argv = _bad(problem, tmp_path, **over)
    status = main(["recon3d", *map(str, argv)])
    err = capsys.readouterr().err
    assert status == 2
    assert err.startswith("diffuserlab: error:") and err.count("\n") == 1
    assert message in err


def test_admm_is_called_with_the_documented_signature(problem, tmp_path, monkeypatch):
    calls = []

    def fake_admm3d(op, b, *, iterations, tv=None, l1=None, nonneg=True):
        calls.append({"iterations": iterations, "tv": tv, "l1": l1, "nonneg": nonneg})
        return recon.volume.fista3d(op, b, iterations=iterations, tv=tv, l1=l1, nonneg=nonneg)

    monkeypatch.setitem(recon.volume.api.SOLVERS, "admm", fake_admm3d)
    assert cli(*_bad(problem, tmp_path, **{"--method": "admm", "--tv": 2e-4, "--l1": 1e-3,
                                           "--metrics-json": tmp_path / "m.json"})) == 0
    assert calls == [{"iterations": 2, "tv": 2e-4, "l1": 1e-3, "nonneg": True}]
    assert json.loads((tmp_path / "m.json").read_text())["method"] == "admm"


def test_defaults_are_automatic():
    args = parser().parse_args(["recon3d", "--psf-stack", "s.tif", "--raw", "r.tif"])
    assert args.tv == "auto" and float(args.l1) == 0.0 and args.method == "auto"

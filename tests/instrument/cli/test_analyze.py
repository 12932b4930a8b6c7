"""Tests of ``diffuserlab analyze`` (instrument.cli.analyze) on a small synthetic stack.

The stack is a random caustic-like pattern (thresholded smoothed noise in a round
aperture) magnified by (1 + d/z) / (1 + d/z_far) per depth with scipy.ndimage.zoom
about the centre, the depth scaling of Sec. 3.2 / Fig. 4.2. The CLI is called
through a parser built here with the module's add_subcommands.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
from scipy import ndimage

from instrument.cli import main

N = 64
D_MM = 5.0
PITCH_UM = 5.0
DEPTHS = [20.0, 30.0, 45.0, 65.0, 100.0]


def caustic_stack(depths=DEPTHS, n: int = N, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    g = ndimage.gaussian_filter(rng.standard_normal((n, n)), 1.5)
    c = (n - 1) / 2
    yy, xx = np.mgrid[:n, :n] - c
    base = np.maximum(g - np.quantile(g, 0.8), 0.0) * (np.hypot(yy, xx) < 0.3 * n)
    planes = []
    for z in depths:
        m = (1 + D_MM / z) / (1 + D_MM / max(depths))
        big = ndimage.zoom(base, m, order=1)
        top = (big.shape[0] - n) // 2
        planes.append(big[top:top + n, top:top + n])
    return np.array(planes, np.float32)


@pytest.fixture(scope="module")
def stack_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("analysis")
    path = d / "stack.tif"
    # stored out of depth order: the CLI sorts by depth
    order = [2, 0, 4, 1, 3]
    tifffile.imwrite(path, caustic_stack()[order], photometric="minisblack",
                     metadata={"depths_mm": [DEPTHS[i] for i in order]})
    np.save(d / "stack.npy", caustic_stack())
    return path


def analyze(kind: str, stack, out, *extra) -> int:
    argv = ["analyze", kind, "--psf-stack", str(stack), "--pitch-um", str(PITCH_UM),
            "--d-mm", str(D_MM), "--out", str(out), *map(str, extra)]
    return main(argv)


def outputs(out, kind: str) -> dict:
    assert (out / f"{kind}.png").stat().st_size > 1000
    return json.loads((out / f"{kind}.json").read_text())


def test_resolution(stack_file, tmp_path, capsys):
    assert analyze("resolution", stack_file, tmp_path) == 0
    assert "70% half width" in capsys.readouterr().out
    r = outputs(tmp_path, "resolution")
    assert r["depths_mm"] == DEPTHS and r["warnings"] == []
    rows = r["per_depth"]
    assert [row["depth_mm"] for row in rows] == DEPTHS
    for row in rows:
        px = row["autocorrelation_half_width_px"]
        assert 0.5 < px["x"] < 10 and 0.5 < px["y"] < 10
        mm = row["autocorrelation_half_width_object_mm"]["x"]
        assert mm == pytest.approx(px["x"] * PITCH_UM * 1e-3 * row["depth_mm"] / D_MM)
        # the 0.8 inner-product shift is narrower than the 70 % half width
        assert row["inner_product_shift_px"]["x"] < px["x"]
        assert 1 < row["inner_product_scale"] < 2
        assert row["hyperfocal_distance_mm"] > 0
        assert 0 < row["depth_of_field_near_mm"]
    obj = [row["autocorrelation_half_width_object_mm"]["x"] for row in rows]
    assert obj == sorted(obj)  # coarser in object space with depth (m = d/z)


def test_similarity(stack_file, tmp_path):
    assert analyze("similarity", stack_file, tmp_path) == 0
    s = outputs(tmp_path, "similarity")
    assert s["nearest_depth_mm"] == 20.0 and s["farthest_depth_mm"] == 100.0
    assert s["index"] == 2 and s["index_depth_mm"] == 45.0
    ip = np.array(s["inner_products"])
    assert ip.shape == (5,) and ip[2] == pytest.approx(1.0)
    assert s["inner_product_max_other"] < 0.95
    assert 0 < s["cross_correlation_max"] < 1
    auto = np.array(s["autocorrelation_x_nearest"])
    assert auto.size == len(s["lags_x_px"]) == 2 * N - 1 and auto.max() == pytest.approx(1.0)
    assert len(s["cross_correlation_x"]) == 2 * N - 1


def test_condition(stack_file, tmp_path):
    assert analyze("condition", stack_file, tmp_path, "--separations-px", "1,4",
                   "--k-max", 8, "--depth", 45) == 0
    c = outputs(tmp_path, "condition")
    assert c["depth_mm"] == 45.0 and c["ks"] == list(range(2, 9))
    close, far = (np.array(v) for v in c["condition_numbers"])
    assert np.all(close >= 1) and np.all(np.diff(close) >= -1e-9 * close[1:])
    assert close[-1] > far[-1]  # closer sources are worse conditioned
    assert c["separations_object_mm"][1] == pytest.approx(4 * PITCH_UM * 1e-3 * 45 / D_MM)
    assert c["warnings"] == []
    # sources shifted far out of the 64 px frame: flagged
    assert analyze("condition", stack_file, tmp_path / "wide", "--separations-px", "12",
                   "--k-max", 8) == 0
    assert "keeps" in outputs(tmp_path / "wide", "condition")["warnings"][0]


def test_condition_axial(stack_file, tmp_path, capsys):
    from recon.analysis import condition_vs_k_axial

    assert analyze("condition", stack_file, tmp_path, "--axial", "--separations-planes", "1,2",
                   "--k-max", 4) == 0
    out = capsys.readouterr().out
    assert "plane(s) apart" in out
    c = outputs(tmp_path, "condition")
    assert c["mode"] == "axial"
    one, two = c["per_separation"]
    # 5 planes: 4 sources fit one plane apart (centred: planes 0..3), 3 fit two apart
    assert one["ks"] == [2, 3, 4] and two["ks"] == [2, 3]
    assert one["source_depths_mm"] == DEPTHS[:4] and two["source_depths_mm"] == DEPTHS[::2]
    assert "only 3 of 4" in c["warnings"][0]
    inv = 1 / np.array(DEPTHS)
    assert one["separation_inverse_mm"] == pytest.approx(np.mean(-np.diff(inv[:4])))
    np.testing.assert_allclose(one["condition_numbers"],
                               condition_vs_k_axial(caustic_stack(), 1, [2, 3, 4]), rtol=1e-6)
    assert np.all(np.diff(one["condition_numbers"]) >= -1e-9)
    # from a given depth, and as an x-z grid (Fig. 4.4)
    assert analyze("condition", stack_file, tmp_path / "xz", "--axial", "--depth", 30,
                   "--separations-planes", "1", "--xz-px", 3, "--k-max", 9) == 0
    xz = outputs(tmp_path / "xz", "condition")["per_separation"][0]
    assert xz["ks"] == list(range(2, 10)) and xz["source_depths_mm"] == [30.0, 45.0, 65.0]
    assert analyze("condition", stack_file, tmp_path / "bad", "--axial",
                   "--separations-planes", "1.5") == 2
    assert "whole numbers" in capsys.readouterr().err


def test_distinguish(stack_file, tmp_path, capsys):
    assert analyze("distinguish", stack_file, tmp_path, "--separations-px", "1,3,6",
                   "--iterations", 80, "--depth", 45) == 0
    d = outputs(tmp_path, "distinguish")
    assert d["depth_mm"] == 45.0 and len(d["two_point"]["dips"]) == 3
    assert d["two_point"]["dips"][0] < 0.2  # 1 px: the same pixel neighbourhood
    lim = d["two_point"]["limit_px"]
    assert lim is not None and lim in (3.0, 6.0)
    assert d["limits_object_mm"]["2"] == pytest.approx(lim * PITCH_UM * 1e-3 * 45 / D_MM)
    assert "two-point: resolved from" in capsys.readouterr().out


def test_grid_fewer_planes_for_a_narrower_scene(stack_file, tmp_path, capsys):
    assert analyze("grid", stack_file, tmp_path / "all") == 0
    assert "lateral bin" in capsys.readouterr().out
    full = outputs(tmp_path / "all", "grid")
    assert analyze("grid", stack_file, tmp_path / "scene", "--scene-range", "40,70") == 0
    part = outputs(tmp_path / "scene", "grid")
    assert full["reasons"] and part["reasons"]
    assert len(part["depths_mm"]) < len(full["depths_mm"])
    assert full["depths_mm"][0] == pytest.approx(20) and full["depths_mm"][-1] == 100
    assert part["span_mm"] == [40, 70]
    assert full["lateral_bin"] >= 1


def test_fov(stack_file, tmp_path):
    assert analyze("fov", stack_file, tmp_path, "--alpha-c-deg", 40, "--beta-deg", 0.5) == 0
    f = outputs(tmp_path, "fov")
    assert f["sensor_width_mm"]["x"] == pytest.approx(N * PITCH_UM * 1e-3)
    widths = [p["psf_width_mm"]["x"] for p in f["per_depth"]]
    assert widths[0] > widths[-1] > 0.1  # nearer depths magnify the caustic more
    # a 0.32 mm sensor 5 mm behind the diffuser: geometry, not alpha_c, limits the FoV
    for p in f["per_depth"]:
        assert p["limited_by"]["x"] == "geometry"
        assert p["fov_half_angle_deg"]["x"] == pytest.approx(
            0.5 + p["geometric_half_angle_deg"]["x"])
    assert 0.5 < f["fov_half_angle_deg"]["x"] < 40.5
    assert analyze("fov", stack_file, tmp_path / "narrow", "--alpha-c-deg", 1.0) == 0
    g = outputs(tmp_path / "narrow", "fov")
    assert g["fov_half_angle_deg"]["x"] == pytest.approx(1.0)
    assert g["per_depth"][0]["limited_by"]["x"] == "sensor angular cutoff"


def test_npy_needs_depths_and_binning_scales_the_pitch(stack_file, tmp_path):
    npy = stack_file.parent / "stack.npy"
    assert analyze("grid", npy, tmp_path, "--depths", ",".join(map(str, DEPTHS)),
                   "--bin", 2) == 0
    g = outputs(tmp_path, "grid")
    assert g["stack_shape"] == [5, N // 2, N // 2] and g["pitch_um"] == 2 * PITCH_UM


@pytest.mark.parametrize("kind,extra,message", [
    ("grid", ["--psf-stack", "NPY"], "carries no depths"),
    ("fov", [], "needs --alpha-c-deg"),
    ("resolution", ["--d-mm", "-1"], "--d-mm must be"),
    ("grid", ["--scene-range", "40"], "ZMIN,ZMAX"),
    ("grid", ["--scene-range", "200,300"], "outside the calibrated range"),
    ("condition", ["--depth", "33"], "no PSF within"),
    ("condition", ["--separations-px", "a"], "comma-separated"),
    ("similarity", ["--index", "9"], "index"),
])
def test_bad_input_exits_2_with_one_line(stack_file, tmp_path, capsys, kind, extra, message):
    extra = [str(stack_file.parent / "stack.npy") if e == "NPY" else e for e in extra]
    argv = ["analyze", kind, "--psf-stack", str(stack_file), "--pitch-um", str(PITCH_UM),
            "--d-mm", str(D_MM), "--out", str(tmp_path), *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("diffuserlab: error:") and err.count("\n") == 1
    assert message in err

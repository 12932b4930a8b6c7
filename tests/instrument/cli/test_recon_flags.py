"""One meaning per flag across ``recon``, ``recon3d``, ``recon-run`` and ``capture live``:
``--dark`` takes the same forms with the same default everywhere, the ``--psf-grid`` path
uses the plain ``--method``, ``--l1`` and ``--dark``, and the former ``--grid-*`` twins
still work as deprecated aliases that say so."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile

from diffuserlab.errors import InputError
from instrument.cli import build_parser, main
from instrument.cli.recon_flags import dark_for_grid, grid_method
from instrument.processing.reconstruct_files import resolve_dark
from recon.options import dark_arg, l1_given

#: Each command's argv without --dark (the parser only: nothing runs).
COMMANDS = {
    "recon": ["recon", "--psf", "p.npy", "--raw", "r.npy"],
    "recon3d": ["recon3d", "--psf-stack", "s.zarr", "--raw", "r.npy"],
    "recon-run": ["recon-run", "RUN.zarr", "--psf", "p.npy"],
    "capture live": ["capture", "live", "--psf", "p.npy", "--simulate"],
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_dark_has_one_default_and_the_same_forms(command):
    parser = build_parser()
    argv = COMMANDS[command]
    assert parser.parse_args(argv).dark.auto
    for text, attr, value in (("none", "none", True), ("12.5", "level", 12.5),
                              ("dark.zarr", "path", "dark.zarr")):
        assert getattr(parser.parse_args([*argv, "--dark", text]).dark, attr) == value


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_negative_dark_is_a_usage_error(command, capsys):
    with pytest.raises(SystemExit) as info:
        build_parser().parse_args([*COMMANDS[command], "--dark", "-3"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--dark" in err and "DN >= 0" in err


@pytest.mark.parametrize("command", ["recon", "recon3d", "recon-run"])
def test_l1_default_is_left_to_the_model(command):
    """No --l1: 0 for one PSF, 1e-3 for FISTA on a grid (resolved where the model is known)."""
    l1 = build_parser().parse_args(COMMANDS[command]).l1
    assert l1 == 0.0 and l1_given(l1) is None
    assert l1_given(build_parser().parse_args([*COMMANDS[command], "--l1", "0"]).l1) == 0.0


def test_the_grid_twins_are_deprecated_aliases(capsys):
    base = ["recon", "--psf-grid", "g.zarr", "--raw", "r.npy"]
    old = build_parser().parse_args([*base, "--grid-l1", "0.01", "--grid-method", "admm",
                                     "--grid-dark", "5"])
    err = capsys.readouterr().err.splitlines()
    assert err == [f"diffuserlab: note: --grid-{f} is deprecated; use --{f} (same meaning)"
                   for f in ("l1", "method", "dark")]
    new = build_parser().parse_args([*base, "--l1", "0.01", "--method", "admm", "--dark", "5"])
    assert capsys.readouterr().err == ""
    assert (old.l1, old.method, old.dark) == (new.l1, new.method, new.dark) == (0.01, "admm",
                                                                                 "5")
    assert build_parser().parse_args(["recon-run", "RUN.zarr", "--psf-grid", "g.zarr",
                                      "--grid-l1", "0.002"]).l1 == 0.002


def test_help_shows_the_plain_flags_only(capsys):
    with pytest.raises(SystemExit):
        main(["recon", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "--grid-" not in out and "--dark auto|none|DN|DARK_RUN" in out
    for unit in ("too short), s", "pixels per side", "a level in DN", "DN; > 0"):
        assert unit in out


def test_dark_has_one_meaning(tmp_path):
    """``resolve_dark`` is what every command does with ``--dark``: a plain PSF's
    ``auto`` is its dark corner (estimated by recon.reconstruct), a calibration run's
    dark-subtracted PSF takes the recorded level or asks for one, a level or frame is
    added back to a calibrated PSF so that it stays as calibrated."""
    frame = np.full((4, 5), 7.0, np.float32)
    np.save(tmp_path / "dark.npy", frame)
    psf = np.ones((4, 5), np.float32)
    image = dark_arg(str(tmp_path / "dark.npy"))
    out, dark = resolve_dark(image, psf, calibrated=False)
    assert np.array_equal(dark, frame) and out is psf
    assert resolve_dark(dark_arg("auto"), psf, calibrated=False) == (psf, "auto")
    assert resolve_dark(dark_arg("auto"), psf, calibrated=False, recorded=3.0)[1] == "auto"
    assert resolve_dark(dark_arg("none"), psf, calibrated=True)[1] == "none"
    out, dark = resolve_dark(dark_arg("auto"), psf, calibrated=True, recorded=3.0)
    assert dark == 3.0 and np.array_equal(out, psf + 3.0)
    out, dark = resolve_dark(dark_arg("4"), psf, calibrated=True)
    assert dark == 4.0 and np.array_equal(out, psf + 4.0)
    with pytest.raises(InputError, match="calibrated .dark-subtracted. PSF: give the frames'"):
        resolve_dark(dark_arg("auto"), psf, calibrated=True, what="--psf RUN.zarr")
    assert [dark_for_grid(dark_arg(t)) for t in ("auto", "none", "4")] == ["auto", "none", 4.0]
    with pytest.raises(InputError, match="use auto, none or a number"):
        dark_for_grid(image)


def test_grid_method():
    assert grid_method("auto", ("fista", "admm")) == "fista"
    assert grid_method("admm", ("fista", "admm")) == "admm"
    with pytest.raises(InputError, match="--method wiener: a --psf-grid model is solved with "
                       "fista or admm"):
        grid_method("wiener", ("fista", "admm"))


def test_recon_subtracts_a_dark_image_as_the_same_level(tmp_path):
    """``--dark IMAGE`` (a frame with the light blocked) gives the image ``--dark DN``
    gives when the frame holds that level everywhere."""
    rng = np.random.default_rng(0)
    psf = np.zeros((48, 64), np.float32)
    psf[rng.integers(0, 48, 30), rng.integers(0, 64, 30)] = 1000.0
    scene = np.zeros_like(psf)
    scene[20:24, 30:34] = 1.0
    raw = np.real(np.fft.ifft2(np.fft.fft2(psf) * np.fft.fft2(scene))).astype(np.float32)
    for name, array in (("psf", psf + 20), ("raw", raw + 20),
                        ("dark", np.full_like(psf, 20))):
        np.save(tmp_path / f"{name}.npy", array)
    outs = {}
    for dark in ("20", str(tmp_path / "dark.npy")):
        out = tmp_path / f"r{len(outs)}"
        assert main(["recon", "--psf", str(tmp_path / "psf.npy"), "--raw",
                     str(tmp_path / "raw.npy"), "--method", "fista", "--tv", "1e-3",
                     "--iterations", "20", "--dark", dark, "--out", str(out),
                     "--metrics-json", f"{out}.json"]) == 0
        outs[dark] = tifffile.imread(out.with_suffix(".tif"))
        assert json.loads(out.with_suffix(".json").read_text())["method"] == "fista"
    first, second = outs.values()
    assert np.allclose(first, second, rtol=1e-5, atol=1e-6)

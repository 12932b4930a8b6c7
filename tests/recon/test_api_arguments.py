"""Non-integer, negative or non-finite numeric arguments of the notebook APIs
(:func:`recon.reconstruct`, :func:`recon.reconstruct_volume`) raise ReconInputError
with the message the CLI shows for the same value."""

from __future__ import annotations

import numpy as np
import pytest

import recon
from recon import reconstruct_volume
from recon.errors import ReconInputError

RNG = np.random.default_rng(0)
PSF = RNG.random((16, 16))
STACK = RNG.random((2, 16, 16))
RAW = PSF + 1.0  # above the PSF's "dark corner" (a random PSF has none): light to image


@pytest.mark.parametrize("kwargs, message", [
    ({"iterations": 2.5}, "iterations=2.5: give a whole number (maximum iterations)"),
    ({"iterations": 0}, "iterations=0 is outside its limits: maximum iterations must be >= 1"),
    ({"iterations": True}, "iterations=True: give a number, not a truth value"),
    ({"bin_factor": 1.5}, "bin_factor=1.5: give a whole number (binning factor)"),
    ({"bin_factor": -2}, "bin_factor=-2 is outside its limits: binning factor must be >= 1"),
    ({"seed": -1}, "seed=-1 is outside its limits: erasure seed must be >= 0"),
    ({"seed": 0.5}, "seed=0.5: give a whole number"),
    ({"erase": 1.5}, "erase=1.5 is outside its limits: erased fraction must be 0 to 0.99"),
    ({"erase": -0.1}, "erase=-0.1 is outside its limits"),
    ({"erase": float("nan")}, "erase=nan is outside its limits"),
    ({"tv": -1.0}, "tv=-1.0 is outside its limits: TV weight must be >= 0"),
])
def test_reconstruct_refuses(kwargs, message):
    with pytest.raises(ReconInputError) as info:
        recon.reconstruct(PSF, RAW, "fista", **kwargs)
    assert message in str(info.value)


def test_reconstruct_accepts_numpy_integers():
    out = recon.reconstruct(PSF, RAW, "fista", iterations=np.int64(2), bin_factor=np.int32(1))
    assert out.image.shape == PSF.shape


@pytest.mark.parametrize("kwargs, message", [
    ({"iterations": 2.5}, "iterations=2.5: give a whole number"),
    ({"iterations": -3}, "iterations=-3 is outside its limits: maximum iterations must be >= 1"),
    ({"bin_factor": 0.5}, "bin_factor=0.5: give a whole number"),
    ({"bin_factor": 0}, "bin_factor=0 is outside its limits: binning factor must be >= 1"),
    ({"tv": "x"}, "tv='x': give a number or auto (TV weight)"),
    ({"l1": float("inf")}, "l1=inf: give a finite number (l1 weight)"),
])
def test_reconstruct_volume_refuses(kwargs, message):
    with pytest.raises(ReconInputError) as info:
        reconstruct_volume(STACK, [1.0, 2.0], RAW, method="fista", **kwargs)
    assert message in str(info.value)


def test_reconstruct_volume_accepts_numpy_integers():
    rec = reconstruct_volume(STACK, [1.0, 2.0], RAW, method="fista", iterations=np.int64(2))
    assert rec.volume.shape[0] == 2


def test_each_front_end_names_the_value_its_way(tmp_path, capsys):
    """One declaration words the problem; the command line names the flag (``--bin``),
    Python the keyword (``bin_factor=``), and neither the other's."""
    from instrument.cli import main

    np.save(tmp_path / "p.npy", PSF)
    assert main(["recon", "--psf", str(tmp_path / "p.npy"), "--raw", str(tmp_path / "p.npy"),
                 "--bin", "0", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    with pytest.raises(ReconInputError) as info:
        recon.reconstruct(PSF, RAW, bin_factor=0)
    why = "is outside its limits: binning factor must be >= 1"
    assert err == f"diffuserlab: error: --bin 0 {why}"
    assert str(info.value) == f"bin_factor=0 {why}"
    for kwargs in ({"tv": -1.0}, {"l1": "x"}, {"iterations": 0}, {"erase": 2.0}):
        with pytest.raises(ReconInputError) as info:
            recon.reconstruct(PSF, RAW, **kwargs)
        assert "--" not in str(info.value)

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
    ({"iterations": 2.5}, "iterations must be an integer >= 1, got 2.5"),
    ({"iterations": 0}, "iterations must be an integer >= 1, got 0"),
    ({"iterations": True}, "iterations must be an integer >= 1"),
    ({"bin_factor": 1.5}, "bin_factor must be an integer >= 1, got 1.5"),
    ({"bin_factor": -2}, "bin_factor must be an integer >= 1, got -2"),
    ({"seed": -1}, "seed must be an integer >= 0, got -1"),
    ({"seed": 0.5}, "seed must be an integer >= 0"),
    ({"erase": 1.5}, "erased fraction 1.5 is outside [0, 1)"),
    ({"erase": -0.1}, "erased fraction -0.1 is outside [0, 1)"),
    ({"erase": float("nan")}, "erase must be a finite number"),
    ({"tv": -1.0}, "tv weight must be a finite number >= 0"),
])
def test_reconstruct_refuses(kwargs, message):
    with pytest.raises(ReconInputError) as info:
        recon.reconstruct(PSF, RAW, "fista", **kwargs)
    assert message in str(info.value)


def test_reconstruct_accepts_numpy_integers():
    out = recon.reconstruct(PSF, RAW, "fista", iterations=np.int64(2), bin_factor=np.int32(1))
    assert out.image.shape == PSF.shape


@pytest.mark.parametrize("kwargs, message", [
    ({"iterations": 2.5}, "--iterations must be an integer >= 1, got 2.5"),
    ({"iterations": -3}, "--iterations must be an integer >= 1, got -3"),
    ({"bin_factor": 0.5}, "--bin must be an integer >= 1, got 0.5"),
    ({"bin_factor": 0}, "--bin must be an integer >= 1, got 0"),
    ({"tv": "x"}, "--tv: tv weight must be a finite number >= 0 or 'auto'"),
    ({"l1": float("inf")}, "--l1: l1 weight must be a finite number >= 0 or 'auto'"),
])
def test_reconstruct_volume_refuses(kwargs, message):
    with pytest.raises(ReconInputError) as info:
        reconstruct_volume(STACK, [1.0, 2.0], RAW, method="fista", **kwargs)
    assert message in str(info.value)


def test_reconstruct_volume_accepts_numpy_integers():
    rec = reconstruct_volume(STACK, [1.0, 2.0], RAW, method="fista", iterations=np.int64(2))
    assert rec.volume.shape[0] == 2


def test_cli_and_api_say_the_same(tmp_path, capsys):
    from instrument.cli import main

    np.save(tmp_path / "p.npy", PSF)
    assert main(["recon", "--psf", str(tmp_path / "p.npy"), "--raw", str(tmp_path / "p.npy"),
                 "--iterations", "0", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    with pytest.raises(ReconInputError) as info:
        recon.reconstruct(PSF, RAW, iterations=0)
    assert err.strip() == f"diffuserlab: error: {info.value}"

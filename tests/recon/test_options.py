"""The option names of :mod:`recon.options` (what the command line offers) are exactly
those of the tables that hold the solvers and models."""

from __future__ import annotations

import argparse

import pytest

from recon import options


def test_the_2d_methods_and_their_summaries_are_the_solver_table():
    from recon.solvers import METHODS, SOLVERS

    assert options.METHODS == METHODS
    assert options.METHOD_SUMMARIES == {k: s.summary for k, s in SOLVERS.items()}


def test_the_3d_and_grid_tables_match():
    from recon.cgh.evaluation import METHODS as HOLO
    from recon.spatial.api import GRID_METHODS, GRID_SOLVERS
    from recon.spatial.choice import MODELS
    from recon.volume.api import METHODS as VOLUME

    assert options.VOLUME_METHODS == VOLUME
    assert set(options.GRID_METHODS) == set(GRID_SOLVERS) and GRID_METHODS is options.GRID_METHODS
    assert MODELS is options.MODELS and HOLO is options.HOLOGRAM_METHODS


def test_weight_arg_is_reexported_and_parses():
    from recon.auto import weight_arg

    assert weight_arg is options.weight_arg
    assert weight_arg(" AUTO ") == "auto" and weight_arg("1e-3") == 1e-3
    with pytest.raises(ValueError):
        weight_arg("lots")


@pytest.mark.parametrize(("text", "auto", "none", "level", "path"), [
    ("auto", True, False, None, None), ("None", False, True, None, None),
    ("12.5", False, False, 12.5, None), ("0", False, False, 0.0, None),
    ("dark.zarr", False, False, None, "dark.zarr"),
])
def test_dark_arg_forms(text, auto, none, level, path):
    value = options.dark_arg(text)
    assert (value.auto, value.none, value.level, value.path) == (auto, none, level, path)
    assert value == text


@pytest.mark.parametrize("text", ["-1", "nan", "inf", "  "])
def test_dark_arg_refuses(text):
    with pytest.raises(argparse.ArgumentTypeError):
        options.dark_arg(text)

"""Every ``diffuserlab`` subcommand's ``--help`` lists all of its options (no option
hidden behind a pass-through argument), e.g. ``holo evaluate --help`` shows ``--size``."""

from __future__ import annotations

import argparse

import pytest

from instrument.cli import build_parser, main


def _leaves(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, parser) of every subcommand without further subcommands."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
        return
    for action in subs:
        for name, child in action.choices.items():
            yield from _leaves(child, (*path, name))


LEAVES = dict(_leaves(build_parser()))


def test_the_commands_are_all_there():
    names = {" ".join(p) for p in LEAVES}
    assert {"recon", "demo", "recon3d", "analyze resolution", "analyze fov", "validate",
            "devices", "runs show", "runs import-psf", "benchmark recon", "holo evaluate",
            "holo benchmark", "calibrate psf-sweep", "calibrate resume", "align mask"} <= names


@pytest.mark.parametrize("path", sorted(LEAVES), ids=" ".join)
def test_help_lists_every_option(path, capsys):
    options = [s for a in LEAVES[path]._actions for s in a.option_strings
               if s.startswith("--") and a.help is not argparse.SUPPRESS]
    assert options, f"{' '.join(path)} has no options"
    with pytest.raises(SystemExit) as info:
        main([*path, "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for option in options:
        assert option in out, f"{' '.join(path)} --help does not show {option}"


def test_holo_evaluate_help_shows_its_options(capsys):
    with pytest.raises(SystemExit):
        main(["holo", "evaluate", "--help"])
    out = capsys.readouterr().out
    for option in ("--size", "--factors", "--seeds", "--images", "--quick", "--strict"):
        assert option in out


def test_benchmark_recon_refuses_unknown_options(capsys):
    with pytest.raises(SystemExit):
        main(["benchmark", "recon", "--only", "volume_speed", "--bogus"])
    capsys.readouterr()

"""Each calibration routine's parameters are one typed model
(calibration_routines/parameters.py): the ``calibrate`` options and the GUI's forms are
generated from it, bad values are refused naming the option and its limits, and the
GUI's plan is the command's plan without any argv."""

from __future__ import annotations

import argparse

import pytest

from calibration_routines.cli.calibrate import add_subcommands, plan_from_args
from calibration_routines.parameters import PARAMETERS, PsfSweepParams, SlmLutParams
from diffuserlab.errors import InputError
from instrument.options import option

#: The options ``calibrate`` had before the models, with their defaults (tests, docs
#: and scripts use them): none may change.
HISTORIC = {
    "dark": {"--frames": None, "--exposure-s": None},
    "psf-sweep": {"--frames": None, "--z-min": None, "--z-max": None, "--spacing": "inverse",
                  "--n-depths": None, "--c-per-mm": None, "--probe-step": False,
                  "--x-mm": 0.0, "--y-mm": 0.0},
    "psf-grid": {"--frames": None, "--mode": "leds", "--n": 3, "--spacing-mm": None,
                 "--z-mm": 40.0, "--led-step": 2, "--falloff-sigma-deg": None},
    "psf-blind": {"--frames": None, "--images": 4, "--grid": 3, "--z-mm": ...,
                  "--node-spacing-mm": ..., "--exposure-s": ..., "--rounds": 6, "--bin": 1},
    "angular-response": {"--frames": None, "--z-mm": None, "--max-angle-deg": None,
                         "--n-angles": None, "--beta-deg": None},
    "slm-lut": {"--frames": None, "--levels": None, "--period-px": None,
                "--no-nd-filter": False},
    "psf-from-scenes": {"--frames": None, "--z-mm": ..., "--images": 12, "--patterns": "random",
                        # --iterations: since issue 65 the cap of an estimate that stops
                        # once converged (26-30 iterations on the real pairs), was 20 fixed
                        "--display": "slm", "--iterations": 100, "--recipe-images": None},
}


def _routine_parsers() -> dict[str, argparse.ArgumentParser]:
    parser = argparse.ArgumentParser(prog="diffuserlab")
    add_subcommands(parser.add_subparsers(dest="command"))
    cal = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    sub = next(a for a in cal.choices["calibrate"]._actions
               if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def test_the_models_keep_every_historic_flag_and_default():
    assert list(PARAMETERS) == list(HISTORIC)
    for routine, flags in HISTORIC.items():
        specs = {s.flag: s for s in PARAMETERS[routine].specs()}
        assert list(specs) == list(flags), routine
        for flag, default in flags.items():
            assert specs[flag].default == default, (routine, flag)


def test_calibrate_options_are_generated_from_the_models():
    parsers = _routine_parsers()
    for routine, model in PARAMETERS.items():
        actions = {a.option_strings[-1]: a for a in parsers[routine]._actions
                   if a.option_strings}
        for s in model.specs():
            a = actions[s.flag]
            assert a.dest == s.dest and a.help == s.help, (routine, s.flag)
            assert a.required == s.required
            if s.is_flag:
                assert isinstance(a, argparse._StoreTrueAction)
            else:
                assert a.type is s.type and (a.default == s.default or s.required)
                assert tuple(a.choices or ()) == (s.choices or ())
            if s.unit:
                assert f", {s.unit}" in a.help  # help names the unit
            if s.limits:
                assert s.limits in a.help
    assert "--falloff-run" in {o for a in parsers["psf-grid"]._actions
                               for o in a.option_strings}
    assert "--apply" in parsers["slm-lut"].format_help()


def test_a_limit_changed_in_the_model_changes_the_options_and_the_refusal():
    class Narrow(PsfSweepParams):
        n_depths: int | None = option(None, ge=4, help="number of depth planes")

    parser = argparse.ArgumentParser()
    Narrow.add_arguments(parser)
    assert ">= 4" in parser.format_help().replace("\n", " ").replace("  ", " ")
    assert PsfSweepParams.from_text({"--n-depths": "3"}).n_depths == 3
    with pytest.raises(InputError, match=r"--n-depths 3 is outside its limits: number of "
                       r"depth planes must be >= 4"):
        Narrow.from_text({"--n-depths": "3"})


@pytest.mark.parametrize("routine, values, message", [
    ("psf-sweep", {"--n-depths": "many"}, r"^--n-depths: 'many' is not a whole number$"),
    ("psf-sweep", {"--z-min": "-5"}, r"--z-min -5.0 is outside its limits: nearest depth "
                                     r"in mm must be > 0 mm"),
    ("psf-sweep", {"--spacing": "log"}, r"--spacing 'log': use one of inverse, uniform"),
    ("slm-lut", {"--levels": "300"}, r"--levels 300 .*must be 8 to 256"),
    ("angular-response", {"--max-angle-deg": "85"}, r"must be 0 \(excl.\) to 85 \(excl.\)"),
    ("psf-blind", {"--z-mm": "30"}, r"give --node-spacing-mm \(spacing of the recovered"),
    ("dark", {"--frames": "0"}, r"--frames 0 is outside its limits: frames per point must "
                                r"be >= 1"),
    ("dark", {"--no-such": "1"}, r"unknown option '--no-such'"),
])
def test_bad_values_name_the_option_and_its_limits(routine, values, message):
    with pytest.raises(InputError, match=message):
        PARAMETERS[routine].from_text(values)


def test_models_are_typed_and_frozen():
    p = SlmLutParams.from_text({"--levels": "32", "--no-nd-filter": True, "--frames": ""})
    assert (p.n_levels, p.no_nd_filter, p.frames) == (32, True, None)
    with pytest.raises(Exception):  # noqa: B017 (pydantic's frozen-instance error)
        p.n_levels = 8
    schema = SlmLutParams.model_json_schema()
    assert schema["properties"]["n_levels"]["anyOf"][0] == {"maximum": 256, "minimum": 8,
                                                            "type": "integer"}


def test_the_guis_plan_is_the_commands_plan_without_argv():
    from gui.jobs import build_plan, routine_options
    from instrument.devices.virtual_bench import VirtualBench

    assert [o.flag for o in routine_options("psf-grid")] == list(HISTORIC["psf-grid"])
    parser = argparse.ArgumentParser(prog="diffuserlab")
    add_subcommands(parser.add_subparsers(dest="command"))
    with VirtualBench(seed=0) as bench:
        for routine, gui_values, argv in (
                ("psf-sweep", {"--z-min": "30", "--z-max": "60", "--n-depths": "3",
                               "--spacing": "uniform"},
                 ["--z-min", "30", "--z-max", "60", "--n-depths", "3", "--spacing",
                  "uniform"]),
                ("psf-grid", {"--mode": "stage", "--n": "2", "--z-mm": "35"},
                 ["--mode", "stage", "--n", "2", "--z-mm", "35"]),
                ("dark", {"--frames": "2"}, ["--frames", "2"]),
                ("slm-lut", {"--levels": "16", "--no-nd-filter": True},
                 ["--levels", "16", "--no-nd-filter"])):
            gui_plan = build_plan(bench, routine, gui_values)
            args = parser.parse_args(["calibrate", routine, "--simulate", *argv])
            cli_plan = plan_from_args(args, bench)
            assert gui_plan.name == cli_plan.name and gui_plan.params == cli_plan.params, \
                routine


def test_the_gui_never_synthesises_a_command_line():
    import inspect

    import gui.jobs

    source = inspect.getsource(gui.jobs)
    assert "argv" not in source and "parse_args" not in source


def test_options_page_matches_the_models(tmp_path):
    from calibration_routines.parameters_doc import DEFAULT_PAGE, main, page

    assert DEFAULT_PAGE.read_text(encoding="utf-8") == page(), (
        "docs/calibration-options.md is out of date: run python -m "
        "calibration_routines.parameters_doc")
    for model in PARAMETERS.values():
        for s in model.specs():
            assert f"`{s.flag}`" in page()
    stale = tmp_path / "options.md"
    stale.write_text(page().replace("nearest depth", "near"), encoding="utf-8")
    assert main(["--check", "--page", str(stale)]) == 1
    assert main(["--page", str(stale)]) == 0 and stale.read_text(encoding="utf-8") == page()


ALIGN_HISTORIC = {"--mask-seed": None, "--mask-pattern": None, "--mask-margin": 16, "--k": 4,
                  "--lut": None, "--coarse-range-px": 12, "--frames": 3,
                  "--no-rotation": False, "--no-focus": False, "--relay-na": None,
                  "--focus-range-mm": None, "--sim-translation-px": (5.3, -3.6),
                  "--sim-rotation-mrad": 2.0, "--sim-distortion-px": 0.0,
                  "--sim-defocus-mm": 0.08, "--sim-tip-mrad": 0.0, "--sim-tilt-mrad": 0.0}


def test_align_mask_options_come_from_its_model():
    from calibration_routines.cli.align import add_subcommands as add_align
    from calibration_routines.cli.align import simulated_truth
    from calibration_routines.parameters import AlignMaskParams

    specs = {s.flag: s for s in AlignMaskParams.specs()}
    assert {f: s.default for f, s in specs.items()} == ALIGN_HISTORIC
    parser = argparse.ArgumentParser(prog="diffuserlab")
    add_align(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["align", "mask", "--simulate", "--frames", "2",
                              "--sim-translation-px", "1", "-2", "--no-focus"])
    cli = AlignMaskParams.from_namespace(args)
    gui = AlignMaskParams.from_text({"--frames": "2", "--sim-translation-px": "1, -2",
                                     "--no-focus": True, "--mask-seed": ""})
    assert cli == gui and gui.sim_translation_px == (1.0, -2.0)
    assert simulated_truth(gui).translation == simulated_truth(cli).translation
    with pytest.raises(InputError, match=r"--mask-seed: 'abc' is not a whole number"):
        AlignMaskParams.from_text({"--mask-seed": "abc"})
    with pytest.raises(InputError, match=r"--relay-na 2.0 is outside its limits"):
        AlignMaskParams.from_text({"--relay-na": "2"})
    with pytest.raises(InputError, match=r"--sim-translation-px: '1' is not 2 numbers"):
        AlignMaskParams.from_text({"--sim-translation-px": "1"})


def test_the_guis_batch_options_are_recon_runs_declarations_without_argv():
    from gui.jobs import batch_options
    from instrument.cli.recon_run import add_subcommands as add_recon_run

    parser = argparse.ArgumentParser(prog="diffuserlab")
    add_recon_run(parser.add_subparsers(dest="command"))
    cli = parser.parse_args(["recon-run", "v.zarr", "--psf", "p.npy", "--iterations", "7",
                             "--method", "fista", "--depth", "45", "--workers", "1"])
    recon, own = batch_options({
        "--psf": "p.npy", "--iterations": "7", "--method": "fista", "--depth": "45",
        "--workers": "1", "--frames": "", "--tv": ""})
    gui = {**recon.model_dump(), **own.model_dump()}
    for name, value in gui.items():  # every option the form sets, as the flag would
        if name in vars(cli) and not callable(value):
            assert value == vars(cli)[name], name
    for options, message in (({"--iterations": "many"}, r"iterations"),
                             ({"--method": "magic"}, r"magic"),
                             ({"--nope": "1"}, r"--nope")):
        with pytest.raises(InputError, match=message):
            batch_options(options)

"""Every reconstruction parameter is declared once (:class:`recon.options.ReconOptions`):
the command line's flags, the GUI's Batch and Live forms and :func:`recon.reconstruct`
default to the very objects the declaration holds, and a new parameter needs one
declaration (and its use in the solver) to reach every front end and the docs."""

from __future__ import annotations

import argparse
import inspect
import os
from pathlib import Path
from typing import Literal

import pytest

from diffuserlab.options import option
from instrument.cli import build_parser
from instrument.cli.recon_flags import COMMAND_FIELDS, add_recon_flags, flags_table
from recon.options import LiveOptions, ReconOptions, kind_options

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

ROOT = Path(__file__).resolve().parents[2]
ARGV = {
    "recon": ["recon", "--psf", "p.npy", "--raw", "r.npy"],
    "recon3d": ["recon3d", "--psf-stack", "s.zarr", "--raw", "r.npy"],
    "recon-run": ["recon-run", "RUN.zarr", "--psf", "p.npy"],
    "capture live": ["capture", "live", "--psf", "p.npy", "--simulate"],
}


@pytest.fixture(scope="module")
def forms(qapp, tmp_path_factory):
    """The GUI's Record (Batch form) and Live panels on an unconnected session."""
    os.environ["DIFFUSERLAB_GUI_SETTINGS"] = str(tmp_path_factory.mktemp("qt") / "gui.ini")
    from gui.panels.live import LivePanel
    from gui.panels.record import RecordPanel
    from gui.session import Session

    session = Session(None, simulate=True, scene="none")
    live = LivePanel(session)
    record = RecordPanel(session, live)
    yield record, live
    record.deleteLater()
    live.deleteLater()


def test_cli_gui_and_api_defaults_are_the_declared_objects(forms):
    import recon
    from gui.jobs import batch_options

    declared = ReconOptions.defaults()
    api = inspect.signature(recon.reconstruct).parameters
    gui, _ = batch_options({"--psf": "p.npy"})  # the Batch form, left empty
    for command, fields in COMMAND_FIELDS.items():
        args = build_parser().parse_args(ARGV[command])
        for name in fields:
            parsed = getattr(args, name)
            # argparse converts a text default with the declared parser (dark_arg)
            assert parsed is declared[name] or parsed == ReconOptions.spec(name).parse(
                declared[name]), (command, name)
    for name in ("method", "iterations", "tv", "l1", "bin_factor", "dark", "device"):
        assert api[name].default is declared[name], name
        assert getattr(gui, name) is declared[name], name  # an empty field: the default
    assert gui.prior == declared["prior"] == "tv-iso"
    record, live = forms
    batch = record.batch_fields
    assert batch["--method"].currentText() is declared["method"] or (
        batch["--method"].currentText() == declared["method"])
    # the prior: the declared choices and default, and what the form holds reaches recon-run
    prior = batch["--prior"]
    assert [prior.itemText(i) for i in range(prior.count())] == list(
        ReconOptions.spec("prior").choices)
    assert prior.currentText() == declared["prior"]
    assert batch_options({"--psf": "p.npy", "--prior": "dncnn"})[0].prior == "dncnn"
    assert batch["--iterations"].value() == declared["iterations"] == 200
    # a form left as built gives the declared defaults, the very objects
    for name, value in record.recon_form.values().model_dump().items():
        assert value is declared[name], name
    # the placeholder names the default and what it means on this bench ("auto: ...")
    assert batch["--dark"].placeholderText().split(":")[0] == declared["dark"]
    assert live.method.currentText() == LiveOptions.defaults()["method"]
    assert live.iterations.value() == LiveOptions.defaults()["iterations"]
    assert live.device.currentText() == declared["device"]
    assert [live.method.itemText(i) for i in range(live.method.count())] == list(
        LiveOptions.spec("method").choices)


def test_the_batch_form_refuses_what_the_flag_refuses(forms):
    from gui.jobs import batch_options
    from gui.workers import InputError

    with pytest.raises(InputError, match=r"^--iterations 0 is outside its limits"):
        batch_options({"--iterations": "0"})
    with pytest.raises(InputError, match=r"^--tv: 'x' is not a number or auto"):
        batch_options({"--tv": "x"})
    with pytest.raises(InputError, match="recon-run has no option --erase"):
        batch_options({"--erase": "0.5"})  # a flag of recon, not recon-run
    # the workers/scheduler exclusion is the declaration's (RunOptions.check_together)
    with pytest.raises(InputError, match=r"^--workers: not allowed with --scheduler"):
        batch_options({"--workers": "2", "--scheduler": "tcp://h:8786"})


class _WithNewParameter(ReconOptions):
    """ReconOptions and one new parameter, declared once."""

    halo_px: int = option(4, help="border added around the sensor before the solve",
                          unit="px", ge=0, kinds=("image",), label="halo")
    window: Literal["none", "hann"] = option("none", help="apodisation of the raw",
                                             kinds=("image", "volume"))


def test_a_new_parameter_needs_one_declaration(monkeypatch):
    import recon.options as options

    monkeypatch.setattr(options, "ReconOptions", _WithNewParameter)
    monkeypatch.setitem(COMMAND_FIELDS, "recon", (*COMMAND_FIELDS["recon"], "halo_px",
                                                   "window"))
    p = argparse.ArgumentParser()
    add_recon_flags(p, "recon")
    args = p.parse_args(["--halo-px", "7", "--window", "hann"])
    assert (args.halo_px, args.window, args.iterations) == (7, "hann", 200)
    assert "halo_px" in kind_options("image") and "window" in kind_options("volume")
    assert "halo_px" not in kind_options("grid")
    with pytest.raises(Exception, match=r"^halo_px=-1 is outside its limits: halo in px"):
        _WithNewParameter.validated({"halo_px": -1}, front="python")
    assert _WithNewParameter.from_text({"--halo-px": "3"}).halo_px == 3
    table = flags_table()
    assert "| `--halo-px` | int | px | >= 0 | 4 |" in table
    assert "| `--window` | one of none, hann |" in table


def test_the_docs_table_is_the_generated_one():
    text = (ROOT / "docs" / "cli.md").read_text()
    assert flags_table() in text, ("docs/cli.md's table is stale: paste the output of "
                                   "python -m instrument.cli.recon_flags")


def test_each_command_offers_its_declared_flags_only():
    for command, fields in COMMAND_FIELDS.items():
        args = vars(build_parser().parse_args(ARGV[command]))
        assert set(fields) <= set(args), command
    assert "erase" not in vars(build_parser().parse_args(ARGV["recon3d"]))


def test_the_declared_erase_limit_is_the_numerics_one():
    from recon.preprocess.signal import MIN_MEASURED_FRACTION

    assert ReconOptions.bounds("erase")["le"] == pytest.approx(1 - MIN_MEASURED_FRACTION)

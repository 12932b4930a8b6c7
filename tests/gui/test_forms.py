"""The GUI's reconstruction forms are generated from the declarations
(:mod:`gui.forms`): the Record panel's batch form, the Live panel's settings and the
napari Reconstruct widget show each declared field of their command with its default,
read back as the validated options object, and a new declared field appears in each."""

from __future__ import annotations

import os
from typing import Literal

import pytest

from diffuserlab.errors import InputError
from diffuserlab.options import option
from instrument.options import COMMAND_FIELDS, RunOptions
from recon.options import LiveOptions, ReconOptions

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


class _Extended(ReconOptions):
    """ReconOptions and one new parameter, declared once."""

    halo_px: int = option(4, help="border added around the sensor before the solve",
                          unit="px", ge=0, le=64, label="halo")
    window: Literal["none", "hann"] = option("none", help="apodisation of the raw",
                                             label="window")


@pytest.fixture
def settings(tmp_path):
    os.environ["DIFFUSERLAB_GUI_SETTINGS"] = str(tmp_path / "gui.ini")


@pytest.fixture
def extended(monkeypatch, settings):
    """The declaration the forms read, with two new fields in every command's list."""
    import gui.napari_plugin.widget
    import gui.panels.live
    import gui.panels.record

    for module in (gui.panels.record, gui.panels.live, gui.napari_plugin.widget):
        monkeypatch.setattr(module, "ReconOptions", _Extended)
    for command in ("recon-run", "capture live", "recon", "recon3d"):
        monkeypatch.setitem(COMMAND_FIELDS, command,
                            (*COMMAND_FIELDS[command], "halo_px", "window"))
    return _Extended


def _panels(qapp):
    from gui.panels.live import LivePanel
    from gui.panels.record import RecordPanel
    from gui.session import Session

    session = Session(None, simulate=True, scene="none")
    live = LivePanel(session)
    return RecordPanel(session, live), live


def _shows_the_new_fields(form) -> None:
    """``form`` shows the two new fields with their defaults, laid out, and reads back
    the declared defaults."""
    assert form.widgets["halo_px"].value() == 4
    assert form.labels["halo_px"].text() == "halo (px):"
    assert form.labels["halo_px"].parent() is not None  # laid out in the form's widget
    window = form.widgets["window"]
    assert [window.itemText(i) for i in range(window.count())] == ["none", "hann"]
    assert window.currentText() == "none"
    assert form.values() == _Extended.validated({})


def _close(*widgets):
    for w in widgets:  # deleted by the GUI thread's event loop (tests/gui/conftest.py)
        w.close()
        w.deleteLater()


def test_every_declared_field_has_a_short_form_label():
    from gui.forms import field_label

    for options in (ReconOptions, LiveOptions, RunOptions):
        for spec in options.specs():
            label = field_label(spec)  # KeyError: neither declared nor in gui.forms.LABELS
            assert 0 < len(label) <= 30, (options.__name__, spec.dest, label)


def test_the_builder_makes_each_kind_of_widget_and_reads_it_back(qapp, settings):
    from PySide6.QtWidgets import QCheckBox, QComboBox, QLineEdit, QSpinBox

    from gui.forms import OptionsForm

    form = OptionsForm(ReconOptions, ("method", "iterations", "tv", "dark", "seconds",
                                      "allow_mixed_ranges", "erase"))
    w = form.widgets
    assert isinstance(w["method"], QComboBox) and not w["method"].isEditable()
    assert isinstance(w["tv"], QComboBox) and w["tv"].isEditable()  # a weight or auto
    assert isinstance(w["iterations"], QSpinBox)
    assert (w["iterations"].minimum(), w["iterations"].value()) == (1, 200)
    assert isinstance(w["dark"], QLineEdit) and w["dark"].placeholderText() == "auto"
    assert w["seconds"].placeholderText() == "none"
    assert isinstance(w["allow_mixed_ranges"], QCheckBox)
    assert w["erase"].maximum() == pytest.approx(0.99)
    assert form.values() == ReconOptions.validated({})  # as built: the defaults
    w["tv"].setCurrentText("x")
    with pytest.raises(InputError, match=r"^--tv: 'x' is not a number or auto"):
        form.values()
    # the checks between fields are the declaration's (a prior with Wiener)
    form = OptionsForm(ReconOptions, ("method", "prior"))
    form.widgets["method"].setCurrentText("wiener")
    form.widgets["prior"].setCurrentText("tgv")
    with pytest.raises(InputError, match="--method wiener takes no image prior"):
        form.values()


def test_a_new_option_appears_in_the_batch_form_with_its_default(qapp, extended):
    record, live = _panels(qapp)
    try:
        form = record.recon_form
        _shows_the_new_fields(form)
        assert record.batch_fields["--halo-px"] is form.widgets["halo_px"]
        # the form's values round-trip to the options object
        chosen = extended.validated({
            "method": "fista", "iterations": 7, "tv": 0.01, "l1": "auto", "bin_factor": 2,
            "dark": ReconOptions.spec("dark").parse("12"), "device": "auto",
            "halo_px": 9, "window": "hann"})
        form.set_values(chosen)
        assert form.values() == chosen
        assert record.batch_fields["--dark"].text() == "12"
    finally:
        _close(record, live)


def test_the_batch_form_gives_recon_runs_options_and_refuses_what_it_refuses(qapp,
                                                                             settings):
    record, live = _panels(qapp)
    try:
        run = record.run_form
        run.widgets["psf"].setText("p.npy")
        run.widgets["workers"].setText("2")
        run.widgets["depth_mm"].setEditText("45")
        recon = record.recon_form.values()
        own = run.values()
        assert (own.psf, own.depth_mm, own.workers, own.scheduler) == ("p.npy", 45.0, 2, None)
        assert recon == ReconOptions.validated({})
        record.batch_fields["--iterations"].setValue(0)  # clamped by the spin box's limits
        assert record.batch_fields["--iterations"].value() == 1
        record.batch_fields["--tv"].setCurrentText("-1")
        record.run_path.setText(__file__)  # an existing path: the form is read
        assert record.start_batch() is None
        # refused on the GUI thread, the field named by its label
        assert record.batch_error.text().startswith(
            "'TV weight' -1.0 is outside its limits"), record.batch_error.text()
        record.batch_fields["--tv"].setCurrentText("auto")
        record.batch_fields["--workers"].setText("x")
        assert record.start_batch() is None
        assert record.batch_error.text() == "'workers': 'x' is not a whole number"
    finally:
        _close(record, live)


def test_a_new_option_appears_in_the_live_settings_with_its_default(qapp, extended):
    record, live = _panels(qapp)
    try:
        form = live.recon_form
        _shows_the_new_fields(form)
        chosen = extended.validated({"dark": ReconOptions.spec("dark").parse("none"),
                                     "device": "auto", "bin_factor": 2, "halo_px": 0,
                                     "window": "hann"})
        form.set_values(chosen)
        assert form.values() == chosen
        # the live method's own declaration: its choices, limits and defaults
        assert live.iterations.maximum() == LiveOptions.bounds("iterations")["le"]
        assert live.live_form.values() == LiveOptions.validated({})
        own = LiveOptions.validated({"method": "admm", "iterations": 12})
        live.live_form.set_values(own)
        assert live.live_form.values() == own
        assert (live.method.currentText(), live.iterations.value()) == ("admm", 12)
    finally:
        _close(record, live)


def test_the_live_reconstruction_takes_the_forms_options(qapp, settings, tmp_path,
                                                         monkeypatch):
    """What the Live form holds reaches the reconstructor: dark level, binning, device,
    method and iterations (a bad value is refused in the panel, nothing built)."""
    import numpy as np

    import gui.jobs
    from gui.jobs import build_live

    monkeypatch.setattr(gui.jobs, "LIVE_IN_PROCESS", False)
    session = type("S", (), {})()
    cam = type("C", (), {"image_shape": (32, 40), "dark_offset_dn": None})()
    session.service = type("Svc", (), {"camera_format": staticmethod(lambda: cam)})()
    psf = np.zeros((32, 40), np.float32)
    psf[14:18, 18:22] = 100.0
    np.save(tmp_path / "psf.npy", psf)
    options = ReconOptions.validated({"dark": ReconOptions.spec("dark").parse("3"),
                                      "bin_factor": 2})
    live, depth = build_live(session, str(tmp_path / "psf.npy"), options=options,
                             live=LiveOptions.validated({"method": "admm",
                                                         "iterations": 9}))
    recon = live.reconstructor
    assert depth is None and recon.bin_factor == 2 and float(recon._dark) == 3.0
    assert live.stats()["method"] == "admm" and live.stats()["iterations"] == 9


def test_a_new_option_appears_in_the_napari_widget_with_its_default(qapp, extended):
    from gui.napari_plugin.widget import ReconstructWidget

    viewer = type("Viewer", (), {"layers": []})()  # napari's: its layers, no window
    widget = ReconstructWidget(viewer)
    try:
        _shows_the_new_fields(widget.form)
        chosen = extended.validated({"method": "fista", "iterations": 3, "tv": 0.5,
                                     "prior": "tv", "l1": 0.0, "bin_factor": 4,
                                     "dark": ReconOptions.spec("dark").parse("7.5"),
                                     "allow_mixed_ranges": True, "device": "cuda",
                                     "halo_px": 64, "window": "hann"})
        widget.form.set_values(chosen)
        assert widget.form.values() == chosen
    finally:
        _close(widget)


def test_the_napari_widget_takes_the_command_lines_options_and_defaults(qapp, settings):
    """The widget's options are those ``recon`` and ``recon3d`` share, the dark level
    included, each with the command line's default (the widget restated 100
    iterations against the command line's 200)."""
    from gui.napari_plugin.widget import ReconstructWidget, widget_fields
    from instrument.cli import build_parser

    cli = build_parser().parse_args(["recon3d", "--psf-stack", "s.zarr", "--raw", "r.npy"])
    assert "dark" in widget_fields() and "iterations" in widget_fields()
    assert set(widget_fields()) == set(COMMAND_FIELDS["recon"]) & set(COMMAND_FIELDS["recon3d"])
    widget = ReconstructWidget(type("Viewer", (), {"layers": []})())
    try:
        assert list(widget.form.widgets) == list(widget_fields())
        assert widget.form.widgets["iterations"].value() == cli.iterations == 200
        values = widget.form.values()
        for name in widget_fields():  # as built: the command line's defaults
            assert getattr(values, name) == getattr(cli, name), name
    finally:
        _close(widget)

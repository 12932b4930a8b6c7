"""The Record panel's batch form with a scene-calibrated PSF run shows what will run:
the run's recipe in the fields and a line, and a visible line when an edit declines it
(issue 67)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from gui.jobs import batch_options
from recon.early_stop import FILE, EarlyStop

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


@pytest.fixture
def panel(record_panel):
    return record_panel


@pytest.fixture
def calibration(tmp_path):
    """A directory holding a scene calibration's recipe (90 iterations, threshold 0.05,
    denoising 0.1), as ``calibrate psf-from-scenes`` writes it."""
    run = tmp_path / "cal.zarr"
    run.mkdir()
    fit = EarlyStop(90, (50, 90, 150), np.zeros((2, 3, 2, 4)), "0" * 64,
                    ("p0", "p1", "p2", "p3"), 0.05, 0.1, (0.0, 0.05), (0.0, 0.1))
    (run / FILE).write_text(json.dumps(fit.to_dict()))
    return run


def _shows(record) -> tuple:
    f = record.batch_fields
    return (f["--method"].currentText(), f["--iterations"].value(), f["--tv"].currentText(),
            f["--prior"].currentText(), f["--early-stop"].placeholderText())


def test_the_batch_form_shows_the_recipe_and_says_when_an_edit_declines_it(panel,
                                                                          calibration):
    f = panel.batch_fields
    assert _shows(panel) == ("auto", 200, "auto", "tv-iso", "none")
    f["--psf"].setText(str(calibration))
    f["--psf"].editingFinished.emit()
    method, iterations, tv, prior, early = _shows(panel)
    assert (method, iterations, tv, prior) == ("fista", 90, "0", "")
    assert "recipe" in early and not f["--prior"].isEnabled()
    line = panel.recipe_line.text()
    assert not panel.recipe_line.isHidden()
    assert "0.05" in line and "90 iterations" in line and "0.1" in line, line
    assert "field response" not in line  # this recipe has none
    recon, _ = batch_options(panel.batch_texts())
    assert recon.early_stop == str(calibration / FILE)
    # an edit declines the recipe, visibly; the form's values then run as shown
    f["--iterations"].setValue(40)
    assert "declined" in panel.recipe_line.text() and "iterations" in panel.recipe_line.text()
    assert not panel.recipe_button.isHidden() and f["--prior"].isEnabled()
    recon, _ = batch_options(panel.batch_texts())
    assert (recon.early_stop, recon.method, recon.iterations) == ("off", "fista", 40)
    # the recipe taken again, then another PSF: the fields return to what they held
    panel.use_recipe()
    assert _shows(panel)[:4] == ("fista", 90, "0", "")
    f["--psf"].setText(str(calibration.parent / "plain.npy"))
    f["--psf"].editingFinished.emit()
    assert _shows(panel) == ("auto", 200, "auto", "tv-iso", "none")
    assert panel.recipe_line.isHidden()


def test_a_form_that_already_departs_says_the_recipe_is_declined(panel, calibration):
    f = panel.batch_fields
    f["--method"].setCurrentText("admm")
    f["--psf"].setText(str(calibration))
    f["--psf"].editingFinished.emit()
    assert _shows(panel)[0] == "admm"
    assert "declined" in panel.recipe_line.text() and "solver" in panel.recipe_line.text()
    assert batch_options(panel.batch_texts())[0].early_stop == "off"


def test_the_line_names_the_recipes_field_response(panel, tmp_path):
    """A recipe with a field response says so: its image is dark where the calibration
    scenes were."""
    run = tmp_path / "field.zarr"
    run.mkdir()
    fit = EarlyStop(90, (90,), np.zeros((1, 1, 1, 3)), "0" * 64, ("p0", "p1", "p2"),
                    field_response=np.ones((3, 4)), field_gain_db=0.3)
    (run / FILE).write_text(json.dumps(fit.to_dict()))
    panel.batch_fields["--psf"].setText(str(run))
    panel.batch_fields["--psf"].editingFinished.emit()
    line = panel.recipe_line.text()
    assert "field response" in line and "dark where they were dark" in line, line

"""``diffuserlab --help`` names every calibration routine on calibrate's line (it left
out psf-blind and psf-from-scenes; issue 67)."""

from __future__ import annotations

import pytest

from calibration_routines.cli.calibrate import PARAMETERS
from instrument.cli import main


def test_the_top_help_names_every_calibration_routine(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    lines = out[out.index("    calibrate "):].splitlines()
    entry = [lines[0]]
    for more in lines[1:]:  # the entry's wrapped lines, up to the next command's
        if not more.startswith(" " * 6):
            break
        entry.append(more)
    line = " ".join(" ".join(entry).split()).replace("- ", "-")  # wrapped at a hyphen
    assert {"psf-blind", "psf-from-scenes"} <= set(PARAMETERS)
    for routine in PARAMETERS:
        assert routine in line, (routine, line)

"""Write docs/calibration-options.md from the calibration routines' parameter models.

``python -m calibration_routines.parameters_doc`` rewrites the page; ``--check`` exits 1
when the page differs from the models (``tests/calibration_routines/test_parameters.py``
checks it).
"""

from __future__ import annotations

import sys
from pathlib import Path

from calibration_routines.parameters import PARAMETERS, AlignMaskParams
from instrument.writer.docpage import page_main

__all__ = ["DEFAULT_PAGE", "main", "page"]

#: The page in a source checkout.
DEFAULT_PAGE = Path(__file__).resolve().parents[1] / "docs" / "calibration-options.md"


def page() -> str:
    """The page's text: one options table per routine, generated from its model."""
    lines = ["# Calibration options", "",
             "Generated from the parameter models in `calibration_routines/parameters.py` "
             "by `python -m calibration_routines.parameters_doc`; do not edit by hand. The "
             "same models generate the options of `diffuserlab calibrate ROUTINE` and the "
             "forms of the GUI's calibration panel; a value outside its limits is refused "
             "before the bench opens. Every routine also takes the bench file, "
             "`--simulate`, `--seed`, `--out`, `--note`, `--overwrite` and "
             "`--reconnect-timeout` (see [Calibration runs](calibration.md)).", ""]
    for name, model in PARAMETERS.items():
        lines += [f"## `calibrate {name}`", "", model.summary[0].upper() + model.summary[1:]
                  + ".", "", model.markdown(), ""]
        if name == "psf-grid":
            lines += ["`--falloff-run RUN.zarr` (an angular-response run) gives the fall-off "
                      "sigma instead of `--falloff-sigma-deg`.", ""]
        if name == "psf-from-scenes":
            lines += ["`--scenes PATH... --measurements PATH...` (files or directories of "
                      ".npy, .tif, .png, matched by name) estimate the PSF from those pairs "
                      "instead, with no bench.", ""]
        if name == "slm-lut":
            lines += ["`--apply` loads the new LUT onto the SLM at the end and compares a "
                      "blazed grating's first-order efficiency with the previous LUT.", ""]
    lines += ["## `align mask`", "", "The SLM-mask alignment with spot feedback (see "
              "[Holography](holography.md)); it also takes the bench file, `--simulate`, "
              "`--seed` and `--out`.", "", AlignMaskParams.markdown(), ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Write (or with ``--check`` compare) the page; returns the exit status."""
    return page_main("calibration_routines.parameters_doc", __doc__.splitlines()[0],
                     DEFAULT_PAGE, page, argv)


if __name__ == "__main__":
    sys.exit(main())

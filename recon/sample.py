"""The real DiffuserCam tutorial sample: a PSF and a hand measurement (TIFF).

Located next to the repository, or at ``$DIFFUSERLAB_DATA``; used by the demo, the
benchmarks and the tests (nothing is downloaded).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from .errors import ReconInputError
from .preprocess import Prepared, prepare_pair

#: Environment variable overriding the directory of the tutorial sample.
DATA_ENV = "DIFFUSERLAB_DATA"
PSF_FILE = "psf_sample.tif"
RAW_FILE = "rawdata_hand_sample.tif"

def data_dir() -> Path:
    """Directory holding the DiffuserCam tutorial sample.

    ``$DIFFUSERLAB_DATA`` if set, else ``shared/data/diffusercam-tutorial`` next to
    the repository (``Path(__file__).resolve().parents[1].parent``).

    Raises
    ------
    ReconInputError
        If the directory or either TIFF is missing.
    """
    env = os.environ.get(DATA_ENV)
    base = (Path(env) if env else
            Path(__file__).resolve().parents[1].parent / "shared/data/diffusercam-tutorial")
    missing = [f for f in (PSF_FILE, RAW_FILE) if not (base / f).is_file()]
    if missing:
        raise ReconInputError(
            f"DiffuserCam tutorial sample not found: {', '.join(missing)} missing in {base}; "
            f"set {DATA_ENV} to the directory holding {PSF_FILE} and {RAW_FILE}"
        )
    return base


@functools.lru_cache(maxsize=1)
def _raw_pair() -> tuple[np.ndarray, np.ndarray]:
    from .io import load_image

    base = data_dir()
    psf, raw = load_image(base / PSF_FILE), load_image(base / RAW_FILE)
    psf.setflags(write=False)
    raw.setflags(write=False)
    return psf, raw


@functools.lru_cache(maxsize=4)
def load_sample(bin_factor: int) -> Prepared:
    """The real PSF and hand measurement preprocessed by
    :func:`recon.preprocess.prepare_pair` (dark from the PSF corner, box binning).

    Parameters
    ----------
    bin_factor : int
        4 gives 300 x 400 (padded 600 x 800), 2 gives 600 x 800.

    Returns
    -------
    Prepared
        Cached and shared by every caller, so its ``psf`` and ``raw`` are read-only
        (a caller that changed them in place changed every later caller's sample);
        copy them to modify.
    """
    psf, raw = _raw_pair()
    prepared = prepare_pair(psf, raw, bin_factor=bin_factor)
    prepared.psf.setflags(write=False)
    prepared.raw.setflags(write=False)
    return prepared

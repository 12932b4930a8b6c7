"""The external 3D DiffuserCam sample: a calibrated PSF stack and one raw image.

The Waller Lab's 3D DiffuserCam example as LenslessPiCam distributes it (folder
``data/diffuser3D``; Antipa et al., Optica 2018, downsampled): 44 PSFs of 270 x 320
(``psf/psf00.tiff`` the nearest plane ... ``psf43.tiff`` the farthest, normalised to a
maximum of 1, background not subtracted) and ``image.tiff`` (uint16). It is not part
of the repository: it is found next to it (``shared/data/diffuser3d-lenslesspicam``
beside the repository directory) or at ``$DIFFUSERLAB_DATA3D``. There is no ground
truth; the depths are not published (the planes' order is what matters).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ReconInputError
from ..preprocess import box_bin

__all__ = ["DATA3D_ENV", "VolumeSample", "load_volume_sample", "volume_data_dir"]

#: Environment variable overriding the directory of the 3D sample.
DATA3D_ENV = "DIFFUSERLAB_DATA3D"
#: Planes of the sample and the corner its dark level is taken from (rows, cols), as
#: LenslessPiCam does.
N_PLANES = 44
DARK_CORNER = (slice(5, 25), slice(5, 25))


def volume_data_dir() -> Path:
    """Directory holding the 3D sample (``$DIFFUSERLAB_DATA3D``, else beside the repository).

    Raises
    ------
    ReconInputError
        The directory or one of its files is missing (names the first and the variable).
    """
    env = os.environ.get(DATA3D_ENV)
    base = (Path(env) if env else Path(__file__).resolve().parents[2].parent
            / "shared/data/diffuser3d-lenslesspicam")
    files = [base / "image.tiff"] + [base / f"psf/psf{k:02d}.tiff" for k in range(N_PLANES)]
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise ReconInputError(f"3D DiffuserCam sample not found: {missing[0]} missing (and "
                              f"{len(missing) - 1} more); set {DATA3D_ENV} to the directory "
                              "holding image.tiff and psf/psf00.tiff ... psf43.tiff")
    return base


@dataclass(frozen=True)
class VolumeSample:
    """The 3D sample, dark-subtracted and binned.

    Attributes
    ----------
    stack : ndarray, float32, (44, rows, cols)
        PSFs, nearest plane first, each minus its own dark-corner mean (not clipped).
    raw : ndarray, float32, (rows, cols)
        The raw image minus its dark-corner mean, counts.
    depths : ndarray, float64, (44,)
        Plane order as depths 1 ... 44 (the true depths are not published).
    bin_factor : int
    """

    stack: np.ndarray
    raw: np.ndarray
    depths: np.ndarray
    bin_factor: int


def load_volume_sample(bin_factor: int = 1) -> VolumeSample:
    """Load the 3D sample, subtract each image's dark level and bin laterally.

    Parameters
    ----------
    bin_factor : int
        Box binning (:func:`recon.preprocess.box_bin`; 270 x 320 at 1, 135 x 160 at 2,
        67 x 80 at 4: the images are first cropped to a multiple of the factor, bottom
        rows and right columns).

    Returns
    -------
    VolumeSample

    Raises
    ------
    ReconInputError
        The sample is missing, or a bin factor that is not an integer >= 1.
    """
    from ..io import load_image

    if isinstance(bin_factor, bool) or not isinstance(bin_factor, int) or bin_factor < 1:
        raise ReconInputError(f"bin_factor must be an integer >= 1, got {bin_factor!r}")
    base = volume_data_dir()
    raw = load_image(base / "image.tiff").astype(np.float32)
    crop = tuple(slice(0, n - n % bin_factor) for n in raw.shape)
    planes = []
    for k in range(N_PLANES):
        p = load_image(base / f"psf/psf{k:02d}.tiff").astype(np.float32)
        planes.append(box_bin((p - p[DARK_CORNER].mean())[crop], bin_factor))
    raw = box_bin((raw - raw[DARK_CORNER].mean())[crop], bin_factor)
    return VolumeSample(np.asarray(planes, np.float32), raw,
                        np.arange(1.0, N_PLANES + 1.0), int(bin_factor))

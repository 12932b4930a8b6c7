"""Preprocessing of a PSF and a raw measurement before reconstruction.

Plain functions on arrays (scikit-image style) with explicit float32 output.
They follow the preprocessing of the DiffuserCam tutorial (Waller Lab) and of
Sec. 3.3 of N. Antipa/G. Kuo et al. as summarised in G. Kuo, *Exploiting
Randomness in Computational Cameras and Displays* (PhD dissertation, UC
Berkeley, 2020): estimate the dark level from a dark corner of the PSF
(mean of ``psf[5:15, 5:15]``), subtract it from both the PSF and the
measurement, and downsample both by box-averaging. Normalisation is left to
the solver layer (:func:`normalize` is provided for it).

Submodules: :mod:`.validation` (input checks, saturation), :mod:`.dark` (dark
level), :mod:`.signal` (the raw checked after its dark level, the PSF/raw pair's bit
depths, the erasure's measured pixels: used by every method, 2D and 3D),
:mod:`.binning` (box binning) and :mod:`.pair` (:func:`prepare_pair`,
:func:`normalize`); every public name is importable from ``recon.preprocess``.

Every refusal raises :class:`recon.errors.ReconInputError` whose message says
what is wrong and how to fix it.
"""


from .binning import box_bin
from .dark import DEFAULT_DARK_REGION, dark_argument, dark_level, subtract_dark
from .pair import Prepared, check_psf_signal, normalize, prepare_pair
from .signal import (
    RawBelowDarkError,
    RawSignalError,
    check_measured_fraction,
    check_pair_ranges,
    check_raw_signal,
    raw_levels,
)
from .validation import (
    SaturationWarning,
    saturation_fraction,
    validate_measurement,
    validate_psf,
)

__all__ = [
    "DEFAULT_DARK_REGION",
    "dark_argument",
    "Prepared",
    "RawBelowDarkError",
    "RawSignalError",
    "SaturationWarning",
    "box_bin",
    "check_measured_fraction",
    "check_psf_signal",
    "check_pair_ranges",
    "check_raw_signal",
    "dark_level",
    "normalize",
    "prepare_pair",
    "raw_levels",
    "saturation_fraction",
    "subtract_dark",
    "validate_measurement",
    "validate_psf",
]

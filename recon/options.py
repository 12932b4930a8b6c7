"""The reconstruction layer's option names and argument types, for command-line parsers.

This module imports only the standard library, so that ``diffuserlab --help`` (and
every command that does not reconstruct) builds its parser without loading numpy,
numba or scipy. The modules that implement the choices re-export these names
(:data:`recon.spatial.api.GRID_METHODS`, :data:`recon.spatial.choice.MODELS`,
:func:`recon.auto.weight_arg`, ...); tests check that the tables that hold the
solvers themselves (:data:`recon.solvers.SOLVERS`, :data:`recon.volume.api.SOLVERS`)
offer exactly these names.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["AUTO", "BACKGROUNDS", "BENCHMARKS", "DEVICES", "DarkOption", "GRID_L1", "GRID_METHODS",
           "HOLOGRAM_METHODS", "L1_DEFAULT", "METHODS", "METHOD_SUMMARIES", "MODELS", "NONE",
           "Unset", "VOLUME_METHODS", "dark_arg", "l1_given", "weight_arg"]

#: ``--device`` choices (:func:`recon.backend.resolve_device`): the CPU (NumPy, numba),
#: a CUDA GPU (CuPy or PyTorch), or the GPU when one is usable.
DEVICES = ("cpu", "cuda", "auto")

#: The value that asks for an automatic choice (``method``, ``tv``, ``l1``, ``dark``).
AUTO = "auto"
#: ``--dark none``: the inputs are already dark-subtracted; nothing is subtracted.
NONE = "none"

#: One line per 2D solver, in the order of :data:`recon.solvers.SOLVERS`.
METHOD_SUMMARIES = {
    "wiener": "Wiener / Tikhonov preview, one FFT pair",
    "gd": "gradient descent with Nesterov momentum",
    "fista": "FISTA with TV and non-negativity (Alg. 1)",
    "admm": "ADMM with crop, TV and non-negativity splits (Eq. 4.5 in 2D)",
}
#: The 2D methods (keys of :data:`recon.solvers.SOLVERS`).
METHODS = tuple(METHOD_SUMMARIES)
#: The 3D methods (keys of :data:`recon.volume.api.SOLVERS`).
VOLUME_METHODS = ("admm", "fista")
#: Solvers of a spatially varying model: FISTA on Eq. 6.2 (l1, optional background) or
#: TV ADMM.
GRID_METHODS = ("fista", "admm")
#: Default l1 weight of FISTA on a PSF grid (Eq. 6.2's sparse object), scaled problem.
GRID_L1 = 1e-3
#: Forward models of a PSF grid (``--model``).
MODELS = ("auto", "convolution", "local", "pca")
#: ``--background`` choices of a PSF-grid reconstruction.
BACKGROUNDS = ("estimate", "none")
#: Methods of Table 7.1 in order (:mod:`recon.cgh.evaluation`).
HOLOGRAM_METHODS = ("one-step", "l2", "frequency", "spatial")
#: The benchmarks of ``diffuserlab benchmark recon``, in the order they run
#: (:mod:`recon.benchmarks.run`).
BENCHMARKS = ("speed", "accuracy", "stability", "erasure", "volume_speed",
              "volume_accuracy", "spatial_speed", "spatial_accuracy", "spatial_far",
              "blind_calibration", "auto", "failure_maps", "failure_map_3d", "volume_auto",
              "volume_external")


class Unset(float):
    """A flag's numeric default that also says the flag was not given: ``--l1`` is 0 for
    one PSF, while FISTA on a PSF grid takes its own default (:data:`GRID_L1`, Eq. 6.2).
    """

    __slots__ = ()


#: ``--l1``'s default: 0, unless the model has its own (:func:`l1_given`).
L1_DEFAULT = Unset(0.0)


def l1_given(value):
    """``--l1`` as given, or None when it was not (the model's own default then).

    Returns
    -------
    float, "auto" or None
    """
    return None if isinstance(value, Unset) else value


def weight_arg(text: str):
    """argparse type of ``--tv`` / ``--l1``: ``"auto"`` or a float.

    Raises
    ------
    ValueError
        Neither (argparse turns it into a usage error naming the option).
    """
    if str(text).strip().lower() == AUTO:
        return AUTO
    return float(text)


class DarkOption(str):
    """The parsed ``--dark`` value: ``"auto"``, ``"none"``, a level in DN (``.level``)
    or the path of a dark run or dark image (``.path``).

    A ``str`` (the text as given, for messages); exactly one of :attr:`auto`,
    :attr:`none`, :attr:`level` (float DN, finite and >= 0) and :attr:`path` is set.
    """

    __slots__ = ()

    @property
    def auto(self) -> bool:
        """``--dark auto``: the level is estimated (how depends on the command)."""
        return self.strip().lower() == AUTO

    @property
    def none(self) -> bool:
        """``--dark none``: nothing is subtracted (inputs already dark-subtracted)."""
        return self.strip().lower() == NONE

    @property
    def level(self) -> float | None:
        """The level in DN, or None when the value is not a number."""
        try:
            return float(self)
        except ValueError:
            return None

    @property
    def path(self) -> str | None:
        """The dark run (RUN.zarr) or dark image (TIFF, PNG, .npy), or None."""
        return None if (self.auto or self.none or self.level is not None) else str(self)


def dark_arg(text: str) -> DarkOption:
    """argparse type of ``--dark``: ``auto``, ``none``, a level in DN (finite, >= 0) or
    the path of a ``calibrate dark`` run or a dark image (checked when it is read).

    Raises
    ------
    argparse.ArgumentTypeError
        A negative, non-finite or empty value (argparse prints it as a usage error
        naming ``--dark``).
    """
    value = DarkOption(str(text).strip())
    if not value:
        raise argparse.ArgumentTypeError("empty: give auto, none, a level in DN or a dark run")
    level = value.level
    if level is not None and not (math.isfinite(level) and level >= 0):
        raise argparse.ArgumentTypeError(f"{text}: a level is a finite number of DN >= 0")
    return value

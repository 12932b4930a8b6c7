"""The reconstruction layer's parameters, declared once, and their option names.

:class:`ReconOptions` declares every parameter of :func:`recon.reconstruct` (name,
type, unit, default, limits, help, which model kinds and methods use it);
:class:`LiveOptions` those of the live reconstructor. The flags of ``recon``,
``recon3d``, ``recon-run`` and ``capture live``, the GUI's Live and Batch forms, the
keywords :func:`recon.reconstruct` accepts per model kind and the table of
docs/cli.md are generated from them (:mod:`diffuserlab.options` is the machinery).

This module imports only the standard library (and layer 0), so that ``diffuserlab --help`` (and
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
from typing import Literal

from diffuserlab.errors import InputError
from diffuserlab.options import Options, option

__all__ = ["AUTO", "BACKGROUNDS", "BENCHMARKS", "DEVICES", "DarkOption", "GRID_L1", "GRID_METHODS",
           "HOLOGRAM_METHODS", "KINDS", "L1_DEFAULT", "LiveOptions", "METHODS",
           "METHOD_SUMMARIES", "MODELS", "NONE", "ReconOptions", "Unset", "VOLUME_METHODS",
           "dark_arg", "kind_options", "l1_given", "weight_arg"]

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
#: Methods of Table 7.1 in order (``recon.cgh.evaluation``).
HOLOGRAM_METHODS = ("one-step", "l2", "frequency", "spatial")
#: The benchmarks of ``diffuserlab benchmark recon``, in the order they run
#: (``instrument.benchmarks.run``): this machine's speed against its FFT floor, 2D and 3D.
#: The accuracy and method studies run from a checkout (``python -m benchmarks``).
BENCHMARKS = ("speed", "volume_speed")


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


#: The model kinds of :func:`recon.reconstruct` (:data:`recon.result.KINDS` is this).
KINDS = ("image", "volume", "grid")

_WEIGHT = "in the scaled problem (unit-sum PSF, raw divided by its maximum), or auto"


class ReconOptions(Options):
    """Every parameter of a reconstruction, declared once.

    A field is one parameter: its Python keyword (:func:`recon.reconstruct`), its flag
    (``--`` + the name, or ``flag``), type, unit, default, limits, help and the model
    kinds (``"image"``: one PSF, ``"volume"``: a PSF stack, ``"grid"``: a PSF grid) and
    methods that use it (empty: every one). A new parameter is one field here and one
    use in the solver: the commands' flags (:meth:`add_arguments`), the GUI's forms
    (:meth:`specs`), :func:`recon.reconstruct`'s keyword check (:func:`kind_options`)
    and docs/cli.md's table (:meth:`markdown`) follow.
    """

    command = "reconstruction"

    method: Literal["auto", "wiener", "gd", "fista", "admm"] = option(
        "auto", help="solver: auto (chosen from the data: one PSF ADMM, or Wiener for a "
        "short --seconds; a stack 3D ADMM; a grid FISTA, Eq. 6.2), or one of wiener, gd, "
        "fista, admm (2D); admm, fista (stack, grid)", label="solver")
    iterations: int = option(
        200, help="maximum iterations: the solve stops earlier when the fit changes by less "
        "than the noise explains (an automatic weight's path, each weight run until its "
        "held-out error settles, takes at most 3.5x as many; with method auto, the channels "
        "of an RGB image then solve at most half as many at its one weight)", ge=1,
        methods=("gd", "fista", "admm"), label="maximum iterations")
    tv: float | Literal["auto"] | None = option(
        AUTO, help=f"TV weight {_WEIGHT} (hold-out cross-validation along a warm-started "
        "ADMM path); 0 disables; FISTA on a grid has none", unit="unitless",
        parse=weight_arg, metavar="TV|auto", ge=0, allow_inf_nan=False, label="TV weight")
    l1: float | Literal["auto"] | None = option(
        L1_DEFAULT, help=f"l1 weight (sparse scenes) {_WEIGHT}; 0, and with a PSF grid and "
        f"FISTA {GRID_L1:g} (Eq. 6.2)", unit="unitless", parse=weight_arg, metavar="L1|auto",
        ge=0, allow_inf_nan=False, label="l1 weight")
    prior: Literal["tv", "tv-iso", "tgv", "wavelet", "dncnn", "auto"] = option(
        "tv-iso", help="image prior of ADMM, weighted by --tv: tv-iso (isotropic TV, "
        "the default: no block tiling), tv (anisotropic TV: favours edges along the pixel "
        "axes, block mosaics on real measurements), tgv (second-order total generalised "
        "variation), wavelet (l1 of symlet-4 wavelet details, cycle-spun), dncnn "
        "(plug-and-play: the shipped DnCNN denoiser, --tv its noise level relative to the "
        "image's scale; slower on a CPU), or auto (the weight paths of tv, wavelet and "
        "dncnn, then the simplest that predicts held-out pixels within one standard error "
        "of the best; 2D only); FISTA and GD run their own (anisotropic) TV under the "
        "default; a volume takes 3D TV (tv, or tv-iso), or another prior (tgv, wavelet, "
        "dncnn on each plane) with a fixed "
        "--tv", kinds=("image", "volume"),
        methods=("auto", "admm"), label="prior")
    bin_factor: int = option(
        1, help="box binning of PSF and raw, pixels per side (4: 1200x1600 -> 300x400)",
        flag="--bin", ge=1, label="binning factor")
    dark: str = option(
        AUTO, help="dark level: auto (a PSF as measured: its dark corner psf[5:15, 5:15], "
        "for a stack the median of its planes' corners, subtracted from PSF and raw; a "
        "calibration run's dark-subtracted PSF: the level recorded with the frames, a "
        "simulated camera's offset, else refused for a PSF or stack, nothing for a grid "
        "whose background fits the offset), none (the inputs are dark-subtracted), a level "
        "in DN, or a `calibrate dark` run or dark image subtracted pixel by pixel (a grid "
        "takes a level)",
        parse=dark_arg, metavar="auto|none|DN|DARK_RUN", label="dark level")
    device: Literal["cpu", "cuda", "auto"] = option(
        "cpu", help="where the solver runs: cpu (NumPy and numba), cuda (a CUDA GPU through "
        "CuPy or PyTorch: pip install 'diffuserlab[gpu]'; refused with a message when none "
        "is usable) or auto (the GPU when one is usable, else the CPU)", label="device")
    allow_mixed_ranges: bool = option(
        False, help="accept a PSF and a raw of different bit depths or value ranges (e.g. a "
        "raw summed from several frames); refused by default because the PSF's dark level "
        "would not fit the raw",
        kinds=("image", "volume"))
    seconds: float | None = option(
        None, help="time budget of the solve for method auto (Wiener if too short)",
        unit="s", gt=0, kinds=("image",), default_text="none", label="time budget")
    early_stop: str | None = option(
        None, help="a scene calibration's recipe: a `calibrate psf-from-scenes` run (or its "
        "early_stop.json); thresholds the PSF, solves by non-negative FISTA without a prior "
        "for the iteration count and denoises with the TV weight fitted on the calibration "
        "pairs (recon.analysis.early_stop), in place of --method, --iterations, --tv and "
        "--l1; refused with another PSF than the run's. The default with such a run's PSF "
        "when none of those is given; 'off' declines it",
        kinds=("image",), default_text="none", metavar="RUN|JSON",
        label="early-stop calibration")
    erase: float = option(
        0.0, help="fraction of raw pixels erased at random (compressed sensing; at least "
        "1 % must stay measured, recon.preprocess.signal.MIN_MEASURED_FRACTION)", ge=0,
        le=0.99,
        kinds=("image",), label="erased fraction")
    seed: int = option(0, help="seed of the erasure mask", ge=0, kinds=("image",),
                       label="erasure seed")
    full_scale: float | None = option(
        None, help="saturation level if below the dtype maximum (65520: 12-bit in uint16)",
        unit="DN", gt=0, kinds=("image",), default_text="the dtype maximum",
        label="saturation level")
    empty_planes: Literal["keep", "drop"] = option(
        "keep", help="with an automatic weight: keep every plane, or set those that show "
        "no signal in the held-out pixels to zero (reported; in memory only: a streamed "
        "solve keeps every plane and says so)",
        kinds=("volume",), label="empty planes")
    model: Literal["auto", "convolution", "local", "pca"] = option(
        "auto", help="forward model of a grid: auto (the cheapest whose predicted model "
        "error is within 0.1: convolution, PCA with the smallest k, local), convolution "
        "(central PSF), local (every grid PSF, Eq. 5.3-5.5) or pca (Eq. 5.6-5.7)",
        kinds=("grid",), label="grid model")
    k: int | None = option(
        None, help="principal PSFs of model pca", flag="--pca-k", ge=1, kinds=("grid",),
        default_text="99 % explained energy", label="PCA components")
    background: Literal["estimate", "none"] = option(
        "estimate", help="estimate a smooth background jointly (Eq. 6.2, lowest 5x5 DCT) or "
        "none", kinds=("grid",), methods=("fista",), label="background")
    two_part: bool = option(
        False, help="a far scene (Eq. 5.1): model each grid PSF over its brightness and "
        "divide the image by the brightness map measured from the grid",
        kinds=("grid",), label="two-part model")

    @classmethod
    def check_together(cls, values, *, front: str = "cli") -> None:
        """A prior other than TV with a method that takes none (Wiener, GD, FISTA: the
        priors run in ADMM, the ``prior`` declaration's ``methods``) is refused, for the
        command line, the GUI's forms and :func:`recon.reconstruct` alike; the prior
        would be ignored or fail only after the data are read. The declared default
        (isotropic TV) is ADMM's: under it the others keep their own TV (FISTA's and
        GD's anisotropic, Wiener none), as they do with ``tv`` named.

        Raises
        ------
        diffuserlab.errors.InputError
            The prior and the method named, with the methods that take it.
        """
        spec, method_spec = cls.spec("prior"), cls.spec("method")
        prior = values.get("prior", spec.default)
        prior = prior if isinstance(prior, str) else getattr(prior, "name", spec.default)
        method = values.get("method", method_spec.default)
        # the declared default (isotropic TV, ADMM's) and TV itself: the other methods'
        # own TV (FISTA, GD) or none (Wiener), as recon.auto.solve_channel runs them
        if prior in (spec.default, "tv") or not isinstance(method, str) \
                or method in spec.methods:
            return

        def given(s, value) -> str:
            return f"{s.name(front)}{value!r}" if front == "python" else f"{s.flag} {value}"

        takers = " or ".join(given(method_spec, m) for m in reversed(spec.methods))
        raise InputError(f"{given(spec, prior)}: {given(method_spec, method)} takes no image "
                         f"prior (the priors run in ADMM); use {takers}, or "
                         f"{given(spec, 'tv')} with this method")

    def keywords(self, kind: str) -> dict:
        """The keywords of :func:`recon.reconstruct` for a model of ``kind`` (``"image"``,
        ``"volume"``, ``"grid"``): the shared ones and the kind's own, as validated."""
        own = {s.dest for s in self.specs() if not s.kinds or kind in s.kinds}
        return {k: v for k, v in self.model_dump().items() if k in own}


#: Keywords of :func:`recon.reconstruct` that are no flag: its own objects (a mask, a
#: prepared model, a colour pattern), per kind.
_PYTHON_ONLY = {
    "image": ("auto_stop", "bayer", "erasure_mask", "preprocess"),
    "volume": ("memory_limit_bytes", "slab_group", "announce"),
    "grid": ("depths_mm", "support", "tolerance", "prepared"),
}
#: Keywords every kind takes (the front door's own).
SHARED = tuple(s.dest for s in ReconOptions.specs() if not s.kinds)


def kind_options(kind: str) -> tuple[str, ...]:
    """The keywords of :func:`recon.reconstruct` only model kind ``kind`` takes: its
    declared :class:`ReconOptions` fields and its Python-only objects."""
    return (*(s.dest for s in ReconOptions.specs() if kind in s.kinds), *_PYTHON_ONLY[kind])


class LiveOptions(Options):
    """The live reconstructor's own parameters (``capture live``, the GUI's Live form);
    its dark level, binning and device are :class:`ReconOptions`'."""

    command = "live reconstruction"

    method: Literal["wiener", "admm"] = option(
        "wiener", help="wiener (a preview, one FFT pair per frame) or admm (warm-started "
        "from the previous frame's state)")
    iterations: int = option(
        5, help="ADMM iterations per frame", ge=1, le=50, methods=("admm",))

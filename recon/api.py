"""The front door: ``recon.reconstruct(model, raw, ...)`` for every forward model.

One call for the three model kinds of Kuo 2020: one PSF (2D, Ch. 3, Eq. 3.4), a PSF
stack with its depths (3D, Ch. 4, Eq. 4.4) and a calibrated PSF grid (spatially
varying, Ch. 5, Eq. 5.5), with the same defaults (method and weights automatic), the
same dark-level vocabulary (docs/cli.md's ``--dark``) and one result,
:class:`recon.result.Reconstruction`. The kinds' own steps live in
:mod:`recon.planar` (2D), :mod:`recon.volume.api` (3D) and :mod:`recon.spatial.api`
(PSF grid).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .errors import ReconInputError
from .options import SHARED, ReconOptions, kind_options, l1_given
from .planar import DEFAULT_TV, check_options, scaled_problem, solve, solver_options
from .result import KINDS, ReconInfo, Reconstruction

__all__ = ["DEFAULT_TV", "KINDS", "SHARED", "PsfStack", "ReconInfo", "Reconstruction",
           "check_options", "check_values", "model_kind", "reconstruct", "reconstruct_grid",
           "reconstruct_volume", "scaled_problem", "solve", "solver_options"]

#: What ``model`` may be, for the error message of :func:`model_kind`.
ACCEPTED_MODELS = ("a PSF array (rows, cols) or (rows, cols, C)",
                   "recon.PsfStack(psf (n_z, rows, cols), depths_mm)",
                   "a recon.spatial.PsfGrid or a list of them (one per depth)")

#: Options only some kinds take (beyond the shared method, iterations, tv, l1,
#: bin_factor, dark and device), from their declarations
#: (:class:`recon.options.ReconOptions`'s ``kinds``) and the kinds' Python-only objects.
KIND_OPTIONS = {kind: kind_options(kind) for kind in KINDS}

#: The declared defaults (:meth:`recon.options.ReconOptions.defaults`): the very objects
#: the command line's flags and the GUI's forms default to.
_D = ReconOptions.defaults()
#: The keywords whose values :func:`reconstruct` checks against their declarations
#: before any work (the others are objects: a dark frame, a mask, a grid's support).
_CHECKED = ("iterations", "tv", "l1", "bin_factor", "seconds", "erase", "seed",
            "full_scale", "k")


@dataclass(frozen=True)
class PsfStack:
    """A PSF stack and the depth of each plane: the 3D model of :func:`reconstruct`.

    A 3D array alone is ambiguous (a colour PSF is (rows, cols, C)), and a stack
    means nothing without its depths, so they travel together.

    Parameters
    ----------
    psf : ndarray, (n_z, rows, cols), real
        One calibration PSF per depth (any order; sorted by depth when solved).
    depths_mm : sequence of float, (n_z,)
        Depth of every plane, mm.
    """

    psf: np.ndarray
    depths_mm: Sequence[float]


def model_kind(model) -> str:
    """Which model kind ``model`` is: ``"image"``, ``"volume"`` or ``"grid"``.

    Parameters
    ----------
    model : ndarray, PsfStack, PsfGrid or list of PsfGrid

    Returns
    -------
    str
        A key of :data:`recon.result.KINDS`.

    Raises
    ------
    ReconInputError
        Anything else, naming what is accepted.
    """
    from .spatial.grid import PsfGrid

    if isinstance(model, PsfStack):
        return "volume"
    if isinstance(model, PsfGrid) or (
            isinstance(model, (list, tuple)) and model
            and all(isinstance(g, PsfGrid) for g in model)):
        return "grid"
    if isinstance(model, np.ndarray) and model.ndim in (2, 3):
        return "image"
    what = (f"an array of shape {model.shape}" if isinstance(model, np.ndarray)
            else type(model).__name__)
    raise ReconInputError(f"model is {what}; give {'; or '.join(ACCEPTED_MODELS)}")


def reconstruct(model, raw: np.ndarray, /, method: str = _D["method"], *,
                iterations: int = _D["iterations"], tv: float | str | None = _D["tv"],
                l1: float | str | None = _D["l1"], bin_factor: int = _D["bin_factor"],
                dark=_D["dark"], device: str = _D["device"], **options) -> Reconstruction:
    """Reconstruct an image or a volume from one lensless measurement and its model.

    The model kind picks the path: one PSF (2D: dark level, binning, colour, the
    convolution model of Eq. 3.4, one solve per channel, Sec. 3.1), a
    :class:`PsfStack` (3D: Eq. 4.4-4.5) or a calibrated :class:`recon.spatial.PsfGrid`
    (spatially varying: Eq. 5.5, Eq. 6.2's background; a list of grids for a
    volume). The image is the sensor field of view on the model grid (Eq. 3.3: the
    scene rotated by 180 degrees, as the data files keep it);
    :meth:`Reconstruction.upright` turns it.

    Parameters
    ----------
    model : ndarray, PsfStack, PsfGrid or list of PsfGrid
        A PSF (rows, cols) or (rows, cols, C), any real dtype, of the raw's spatial
        shape; a :class:`PsfStack`; a grid (2D) or one grid per depth (3D).
        Positional (a grid's ``model=`` option names its forward model:
        ``"auto"``, ``"convolution"``, ``"local"``, ``"pca"``).
    raw : ndarray, (rows, cols) or (rows, cols, C)
        The measurement (sensor counts, DN); colour only with one PSF.
    method : str or ReconOptions
        ``"auto"`` (default): one PSF chooses by :mod:`recon.auto.choice` (ADMM, or
        Wiener for a short time budget), a stack takes 3D ADMM, a grid FISTA on
        Eq. 6.2; ``info.method_reason`` says why. Otherwise one of ``"wiener"``,
        ``"gd"``, ``"fista"``, ``"admm"`` (one PSF), ``"admm"``, ``"fista"`` (stack,
        grid). Or a :class:`recon.options.ReconOptions` holding every declared option
        (``reconstruct(model, raw, options)``, what the command line and the GUI
        pass): its fields for the model's kind (:meth:`ReconOptions.keywords
        <recon.options.ReconOptions.keywords>`) are the keywords, the same call as
        ``reconstruct(model, raw, **options.keywords(kind))``; a keyword given
        beside it replaces its field where it differs from the declared default (a
        dark frame the caller resolved), and the kind's own objects (``bayer``,
        ``depths_mm``, ...) are given beside it as keywords.
    iterations : int
        Maximum iterations (>= 1); the iterative solves stop earlier when the fit
        changes by less than the noise explains (``info.iterations_used``).
    tv : "auto", None or float
        TV weight, absolute in the scaled problem (PSF of unit sum, measurement
        divided by its maximum); ``"auto"`` (default; None too) chooses it by
        hold-out cross-validation (:mod:`recon.auto.weight`; ``info.auto`` has the
        record); a number fixes it (:data:`DEFAULT_TV` and
        :data:`recon.volume.DEFAULT_TV` hold tested fixed weights). FISTA on a grid has
        no TV term (``info.tv`` None).
    l1 : "auto", None or float
        l1 (sparsity) weight; ``"auto"`` chooses it with TV fixed; not given (the
        declared default, :data:`recon.options.L1_DEFAULT`) or None is 0, and 1e-3 for
        FISTA on a grid (Eq. 6.2's sparse object).
    bin_factor : int
        Lateral box binning of model and raw before the solve (>= 1).
    dark : "auto", "none", None, float or ndarray
        The dark level (docs/cli.md's ``--dark``): ``"auto"`` (default) estimates it
        (one PSF: its dark corner ``psf[5:15, 5:15]``, subtracted from both; a stack:
        the median of the planes' corners; a grid: nothing, its PSFs are
        dark-subtracted and Eq. 6.2's background fits the frame's offset); ``"none"``
        or None subtract nothing (the inputs are dark-subtracted); a number is a
        level in DN; an array is a dark frame (raw's shape; one PSF also takes one
        level per channel), subtracted pixel by pixel. A grid subtracts it from the
        raw only.
    device : {"cpu", "cuda", "auto"}
        Where the solves run (:func:`recon.backend.resolve_device`): the CPU's NumPy
        path (default), a CUDA GPU through CuPy or PyTorch (the array-API path,
        ``recon.solvers.device``), or the GPU when one is usable. One PSF: every
        method, an automatic weight's ADMM path too. A stack: 3D ADMM and FISTA, an
        automatic weight's path too (the plane tests on the host). A grid: FISTA
        (Eq. 6.2) and ADMM; ADMM's automatic weight is chosen on the CPU
        (:func:`recon.spatial.api.reconstruct_psf_grid`). ``info.device`` says which
        ran.
    **options
        Kind-specific options (:data:`KIND_OPTIONS`, declared with the others in
        :class:`recon.options.ReconOptions`): one PSF or a stack
        ``allow_mixed_ranges`` (accept a model and raw whose bit depths cannot be one
        camera's); one PSF ``seconds``,
        ``auto_stop``, ``bayer``, ``erase``, ``erasure_mask``, ``seed``,
        ``preprocess``, ``full_scale`` and the named solver's options
        (:func:`solver_options`); a stack ``empty_planes``, ``memory_limit_bytes``,
        ``slab_group``, ``announce`` (:func:`recon.volume.api.reconstruct_stack`); a
        grid ``model``, ``k``, ``background``, ``depths_mm``, ``support``,
        ``tolerance``, ``prepared``, ``two_part`` (:func:`recon.spatial.api.reconstruct_psf_grid`).

    Returns
    -------
    Reconstruction
        ``image`` (float32), ``estimate``, ``results``, ``operator``, ``info``
        (:class:`recon.result.ReconInfo`), ``depths_mm`` for a volume,
        ``background`` and ``choice`` for a grid.

    Raises
    ------
    ReconInputError
        A model of none of the accepted kinds (the message names them), a bad
        argument (a value outside its declared limits, named as the keyword:
        ``iterations=0 is outside its limits: ...``), an option the kind does not
        take, or bad data (see
        :mod:`recon.preprocess`); :class:`recon.preprocess.RawSignalError` for a raw
        with nothing to reconstruct after its dark level; an unusable ``device``
        (names what is missing), an automatic weight or FISTA asked of a GPU for a
        stack, or a problem that does not fit in the GPU's free
        memory.
    recon.errors.DivergenceError
        A solver diverged.

    Examples
    --------
    One PSF (a blurred point), one measurement of two points:

    >>> import numpy as np
    >>> import recon
    >>> psf = np.zeros((24, 32)); psf[10:13, 14:17] = 1.0
    >>> scene = np.zeros((24, 32)); scene[8, 9] = scene[15, 20] = 50.0
    >>> raw = np.real(np.fft.ifft2(np.fft.fft2(scene) * np.fft.fft2(np.fft.ifftshift(psf))))
    >>> rec = recon.reconstruct(psf, raw, "admm", tv=1e-4, iterations=20, dark="none")
    >>> rec.image.shape, rec.image.dtype, rec.info.method, rec.info.kind
    ((24, 32), dtype('float32'), 'admm', 'image')
    >>> rec.upright().shape
    (24, 32)

    A stack of two depths, the same call:

    >>> stack = recon.PsfStack(np.stack([psf, np.roll(psf, 3, axis=1)]), [10.0, 12.0])
    >>> vol = recon.reconstruct(stack, raw, "fista", tv=0.0, iterations=10, dark="none")
    >>> vol.image.shape, vol.depths_mm, vol.info.kind
    ((2, 24, 32), [10.0, 12.0], 'volume')

    A PSF grid of one node (the convolution model), background estimated:

    >>> from recon.spatial import PsfGrid
    >>> grid = PsfGrid(psf[None], np.zeros((1, 2)), (1, 1))
    >>> g = recon.reconstruct(grid, raw + 5.0, iterations=10)
    >>> g.info.kind, g.info.method, g.background.shape
    ('grid', 'fista', (24, 32))
    """
    kind = model_kind(model)
    if isinstance(method, ReconOptions):  # reconstruct(model, raw, options)
        beside = {k: v for k, v in (("iterations", iterations), ("tv", tv), ("l1", l1),
                                    ("bin_factor", bin_factor), ("dark", dark),
                                    ("device", device)) if _given(v, _D[k])}
        return reconstruct(model, raw, **{**method.keywords(kind), **beside, **options})
    allowed = KIND_OPTIONS[kind]
    extra = [k for k in options if k not in allowed]
    if kind == "image":  # solver options by name (checked against the method there)
        extra = [k for k in extra if k in sum(KIND_OPTIONS.values(), ())]
    if extra:
        raise ReconInputError(
            f"a {_KIND_WORDS[kind]} takes no option {', '.join(map(repr, sorted(extra)))}; its "
            f"own options are {', '.join(allowed)}")
    check_values(method=method, iterations=iterations, tv=tv, l1=l1, bin_factor=bin_factor,
                 **options)
    l1 = l1_given(l1)  # None: the model's own default (0, FISTA on a grid 1e-3)
    # the options object every kind's path reads (checked above; the dark level as the
    # kind takes it), and the kind's own objects beside it
    chosen = ReconOptions.from_defaults(
        method=method, iterations=iterations, tv=tv,
        l1=l1 if kind == "grid" else 0.0 if l1 is None else l1, bin_factor=bin_factor,
        dark=_image_dark(dark) if kind == "image" else dark, device=device,
        **{k: v for k, v in options.items() if k in _D})
    own = {k: v for k, v in options.items() if k not in _D}
    if kind == "image":
        from .planar import reconstruct_image

        return reconstruct_image(model, raw, chosen, **own)
    if kind == "volume":
        from .volume.api import reconstruct_stack

        return reconstruct_stack(model.psf, model.depths_mm, raw, chosen, **own)
    from .spatial.api import reconstruct_psf_grid

    grids = model if not isinstance(model, tuple) else list(model)
    return reconstruct_psf_grid(grids, raw, chosen, **own)


def _given(value, default) -> bool:
    """Whether a keyword of :func:`reconstruct` was given other than its declared
    default (``l1=0.0`` is given: the default is the unset
    :data:`recon.options.L1_DEFAULT`)."""
    return not (value is default or (type(value) is type(default) and value == default))


def check_values(**values) -> None:
    """Check the keywords of :func:`reconstruct` against their declarations
    (:class:`recon.options.ReconOptions`: type and limits, and the checks between them,
    :meth:`~recon.options.ReconOptions.check_together`), before any work.

    Raises
    ------
    ReconInputError
        A value outside its limits or of the wrong type, named as the Python keyword
        (``tv=-1 is outside its limits: TV weight must be >= 0``), or values that
        cannot be used together (``prior='dncnn'`` with ``method='wiener'``).
    """
    given = {k: v for k, v in values.items() if k in _CHECKED
             and not (k in ("tv", "l1") and v is None)
             and not isinstance(v, np.ndarray)}
    if any(isinstance(v, bool) for k, v in given.items() if k != "seed"):
        name = next(k for k, v in given.items() if isinstance(v, bool))
        raise ReconInputError(f"{name}={given[name]!r}: give a number, not a truth value")
    together = {k: values[k] for k in ("method", "prior") if k in values}
    try:
        ReconOptions.validated(given, front="python")
        ReconOptions.check_together(together, front="python")
    except ValueError as exc:  # diffuserlab.errors.InputError: as the numerics' error
        raise ReconInputError(str(exc)) from None


_KIND_WORDS = {"image": "PSF (2D)", "volume": "PSF stack", "grid": "PSF grid"}


def _image_dark(dark):
    """The front door's dark for the 2D path (:func:`recon.preprocess.dark.front_door_dark`,
    the estimate spelled ``"auto"``)."""
    from .preprocess.dark import front_door_dark

    resolved = front_door_dark(dark)
    return "auto" if resolved is None else resolved


def reconstruct_volume(psf_stack: np.ndarray, depths_mm, raw: np.ndarray,
                       **kwargs) -> Reconstruction:
    """``reconstruct(PsfStack(psf_stack, depths_mm), raw, **kwargs)``: the 3D form.

    Kept as a short spelling of the front door; every argument and the result are
    :func:`reconstruct`'s.

    Examples
    --------
    >>> import numpy as np
    >>> import recon
    >>> psf = np.zeros((16, 16)); psf[7:9, 7:9] = 1.0
    >>> raw = np.roll(psf, (2, -3), axis=(0, 1)) * 40.0
    >>> vol = recon.reconstruct_volume(np.stack([psf, psf.T]), [1.0, 2.0], raw,
    ...                                method="fista", tv=0.0, iterations=5, dark="none")
    >>> vol.volume.shape
    (2, 16, 16)
    """
    return reconstruct(PsfStack(psf_stack, depths_mm), raw, **kwargs)


def reconstruct_grid(grids, raw: np.ndarray, **kwargs) -> Reconstruction:
    """``reconstruct(grids, raw, **kwargs)`` for a :class:`recon.spatial.PsfGrid` (or a list).

    Kept as a short spelling of the front door that refuses anything but a grid;
    every argument and the result are :func:`reconstruct`'s.

    Raises
    ------
    ReconInputError
        ``grids`` is not a PsfGrid or a list of them.
    """
    if model_kind(grids) != "grid":
        raise ReconInputError("reconstruct_grid takes a recon.spatial.PsfGrid or a list of "
                              "them; use recon.reconstruct for a PSF or a PsfStack")
    return reconstruct(grids, raw, **kwargs)

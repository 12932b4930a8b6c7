"""Reconstruction with a calibrated PSF grid: preprocess, choose the model, solve, crop.

:func:`reconstruct_grid` is what ``diffuserlab recon --psf-grid`` and ``recon3d
--psf-grid`` run (through :mod:`instrument.reconstruct_grid`): bin the grid and the
raw frame alike, pick the forward model (``auto``: :func:`recon.spatial.choose_model`),
scale as the other solvers expect (central PSF of unit sum, measurement divided by
its maximum) and solve Eq. 6.2 with :func:`recon.spatial.fista_background`
(``background="estimate"``) or the same l1 FISTA without a background
(``"none"``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ReconInputError
from ..preprocess import box_bin
from ..solvers.common import SolveResult
from ..validate import as_int, nonneg_weight
from .background import fista_background
from .choice import MODELS, ModelChoice, build_operator, choose_model, predicted_errors
from .grid import PsfGrid

__all__ = ["BACKGROUNDS", "GridReconstruction", "bin_grid", "grid_model", "reconstruct_grid"]

#: ``--background`` choices.
BACKGROUNDS = ("estimate", "none")


@dataclass
class GridReconstruction:
    """Result of :func:`reconstruct_grid`.

    Attributes
    ----------
    image : ndarray, float32
        Sensor field of view: (rows, cols) in 2D, (n_z, rows, cols) in 3D, in
        measurement units per unit of the normalised central PSF.
    background : ndarray, float32, (rows, cols) or None
        The estimated background, measurement units.
    result : SolveResult
    operator : SpatialConvolutionOperator
    choice : ModelChoice
    info : dict
    """

    image: np.ndarray
    background: np.ndarray | None
    result: SolveResult
    operator: object
    choice: ModelChoice
    info: dict = field(default_factory=dict)

    def metrics(self, floor_seconds: float | None = None) -> dict:
        """JSON-ready record: model, cost, timings against the FFT floor of the
        model's ``K`` convolutions (:func:`recon.volume.fft_floor_seconds`)."""
        from ..volume import fft_floor_seconds

        op = self.operator
        if floor_seconds is None:
            floor_seconds = fft_floor_seconds(op.padded_shape, op.n_kernels)
        per_it = float(np.median(self.result.history.seconds))
        return {"model": self.choice.as_dict(), "n_kernels": int(op.n_kernels),
                "ffts_per_apply": int(op.ffts_per_apply), "shape": list(self.image.shape),
                "padded_shape": list(op.padded_shape), **self.info,
                "seconds_per_iteration": per_it, "fft_floor_seconds": floor_seconds,
                "ratio_to_fft_floor": per_it / floor_seconds,
                "final_relative_residual": self.result.final_relative_residual,
                "objective": list(self.result.history.objective)}


def bin_grid(grid: PsfGrid, factor: int) -> PsfGrid:
    """A grid box-binned laterally by ``factor`` (PSFs summed over blocks, shifts scaled).

    Bin the raw frame with :func:`recon.preprocess.box_bin` by the same factor.
    """
    factor = as_int(factor, "bin factor", 1)
    if factor == 1:
        return grid
    psfs = box_bin(np.moveaxis(grid.psfs, 0, -1), factor)
    return PsfGrid(np.moveaxis(psfs, -1, 0), grid.shifts_px / factor, grid.grid_shape,
                   grid.z_mm, grid.d_mm)


def grid_model(grids, *, model: str = "auto", k: int | None = None, depths_mm=None,
               bin_factor: int = 1, support=None, tolerance: float | None = None
               ) -> tuple[ModelChoice, object]:
    """Choose the forward model of a calibrated grid and build it, once for many frames.

    The grids are binned by ``bin_factor`` (:func:`bin_grid`); ``auto`` takes
    :func:`recon.spatial.choose_model`'s choice, any other model is used as given
    (its predicted errors still reported).

    Parameters
    ----------
    grids : PsfGrid or list of PsfGrid
        One grid (2D) or one per depth (3D).
    model, k, depths_mm, bin_factor, support, tolerance
        As :func:`reconstruct_grid`.

    Returns
    -------
    (ModelChoice, SpatialConvolutionOperator)
        Pass them to :func:`reconstruct_grid` as ``prepared`` for every frame.

    Raises
    ------
    ReconInputError
        Unknown model, bad bin factor.
    """
    if model not in MODELS:
        raise ReconInputError(f"unknown model {model!r}; choose one of {', '.join(MODELS)}")
    single = isinstance(grids, PsfGrid)
    glist = [bin_grid(g, bin_factor) for g in ([grids] if single else list(grids))]
    arg = glist[0] if single else glist
    if model == "auto":
        opts = {} if tolerance is None else {"tolerance": tolerance}
        support_2d = None if support is None or np.ndim(support) == 2 else np.any(support, 0)
        choice = choose_model(arg, support=support_2d, **opts)
    else:
        errors = predicted_errors(arg)
        choice = ModelChoice(model, k, 0, errors, reason="given (--model)")
    op = build_operator(arg, choice.model, k=choice.k, depths_mm=depths_mm, support=support)
    choice.convolutions = op.n_kernels // (op.n_z if op.volume else 1)
    if choice.model == "pca":
        choice.k = op.components[0]
    return choice, op


def reconstruct_grid(grids, raw: np.ndarray, *, model: str = "auto", k: int | None = None,
                     background: str = "estimate", l1: float = 1e-3, iterations: int = 200,
                     depths_mm=None, bin_factor: int = 1, dark: float = 0.0,
                     support=None, tolerance: float | None = None,
                     prepared: tuple | None = None) -> GridReconstruction:
    """Reconstruct an image (one grid) or a volume (several grids) from one frame.

    Parameters
    ----------
    grids : PsfGrid or list of PsfGrid
        Registered calibration grids (one: 2D; a list, one per depth: 3D).
    raw : ndarray, (rows, cols)
        The frame, same shape as the PSFs.
    model : {"auto", "convolution", "local", "pca"}
    k : int, optional
        PCA components (default from the explained energy).
    background : {"estimate", "none"}
        Eq. 6.2's joint background, or none.
    l1 : float
        l1 weight in the scaled problem.
    iterations : int
    depths_mm : array_like, optional
        3D reconstruction depths (grids synthesised, Sec. 5.2); default the grids'.
    bin_factor : int
    dark : float
        Level subtracted from the raw frame first (DN).
    support : ndarray of bool, optional
        Object support on the model's object grid (after binning).
    tolerance : float, optional
        For ``auto`` (default :data:`recon.spatial.choice.DEFAULT_TOLERANCE`).
    prepared : (ModelChoice, SpatialConvolutionOperator), optional
        :func:`grid_model`'s result for these grids and ``bin_factor``, made once for
        a batch of frames (then ``model``, ``k``, ``depths_mm``, ``support`` and
        ``tolerance`` are not used).

    Returns
    -------
    GridReconstruction

    Raises
    ------
    ReconInputError
        Unknown model or background, a frame whose shape differs from the PSFs (or
        from the ``prepared`` model's).
    """
    if model not in MODELS:
        raise ReconInputError(f"unknown model {model!r}; choose one of {', '.join(MODELS)}")
    if background not in BACKGROUNDS:
        raise ReconInputError(f"unknown background {background!r}; choose estimate or none")
    iterations = as_int(iterations, "iterations", 1)
    l1 = nonneg_weight(l1, "l1")
    t0 = time.perf_counter()
    single = isinstance(grids, PsfGrid)
    glist = [grids] if single else list(grids)
    b = np.asarray(raw, np.float64)
    if b.shape != glist[0].sensor_shape:
        raise ReconInputError(f"raw frame shape {b.shape} differs from the PSF grid's "
                              f"{glist[0].sensor_shape}; pass the frame of the calibrated camera")
    b = box_bin(b - float(dark), bin_factor) if bin_factor > 1 else b - float(dark)
    if prepared is None:
        prepared = grid_model(grids, model=model, k=k, depths_mm=depths_mm,
                              bin_factor=bin_factor, support=support, tolerance=tolerance)
    choice, op = prepared
    if tuple(op.shape_out) != b.shape:
        raise ReconInputError(f"the prepared model's frames are {tuple(op.shape_out)} but the "
                              f"binned frame is {b.shape}; prepare it with the same bin factor")
    scale = float(np.max(np.abs(b)))
    if not scale > 0:
        raise ReconInputError("raw frame is zero after the dark level; check the exposure")
    res = fista_background(op, (b / scale).astype(np.float32), iterations=iterations, l1=l1,
                           estimate_background=background == "estimate")
    crop = (slice(None), *op.crop) if op.volume else op.crop
    image = (res.x[crop] * scale).astype(np.float32)
    g = res.params["background"] * scale if background == "estimate" else None
    info = {"background": background, "l1": l1, "iterations": iterations,
            "bin_factor": int(bin_factor), "dark": float(dark), "raw_scale": scale,
            "psf_scale": float(op.scale), "seconds_total": time.perf_counter() - t0,
            "depths_mm": None if not op.volume else [float(z) for z in op.depths]}
    return GridReconstruction(image, g, res, op, choice, info)

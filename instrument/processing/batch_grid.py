"""Batch reconstruction of a recorded run with a spatially varying model (``recon-run
--psf-grid``).

:func:`prepare_grid_batch` loads a ``calibrate psf-grid`` run
(:func:`instrument.processing.reconstruct_grid.load_psf_grid`), chooses the forward model once
for the whole batch (``auto``: the cheapest model within the predicted error
tolerance, :func:`recon.spatial.choose_model`; or the model given) and builds it
once (:func:`recon.spatial.api.grid_model`). :func:`instrument.processing.batch.reconstruct_run`
sends that prepared model to its dask workers, which run
:func:`reconstruct_stored_frame_grid` on each frame: the l1 FISTA of
:func:`recon.reconstruct` for a PSF grid with, by default, the frame's own smooth
background estimated jointly (Kuo 2020, Eq. 6.2), stored beside the image.
"""

from __future__ import annotations

import functools
from contextlib import nullcontext
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["GridBatchModel", "open_run", "prepare_grid_batch", "reconstruct_stored_frame_grid"]


@functools.lru_cache(maxsize=4)
def open_run(path: str):
    """The run store at ``path``, read-only, opened once per process (the batch's dask
    tasks, :mod:`instrument.processing.batch` and this module's)."""
    from ..runs.runstore import RunStore

    return RunStore.open(path)


def reconstruct_run_frame(run_path: str, index: int, model: Any, threads: int | None,
                          raw_dtype: Any = None, **keywords: Any) -> Any:
    """:func:`recon.reconstruct` of frame ``index`` of a run: the body of every batch
    task (this module's and :func:`instrument.processing.batch.reconstruct_stored_frame`).

    Parameters
    ----------
    run_path : str
        The run store (:func:`open_run`).
    index : int
        Frame slot.
    model : ndarray or recon.spatial.PsfGrid
        The PSF or PSF grid.
    threads : int or None
        FFT and numba threads of the task (:func:`recon.fft.limited_threads`); None
        or 0 leaves the process's defaults.
    raw_dtype : dtype, optional
        The frame converted to this dtype first; None passes it as stored.
    **keywords
        Of :func:`recon.reconstruct`.

    Returns
    -------
    recon.result.Reconstruction

    Raises
    ------
    RunStoreError
        A damaged frame.
    recon.errors.ReconInputError, recon.errors.DivergenceError
        Options :func:`recon.reconstruct` refuses, or a solve that diverged.
    """
    from recon import reconstruct
    from recon.fft import limited_threads

    raw = open_run(str(run_path)).frame(int(index)).image
    if raw_dtype is not None:
        raw = np.asarray(raw, raw_dtype)
    with limited_threads(threads) if threads else nullcontext():
        return reconstruct(model, raw, **keywords)


@dataclass
class GridBatchModel:
    """A PSF grid with its forward model chosen and built, for every frame of a batch.

    Attributes
    ----------
    grid : recon.spatial.PsfGrid
        The registered calibration PSFs (sensor shape, unbinned).
    choice : recon.spatial.ModelChoice
        The model used (made once for the batch) and why.
    operator : recon.spatial.SpatialConvolutionOperator
        That model on the binned grid.
    source : str
        The psf-grid run it came from.
    model : str
        The ``--model`` asked for (``auto`` or a model name).
    bin_factor : int
    """

    grid: Any
    choice: Any
    operator: Any
    source: str
    model: str
    bin_factor: int

    @property
    def product_name(self) -> str:
        """Default product: ``recon_grid_<model>`` (``local``, ``convolution``,
        ``pcaK``)."""
        return f"recon_grid_{self.choice.label().replace(':', '')}"

    def settings(self) -> dict[str, Any]:
        """What the product records of the model (compared on resume: the model used,
        so ``auto`` resumes a product of the model it chooses)."""
        return {"psf_grid": self.source, "model": self.choice.label(),
                "convolutions_per_apply": int(self.operator.n_kernels)}


def prepare_grid_batch(psf_grid: str, frame_shape, *, model: str = "auto",
                       k: int | None = None, bin_factor: int) -> GridBatchModel:
    """Load a psf-grid run and choose and build its forward model for a run's frames.

    Parameters
    ----------
    psf_grid : str
        ``RUN.zarr`` of a finished ``calibrate psf-grid`` (or ``psf-blind``) run.
    frame_shape : (int, int)
        The recorded frames' shape (the grid must have been calibrated on it).
    model : {"auto", "convolution", "local", "pca"}
    k : int, optional
        PCA components (``model="pca"``; default from the explained energy).
    bin_factor : int

    Returns
    -------
    GridBatchModel

    Raises
    ------
    recon.errors.ReconInputError
        Not a finished psf-grid run, a grid calibrated on another sensor shape, an
        unknown model, a bad ``k`` or bin factor.
    """
    from recon.errors import ReconInputError
    from recon.spatial.api import grid_model
    from recon.validate import as_int

    from .reconstruct_grid import load_psf_grid

    bin_factor = as_int(bin_factor, "bin factor", minimum=1)
    if k is not None and model != "pca":
        raise ReconInputError(f"--pca-k {k} goes with --model pca; drop it or add --model pca")
    k = None if k is None else as_int(k, "--pca-k", minimum=1)
    grid = load_psf_grid(psf_grid)
    if tuple(grid.sensor_shape) != tuple(frame_shape):
        raise ReconInputError(
            f"--psf-grid {psf_grid} was calibrated on a {grid.sensor_shape[0]}x"
            f"{grid.sensor_shape[1]} sensor but the run's frames are {frame_shape[0]}x"
            f"{frame_shape[1]}; calibrate a PSF grid with the camera settings that recorded "
            "the run")
    choice, op = grid_model(grid, model=model, k=k, bin_factor=bin_factor)
    return GridBatchModel(grid, choice, op, str(psf_grid), model, bin_factor)


def reconstruct_stored_frame_grid(run_path: str, index: int, prepared: GridBatchModel,
                                  options: dict[str, Any], threads: int | None = None
                                  ) -> tuple[int, np.ndarray, np.ndarray | None]:
    """Reconstruct frame ``index`` of a run with a prepared grid model (a dask task).

    Parameters
    ----------
    run_path : str
        The run store (read-only; :func:`open_run` opens it once per worker process).
    index : int
        The frame's slot in the run.
    prepared : GridBatchModel
        From :func:`prepare_grid_batch` (sent to each worker once).
    options : dict
        ``background`` ("estimate" or "none"), ``l1``, ``iterations``, ``dark``
        (the frames' dark level: DN, a (rows, cols) frame, or None for 0) and
        ``device`` (``device`` of :func:`recon.reconstruct`; default cpu).
    threads : int, optional
        FFT and numba threads of the task (:func:`recon.fft.limited_threads`).

    Returns
    -------
    (int, ndarray, ndarray or None)
        ``index``, the image (float32, (rows // bin, cols // bin), the sensor field
        of view on the model grid, as every reconstruction) and the estimated
        background (float32, same shape; None with ``background="none"``), both in
        frame units (DN).

    Raises
    ------
    RunStoreError
        The frame is not stored or is damaged.
    recon.errors.ReconInputError
        From :func:`recon.reconstruct`.
    """
    dark = options.get("dark")
    rec = reconstruct_run_frame(run_path, index, prepared.grid, threads, np.float64,
                                method="fista",
                                background=options["background"], l1=options["l1"],
                                iterations=options["iterations"],
                                bin_factor=prepared.bin_factor,
                                dark="none" if dark is None else dark,
                                prepared=(prepared.choice, prepared.operator),
                                device=options.get("device", "cpu"))
    background = None if rec.background is None else np.asarray(rec.background, np.float32)
    return int(index), np.asarray(rec.image, np.float32), background

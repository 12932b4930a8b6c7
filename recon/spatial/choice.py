"""Which forward model a PSF grid needs: "model no more than a scene needs" (Ch. 5).

Three models of increasing cost serve a calibrated PSF grid: the convolution model
with the central PSF (1 convolution per plane, Eq. 3.4 / 4.4), the PCA model with
``k`` principal PSFs (``k`` convolutions, Eq. 5.6-5.7) and the local convolution
model with every grid PSF (``N`` convolutions, Eq. 5.3-5.5). :func:`predicted_errors`
states each one's model error on the calibration itself, over the nodes whose
region the scene occupies (the object support):

* convolution: ``max_i sqrt(1 - ip(h~_i, h~_c)^2)`` with ``ip`` the normalised
  inner product of a registered PSF and the central one (Fig. 5.1d) over the
  pixels the node's PSF had on the sensor (:meth:`PsfGrid.valid_masks`) -- the
  relative residual of the best multiple of the central PSF, so a pure brightness
  change (which the object absorbs, Eq. 5.1 far from the sensor) costs nothing;
* PCA with ``k``: ``max_i ||h~_i - H_k e_i|| / ||h~_i||``, the rank-``k`` residual;
* local: the bilinear interpolation error between nodes, ``max ||h~_{i-1} - 2 h~_i
  + h~_{i+1}|| / (8 ||h~_i||)`` along rows and columns (the linear-interpolation
  bound ``f'' Delta^2 / 8`` with the second difference standing for ``f''
  Delta^2``); 0 when no axis has three nodes.

:func:`choose_model` takes the cheapest model whose predicted error is within a
tolerance and, with ``measure=True``, checks it by reconstruction: a sparse scene
rendered with the local model from the grid (binned small), Poisson noise,
reconstructed with every candidate, PSNR against the truth; the cheapest model
within ``margin_db`` of the local model's PSNR wins. The default tolerance,
:data:`DEFAULT_TOLERANCE`, comes from the microscope benchmark
(``diffuserlab benchmark recon --only spatial_accuracy``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ReconInputError
from ..options import MODELS  # model names of ``--model``
from ..preprocess import box_bin
from .grid import PsfGrid
from .operator import local_convolution_operator, pca_components, pca_operator

__all__ = ["DEFAULT_TOLERANCE", "MODELS", "ModelChoice", "build_operator", "choose_model",
           "measure_models", "predicted_errors"]

#: Largest predicted relative model error a cheaper model may have.
DEFAULT_TOLERANCE = 0.1


@dataclass
class ModelChoice:
    """The model chosen for a PSF grid and the figures it was chosen on.

    Attributes
    ----------
    model : {"convolution", "local", "pca"}
    k : int or None
        Principal PSFs per plane (PCA).
    convolutions : int
        Convolutions per plane and apply.
    predicted_error : dict
        ``"convolution"``, ``"pca:k"`` for k = 1..N-1 and ``"local"``: relative model
        error (max over the nodes in the support and over the planes).
    measured_psnr_db : dict or None
        Reconstruction PSNR per candidate when measured.
    tolerance : float
    reason : str
    """

    model: str
    k: int | None
    convolutions: int
    predicted_error: dict
    measured_psnr_db: dict | None = None
    tolerance: float = DEFAULT_TOLERANCE
    reason: str = ""
    extra: dict = field(default_factory=dict)

    def label(self) -> str:
        """``convolution``, ``local`` or ``pca:k``."""
        return f"pca:{self.k}" if self.model == "pca" else self.model

    def as_dict(self) -> dict:
        """JSON-ready record."""
        return {"model": self.model, "k": self.k, "label": self.label(),
                "convolutions_per_plane": self.convolutions,
                "predicted_error": dict(self.predicted_error),
                "measured_psnr_db": self.measured_psnr_db, "tolerance": self.tolerance,
                "reason": self.reason, **self.extra}


def _grids(grids) -> list[PsfGrid]:
    out = [grids] if isinstance(grids, PsfGrid) else list(grids)
    if not out or not all(isinstance(g, PsfGrid) for g in out):
        raise ReconInputError("pass a PsfGrid or a list of them")
    return out


def _nodes_in_support(grid: PsfGrid, support) -> np.ndarray:
    if support is None:
        return np.arange(grid.n)
    op = local_convolution_operator(grid, support=support)
    return op.kept


def predicted_errors(grids, support=None) -> dict[str, float]:
    """Predicted relative model errors of the candidate models (module docstring).

    Parameters
    ----------
    grids : PsfGrid or list of PsfGrid
    support : ndarray of bool, optional
        Object support on one plane's padded grid (2D), applied to every plane.

    Returns
    -------
    dict
        ``{"convolution": e, "pca:1": e, ..., "pca:N-1": e, "local": e}``, each the
        maximum over planes.
    """
    errors: dict[str, float] = {}

    def keep_max(key, value):
        errors[key] = max(errors.get(key, 0.0), float(value))

    for g in _grids(grids):
        nodes = _nodes_in_support(g, support)
        valid = g.valid_masks().reshape(g.n, -1)
        H = g.psfs.reshape(g.n, -1).astype(np.float64)
        ref = H[g.central]
        keep_max("convolution", max(_shape_error(H[i], ref, valid[i]) for i in nodes))
        for k in range(1, g.n):
            principal, weights, _ = pca_components(g, k=k)
            if len(principal) < k:  # rank reached: more components add nothing
                break
            approx = weights.reshape(k, g.n).T @ principal.reshape(k, -1).astype(np.float64)
            rel = [np.linalg.norm((H[i] - approx[i])[valid[i]]) / np.linalg.norm(H[i][valid[i]])
                   for i in nodes]
            keep_max(f"pca:{k}", max(rel))
        keep_max("local", _interpolation_error(g, nodes, valid))
    return errors


def _shape_error(h: np.ndarray, ref: np.ndarray, valid: np.ndarray) -> float:
    """sqrt(1 - ip^2) of two PSFs over the pixels the node's sensor saw."""
    a, b = h[valid], ref[valid]
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na == 0 or nb == 0:
        return 1.0
    return float(np.sqrt(max(0.0, 1.0 - (float(a @ b) / (na * nb)) ** 2)))


def _interpolation_error(g: PsfGrid, nodes, valid) -> float:
    ny, nx = g.grid_shape
    h = g.psfs.reshape(ny, nx, -1).astype(np.float64)
    ok = valid.reshape(ny, nx, -1)
    wanted = set(int(i) for i in nodes)
    worst = 0.0
    for a in range(ny):
        for b in range(nx):
            if a * nx + b not in wanted:
                continue
            for da, db in ((1, 0), (0, 1)):
                if 0 <= a - da and a + da < ny and 0 <= b - db and b + db < nx:
                    m = ok[a - da, b - db] & ok[a, b] & ok[a + da, b + db]
                    second = (h[a - da, b - db] - 2 * h[a, b] + h[a + da, b + db])[m]
                    norm = np.linalg.norm(h[a, b][m])
                    if norm > 0:
                        worst = max(worst, float(np.linalg.norm(second) / (8 * norm)))
    return worst


def build_operator(grids, model: str, *, k: int | None = None, **options):
    """The forward model of a choice: ``"convolution"`` (the central PSF of each
    grid, as a one-node local model), ``"local"`` or ``"pca"`` (with ``k``).

    Parameters
    ----------
    grids : PsfGrid or list of PsfGrid
    model : {"convolution", "local", "pca"}
    k : int, optional
        PCA components (default: :func:`pca_operator`'s explained-energy rule).
    **options
        Passed to the builder (``depths_mm``, ``support``, ``padded_shape``, ...).

    Returns
    -------
    recon.spatial.SpatialConvolutionOperator
    """
    if model == "local":
        return local_convolution_operator(grids, **options)
    if model == "pca":
        return pca_operator(grids, k=k, **options)
    if model == "convolution":
        single = [PsfGrid(g.psfs[g.central][None], [(0.0, 0.0)], (1, 1), g.z_mm, g.d_mm)
                  for g in _grids(grids)]
        op = local_convolution_operator(single[0] if isinstance(grids, PsfGrid) else single,
                                        **options)
        op.model = "convolution"
        return op
    raise ReconInputError(f"unknown model {model!r}; choose one of {', '.join(MODELS)}")


def measure_models(grids, candidates, *, max_side: int = 96, iterations: int = 150,
                   l1: float = 1e-4, photons: float = 2000.0, n_points: int = 12,
                   seed: int = 0) -> dict[str, float]:
    """Reconstruction PSNR of each candidate model on a scene rendered from the grid.

    A sparse scene (``n_points`` points per plane over the nodes' region) is
    imaged with the local model of the grids (binned so the sensor's longer side
    is at most ``max_side``), Poisson noise at ``photons`` for the brightest pixel
    is added, and each candidate (``"convolution"``, ``"pca:k"``, ``"local"``)
    reconstructs it with l1 FISTA (:func:`recon.spatial.fista_background`, no
    background); the PSNR is taken over the object plane(s) after a least-squares
    gain.

    Returns
    -------
    dict
        candidate label -> PSNR in dB.
    """
    from .background import fista_background

    glist = _grids(grids)
    factor = max(1, int(np.ceil(max(glist[0].sensor_shape) / max_side)))
    small = [PsfGrid(box_bin(np.moveaxis(g.psfs, 0, -1), factor).transpose(2, 0, 1)
                     if factor > 1 else g.psfs, g.shifts_px / factor, g.grid_shape,
                     g.z_mm, g.d_mm) for g in glist]
    arg = small[0] if isinstance(grids, PsfGrid) else small
    truth_op = local_convolution_operator(arg)
    rng = np.random.default_rng(seed)
    x = np.zeros(truth_op.shape_in, np.float32)
    xv = x if truth_op.volume else x[None]
    p0, p1 = truth_op.padded_shape
    for z, g in enumerate(small):
        rows, cols = g.node_coordinates()
        r = rng.uniform(rows.min(), rows.max() + 1e-9, n_points) + p0 // 2
        c = rng.uniform(cols.min(), cols.max() + 1e-9, n_points) + p1 // 2
        xv[z, r.astype(int), c.astype(int)] = rng.uniform(0.5, 1.0, n_points)
    clean = truth_op.forward(x)
    gain = photons / float(clean.max())
    b = (rng.poisson(np.maximum(clean, 0) * gain) / gain).astype(np.float32)
    out = {}
    for label in candidates:
        model, _, kk = label.partition(":")
        op = build_operator(arg, model, k=int(kk) if kk else None)
        res = fista_background(op, b / b.max(), iterations=iterations, l1=l1,
                               estimate_background=False)
        e, t = res.x.ravel().astype(np.float64), x.ravel().astype(np.float64)
        g_fit = float(e @ t) / max(float(e @ e), 1e-30)
        out[label] = float(10 * np.log10(t.max() ** 2 / np.mean((g_fit * e - t) ** 2)))
    return out


def choose_model(grids, *, support=None, tolerance: float = DEFAULT_TOLERANCE,
                 measure: bool = False, margin_db: float = 1.0, **measure_options
                 ) -> ModelChoice:
    """The cheapest model whose predicted (and, if asked, measured) error suffices.

    Parameters
    ----------
    grids : PsfGrid or list of PsfGrid
    support : ndarray of bool, optional
        Object support on one plane's padded grid.
    tolerance : float
        Largest predicted relative model error (default :data:`DEFAULT_TOLERANCE`).
    measure : bool
        Also reconstruct a rendered scene with every candidate
        (:func:`measure_models`) and take the cheapest within ``margin_db`` of the
        local model.
    margin_db : float
    **measure_options
        Passed to :func:`measure_models`.

    Returns
    -------
    ModelChoice
    """
    if not (isinstance(tolerance, int | float) and tolerance > 0):
        raise ReconInputError(f"tolerance must be a number > 0, got {tolerance!r}")
    glist = _grids(grids)
    errors = predicted_errors(grids, support)
    n_nodes = max(len(_nodes_in_support(g, support)) for g in glist)
    candidates = [("convolution", None, 1)]
    candidates += [("pca", k, k) for k in range(1, n_nodes)
                   if f"pca:{k}" in errors and k < n_nodes]
    candidates.append(("local", None, n_nodes))

    def label(m, k):
        return f"pca:{k}" if m == "pca" else m

    measured = None
    if measure:
        measured = measure_models(grids, [label(m, k) for m, k, _ in candidates],
                                  **measure_options)
        best = measured["local"]
        for m, k, cost in candidates:
            if measured[label(m, k)] >= best - margin_db:
                return ModelChoice(m, k, cost, errors, measured, tolerance,
                                   f"{label(m, k)} reconstructs within {margin_db:g} dB of "
                                   f"the local model ({measured[label(m, k)]:.1f} against "
                                   f"{best:.1f} dB)")
    for m, k, cost in candidates:
        e = errors[label(m, k)]
        if e <= tolerance:
            return ModelChoice(m, k, cost, errors, measured, tolerance,
                               f"{label(m, k)}: predicted model error {e:.3f} <= {tolerance:g}"
                               f" with {cost} convolution(s) per plane")
    return ModelChoice("local", None, n_nodes, errors, measured, tolerance,
                       f"no model within {tolerance:g}: the local model (interpolation error "
                       f"{errors['local']:.3f}); a finer grid would lower it (Eq. 5.9)")

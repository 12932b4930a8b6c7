"""Two-point resolution across the field with a spatially varying model (Sec. 6.4, Fig. 6.4a).

At each field position two point sources ``s`` pixels apart (object grid) are
imaged with the forward model (or a separate "truth" model, e.g. a finer one),
noise is added, and the model reconstructs them with l1 FISTA
(:func:`recon.spatial.fista_background`, no background); they are resolved when
the reconstruction dips by at least 20 % between them
(:func:`recon.analysis.dip_between`, the criterion of Sec. 6.4). The resolution at
a position is the smallest tested separation from which on every larger one is
resolved.
"""

from __future__ import annotations

import numpy as np

from ..analysis import dip_between
from ..analysis.distinguishability import DIP_CRITERION
from ..errors import ReconInputError
from .background import fista_background

__all__ = ["two_point_resolution"]


def _splat(shape, points) -> np.ndarray:
    out = np.zeros(shape, np.float32)
    for r, c in points:
        r0, c0 = int(np.floor(r)), int(np.floor(c))
        fr, fc = r - r0, c - c0
        for dr, dc, w in ((0, 0, (1 - fr) * (1 - fc)), (1, 0, fr * (1 - fc)),
                          (0, 1, (1 - fr) * fc), (1, 1, fr * fc)):
            out[r0 + dr, c0 + dc] += w
    return out


def two_point_resolution(op, field_px, separations_px, *, truth_op=None, axis: str = "x",
                         iterations: int = 200, l1: float = 1e-4, noise_std: float = 0.01,
                         seed: int = 0) -> list[dict]:
    """Two-point resolution of a 2D model at field positions (module docstring).

    Parameters
    ----------
    op : SpatialConvolutionOperator or LinearOperator
        2D model that reconstructs (object on the padded grid ``op.shape_in``).
    field_px : array_like, (M, 2)
        Field positions ``(row, col)`` as offsets from the padded grid's centre, px.
    separations_px : array_like
        Separations to test, px (> 0), any order.
    truth_op : LinearOperator, optional
        Model that makes the measurements (default ``op``: the model's own
        resolution, the inverse crime; pass a finer model for mismatch).
    axis : {"x", "y"}
        Direction of the pair.
    iterations, l1 : int, float
        FISTA settings.
    noise_std : float
        Gaussian noise, fraction of the measurement's peak.
    seed : int

    Returns
    -------
    list of dict
        Per position: ``field_px``, ``resolution_px`` (None when even the largest
        separation is not resolved), ``dips`` (separation -> dip).

    Raises
    ------
    ReconInputError
        A 3D model, no positive separations, a bad axis or positions off the grid.
    """
    if len(op.shape_in) != 2:
        raise ReconInputError("two_point_resolution needs a 2D model (one depth)")
    if axis not in ("x", "y"):
        raise ReconInputError(f"axis={axis!r}: use 'x' or 'y'")
    seps = np.sort(np.asarray(separations_px, float).ravel())
    if seps.size == 0 or not np.all(seps > 0):
        raise ReconInputError("give positive separations in pixels, e.g. [1, 2, 3, 4]")
    truth_op = op if truth_op is None else truth_op
    centre = np.array([op.shape_in[0] // 2, op.shape_in[1] // 2], float)
    step = np.array([0.0, 1.0]) if axis == "x" else np.array([1.0, 0.0])
    rng = np.random.default_rng(seed)
    out = []
    for pos in np.asarray(field_px, float).reshape(-1, 2):
        dips = {}
        for s in seps:
            p0 = centre + pos - step * s / 2
            p1 = centre + pos + step * s / 2
            if min(*p0, *p1) < 0 or np.any(np.maximum(p0, p1) + 1 >= op.shape_in):
                raise ReconInputError(f"field position {pos.tolist()} px with separation "
                                      f"{s:g} leaves the object grid {op.shape_in}")
            b = truth_op.forward(_splat(truth_op.shape_in, [p0, p1]))
            b = b + noise_std * float(b.max()) * rng.standard_normal(b.shape)
            x = fista_background(op, (b / np.abs(b).max()).astype(np.float32),
                                 iterations=iterations, l1=l1, estimate_background=False).x
            dips[float(s)] = dip_between(x, p0, p1)
        ok = [dips[float(s)] >= DIP_CRITERION for s in seps]
        res = None
        for i in range(len(seps)):
            if all(ok[i:]):
                res = float(seps[i])
                break
        out.append({"field_px": pos.tolist(), "resolution_px": res, "dips": dips})
    return out

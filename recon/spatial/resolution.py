"""Two-point resolution across the field with a spatially varying model (Sec. 6.4, Fig. 6.4a).

At each field position two point sources ``s`` pixels apart (object grid) are
imaged with the forward model (or a separate "truth" model, e.g. a finer one),
noise is added, and the model reconstructs them with l1 FISTA
(:func:`recon.spatial.fista_background`, no background); they are resolved when
the reconstruction dips by at least 20 % between them
(:func:`recon.analysis.dip_between`, the criterion of Sec. 6.4). The resolution at
a position is the smallest tested separation from which on every larger one is
resolved. :func:`ray_traced_pair` makes the measurements by ray tracing the two
points through a :class:`recon.optics.lensless.LenslessModel` instead (the virtual
twin's optics: no model, no splatting onto the grid).
"""

from __future__ import annotations

import numpy as np

from ..analysis import dip_between
from ..analysis.distinguishability import DIP_CRITERION
from ..errors import ReconInputError
from ..solvers.common import DEFAULT_ITERATIONS
from .background import fista_background

__all__ = ["ray_traced_pair", "two_point_resolution"]


def _splat(shape, points) -> np.ndarray:
    out = np.zeros(shape, np.float32)
    for r, c in points:
        r0, c0 = int(np.floor(r)), int(np.floor(c))
        fr, fc = r - r0, c - c0
        for dr, dc, w in ((0, 0, (1 - fr) * (1 - fc)), (1, 0, fr * (1 - fc)),
                          (0, 1, (1 - fr) * fc), (1, 1, fr * fc)):
            out[r0 + dr, c0 + dc] += w
    return out


def ray_traced_pair(model, z_mm: float, shape_in, *, reference_mm=(0.0, 0.0),
                    oversample: int = 2):
    """Measurements of point pairs by ray tracing, for :func:`two_point_resolution`.

    Object-grid pixel ``(r, c)`` of a model whose grid is centred on the source at
    ``reference_mm`` (a PSF grid's reference node) is the source at ``x = x_ref - (c -
    P1 // 2) p / m``, ``y = y_ref - (r - P0 // 2) p / m`` (Eq. 3.3, ``u = -m x``;
    ``p`` the sensor pitch, ``m = d / z``).

    Parameters
    ----------
    model : recon.optics.lensless.LenslessModel
        The optics (e.g. the virtual bench's ``model``).
    z_mm : float
        Depth of the points, mm.
    shape_in : (P0, P1)
        The reconstructing model's object grid.
    reference_mm : (x, y)
        Source position of the object grid's centre, mm.
    oversample : int
        Ray-tracing grid factor.

    Returns
    -------
    callable
        ``f(points)`` with ``points`` (M, 2) object-grid ``(row, col)`` positions:
        the sensor image (float64, the model's sensor shape) of unit points there.
    """
    geo = model.geometry
    m = geo.d_mm / float(z_mm)
    q = geo.sensor_pitch_um * 1e-3 / m
    p0, p1 = (int(v) for v in shape_in)
    x0, y0 = (float(v) for v in reference_mm)

    def images(points):
        pts = np.asarray(points, float).reshape(-1, 2)
        xyz = np.column_stack([x0 - (pts[:, 1] - p1 // 2) * q, y0 - (pts[:, 0] - p0 // 2) * q,
                               np.full(len(pts), float(z_mm))])
        return model.render_points(xyz, np.ones(len(pts)), oversample)

    return images


def two_point_resolution(op, field_px, separations_px, *, truth_op=None, truth_images=None,
                         axis: str = "x", iterations: int = DEFAULT_ITERATIONS, l1: float = 1e-4,
                         noise_std: float = 0.01, seed: int = 0) -> list[dict]:
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
    truth_images : callable, optional
        ``f(points)`` -> sensor image of unit points at object-grid ``(row, col)``
        positions (e.g. :func:`ray_traced_pair`); takes precedence over ``truth_op``.
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
            if truth_images is not None:
                b = np.asarray(truth_images(np.stack([p0, p1])), np.float64)
                if b.shape != tuple(op.shape_out):
                    raise ReconInputError(f"truth_images gave a {b.shape} image; the model's "
                                          f"sensor is {tuple(op.shape_out)}")
            else:
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

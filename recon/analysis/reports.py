"""The numbers of ``diffuserlab analyze``, callable from a notebook (Kuo 2020).

Each function takes a PSF stack sorted by depth (:func:`prepare_stack`) or one PSF
and returns JSON-ready numbers plus warnings; ``diffuserlab analyze`` adds the
plots, the files and the terminal summary:

* :func:`resolution_per_depth` -- per depth, the 70 % autocorrelation half width
  (Sec. 3.2) in sensor pixels, object space (m = d/z) and degrees, the 0.8
  inner-product shift and scale (Sec. 6.4, Fig. 6.4), the hyperfocal distance and
  the depth of field;
* :func:`lateral_condition` / :func:`axial_condition` -- Fig. 4.5: local condition
  number of k neighbouring point sources side by side or across depth planes;
* :func:`distinguishability` -- Sec. 4.4 / Fig. 4.3-4.4: two-point and 16-point
  limits by reconstruction (20 % dip);
* :func:`field_of_view` -- the angular field of view of Eq. 3.12 / Eq. 4.6 per depth,
  from the sensor's angular cutoff, the diffuser's deflection, the sensor width and
  the PSF width (:func:`support_width_px`).

PSF similarity (App. A.2) is :func:`recon.analysis.stack_similarity` and the grid
recommendation :func:`recon.analysis.recommend_grid`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import ReconInputError
from ..validate import as_array, as_int, finite_float, float_array, positive
from ..volume.operator import bin_stack
from .angular import fov_half_angle_deg
from .conditioning import axial_layout, condition_vs_k, condition_vs_k_axial
from .distinguishability import distinguishability_limit
from .psf import remove_background_dct
from .resolution import (
    axial_inner_product_scale,
    depth_of_field_mm,
    hyperfocal_distance_mm,
    lateral_inner_product_resolution_px,
    lateral_resolution_deg,
    lateral_resolution_object_mm,
    lateral_resolution_px,
)

__all__ = ["axial_condition", "check_stack", "distinguishability", "energy_kept",
           "field_of_view", "lateral_condition", "prepare_stack", "resolution_per_depth",
           "support_width_px"]


def check_stack(stack, depths_mm) -> tuple[np.ndarray, np.ndarray]:
    """A PSF stack and its depths as the report functions take them.

    Parameters
    ----------
    stack : array_like, (n_z, rows, cols)
        Real, finite, non-empty.
    depths_mm : sequence of float, length n_z
        Finite, mm.

    Returns
    -------
    stack : ndarray
        The input as an array (its own dtype).
    depths : ndarray, float64, (n_z,)

    Raises
    ------
    ReconInputError
        Not a real finite 3D stack, or not one finite depth per plane.
    """
    arr = as_array(stack, "PSF stack")
    if arr.dtype.kind not in "biuf" or arr.ndim != 3 or arr.size == 0:
        raise ReconInputError(f"the PSF stack must be a non-empty real (n_z, rows, cols) "
                              f"array, got dtype {arr.dtype} and shape {arr.shape}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise ReconInputError("the PSF stack contains NaN or inf; repair or recapture it")
    z = float_array(depths_mm, "depths", ndims=(1,))
    if len(z) != arr.shape[0]:
        raise ReconInputError(f"{len(z)} depths for a PSF stack of {arr.shape[0]} planes "
                              f"(shape {arr.shape}); give one depth per plane")
    return arr, z


def _fraction(value, name: str) -> float:
    """A fraction in (0, 1], or ReconInputError naming ``name``."""
    return finite_float(value, name, lo=0.0, hi=1.0, lo_open=True)


def prepare_stack(stack: np.ndarray, depths_mm, *, bin_factor: int,
                  remove_background: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A PSF stack sorted by depth, binned and with its background removed if asked.

    Parameters
    ----------
    stack : ndarray, shape (n_z, rows, cols)
        One PSF per depth, any order.
    depths_mm : sequence of float, length n_z
        Depth of every plane, mm.
    bin_factor : int
        Lateral box binning of every plane (1: none); the pixel pitch of the result
        is ``bin_factor`` times the input's.
    remove_background : int
        N > 0: zero the N x N lowest DCT coefficients of each plane (Sec. 6.2,
        :func:`recon.analysis.remove_background_dct`); 0: off.

    Returns
    -------
    stack : ndarray, (n_z, rows / bin, cols / bin)
        float32 after background removal, else the input dtype (binned: float32).
    depths : ndarray, float64, (n_z,)
        Ascending.

    Raises
    ------
    ReconInputError
        See :func:`check_stack`; ``bin_factor`` not an integer >= 1,
        ``remove_background`` not an integer >= 0.
    """
    stack, z = check_stack(stack, depths_mm)
    bin_factor = as_int(bin_factor, "--bin", 1)
    remove_background = as_int(remove_background, "--remove-background", 0)
    order = np.argsort(z, kind="stable")
    stack, z = stack[order], z[order]
    if bin_factor != 1:
        stack = bin_stack(stack, bin_factor)
    if remove_background:
        stack = remove_background_dct(stack, remove_background).astype(np.float32)
    return stack, z


def _try(warnings: list[str], what: str, func, *a, **kw):
    """``func(*a, **kw)``, or None with a warning when the analysis refuses the PSF."""
    try:
        return func(*a, **kw)
    except ReconInputError as exc:
        warnings.append(f"{what}: {exc}")
        return None


def _xy(res) -> dict | None:
    """``{"x": ..., "y": ...}`` of a :class:`recon.analysis.LateralResolution` (or None)."""
    return None if res is None else {"x": res.x_px, "y": res.y_px}


def resolution_per_depth(stack: np.ndarray, z: np.ndarray, *, pitch_mm: float, d_mm: float,
                         level: float = 0.7, threshold: float = 0.8
                         ) -> tuple[list[dict], list[str]]:
    """Lateral and axial resolution of every PSF of a stack (Sec. 3.2, Sec. 6.4).

    Parameters
    ----------
    stack : ndarray, (n_z, rows, cols)
        Background-removed PSFs sorted by depth.
    z : ndarray, (n_z,)
        Depths, mm.
    pitch_mm : float
        Sensor pixel pitch of the stack, mm.
    d_mm : float
        Diffuser-to-sensor distance, mm (magnification m = d/z).
    level : float
        Autocorrelation level of the half width (0.7, Sec. 3.2).
    threshold : float
        Inner-product threshold of distinguishability (0.8, Sec. 6.4).

    Returns
    -------
    rows : list of dict
        Per depth: ``depth_mm``, ``magnification``,
        ``autocorrelation_half_width_px`` / ``_object_mm`` (x, y) / ``_deg``,
        ``inner_product_shift_px`` / ``_object_mm``, ``inner_product_scale``,
        ``hyperfocal_distance_mm``, ``depth_of_field_far_mm`` / ``_near_mm``
        (None where the analysis refused the PSF).
    warnings : list of str
        Why a value is None.

    Raises
    ------
    ReconInputError
        See :func:`check_stack`; ``pitch_mm`` or ``d_mm`` not a positive number,
        ``level`` or ``threshold`` not in (0, 1].
    """
    stack, z = check_stack(stack, z)
    pitch_mm, d_mm = positive(pitch_mm, "pitch_mm"), positive(d_mm, "--d-mm")
    level, threshold = _fraction(level, "--level"), _fraction(threshold, "--threshold")
    warnings: list[str] = []
    rows = []
    for k, zk in enumerate(z):
        h, tag = stack[k], f"z = {zk:g} mm"
        r70 = _try(warnings, f"{tag}, 70 % half width", lateral_resolution_px, h, level)
        rip = _try(warnings, f"{tag}, inner-product shift", lateral_inner_product_resolution_px,
                   h, threshold)
        s_star = _try(warnings, f"{tag}, inner-product scale", axial_inner_product_scale, h,
                      threshold)
        hyper = _try(warnings, f"{tag}, hyperfocal distance", hyperfocal_distance_mm, h,
                     d_mm=d_mm, psf_z_mm=float(zk), threshold=threshold)
        far = near = None
        if hyper is not None:
            far = float(depth_of_field_mm(h, zk, d_mm=d_mm, psf_z_mm=float(zk),
                                          threshold=threshold)[0])
            near = float(depth_of_field_mm(h, zk, d_mm=d_mm, psf_z_mm=float(zk),
                                           threshold=threshold, side="near")[0])

        def obj(res, zk=zk):
            return None if res is None else {
                "x": lateral_resolution_object_mm(res.x_px, pitch_mm, d_mm, zk),
                "y": lateral_resolution_object_mm(res.y_px, pitch_mm, d_mm, zk)}

        rows.append({
            "depth_mm": float(zk),
            "magnification": d_mm / float(zk),
            "autocorrelation_half_width_px": _xy(r70),
            "autocorrelation_half_width_object_mm": obj(r70),
            "autocorrelation_half_width_deg": None if r70 is None else
            lateral_resolution_deg(min(r70), pitch_mm, d_mm),
            "inner_product_shift_px": _xy(rip),
            "inner_product_shift_object_mm": obj(rip),
            "inner_product_scale": s_star,
            "hyperfocal_distance_mm": hyper,
            "depth_of_field_far_mm": far,
            "depth_of_field_near_mm": near,
        })
    return rows, warnings


def energy_kept(h: np.ndarray, k_max: int, sep: float, layout: str, axis: str) -> float:
    """Fraction of the PSF energy inside the frame for the outermost of `k_max` sources.

    The sources sit where :func:`recon.analysis.condition_vs_k` puts them (centred
    on the PSF's position, line or raster grid); a shifted PSF loses what leaves
    the frame, which makes the large-k condition numbers pessimistic.

    Parameters
    ----------
    h : ndarray, (rows, cols)
    k_max : int
        Number of sources.
    sep : float
        Separation, px.
    layout : {"line", "grid"}
    axis : {"x", "y"}
        Direction of a line.

    Returns
    -------
    float
        Sum of h^2 inside the frame after the outermost shift over the total.

    Raises
    ------
    ReconInputError
        ``h`` not a real finite 2D image, ``k_max`` not an integer >= 1, ``sep`` not a
        finite number >= 0.
    """
    h = float_array(h, "PSF")
    k_max = as_int(k_max, "--k-max", 1)
    sep = finite_float(sep, "separation", lo=0.0)
    if layout == "line":
        reach = ((k_max - 1) - (k_max - 1) // 2) * sep
        shift = (0.0, reach) if axis == "x" else (reach, 0.0)
    else:
        width = math.ceil(math.sqrt(k_max))
        height = math.ceil(k_max / width)
        shift = (((height - 1) - (height - 1) // 2) * sep, ((width - 1) - (width - 1) // 2) * sep)
    dy, dx = (min(int(round(v)), n) for v, n in zip(shift, h.shape, strict=True))
    e = np.square(h, dtype=np.float64)
    return float(e[: h.shape[0] - dy, : h.shape[1] - dx].sum() / e.sum())


def lateral_condition(psf: np.ndarray, separations_px, k_max: int, *, layout: str = "line",
                      axis: str = "x") -> tuple[list[int], list[np.ndarray], list[str]]:
    """Fig. 4.5: local condition number of k = 2 .. k_max sources side by side.

    Parameters
    ----------
    psf : ndarray, (rows, cols)
    separations_px : sequence of float
        Source separations on the sensor, px.
    k_max : int
        Largest number of sources (>= 2).
    layout : {"line", "grid"}
    axis : {"x", "y"}

    Returns
    -------
    ks : list of int
    condition_numbers : list of ndarray
        One array over ``ks`` per separation
        (:func:`recon.analysis.condition_vs_k`).
    warnings : list of str
        Separations where the outermost source keeps less than 90 % of the PSF
        energy inside the frame (:func:`energy_kept`).

    Raises
    ------
    ReconInputError
        ``k_max`` not an integer >= 2, separations not finite numbers > 0, or a PSF
        that is not a real finite 2D image.
    """
    k_max = as_int(k_max, "--k-max", 2)
    separations_px = _separations(separations_px, "--separations-px")
    ks = list(range(2, k_max + 1))
    cond = [condition_vs_k(psf, s, ks, layout=layout, axis=axis) for s in separations_px]
    warnings = []
    for s in separations_px:
        kept = energy_kept(psf, k_max, s, layout, axis)
        if kept < 0.9:
            warnings.append(
                f"at {s:g} px the outermost of {k_max} sources keeps {kept:.0%} of the PSF "
                "energy inside the frame: its large-k condition numbers are pessimistic; use "
                "a smaller --k-max or separation, or a larger frame")
    return ks, cond, warnings


def _separations(values, name: str) -> list[float]:
    """Separations as a list of finite numbers > 0, or ReconInputError naming ``name``."""
    seps = float_array(values, name, ndims=(0, 1)).ravel()
    if np.any(seps <= 0):
        raise ReconInputError(f"{name} must be > 0, got {seps.tolist()}")
    return [float(v) for v in seps]


def axial_condition(stack: np.ndarray, z: np.ndarray, steps, k_max: int, *,
                    xz_px: float = 0.0, axis: str = "x", start_plane: int | None = None
                    ) -> tuple[list[dict], list[str]]:
    """Fig. 4.5 across depth: sources at consecutive depth planes (or an x-z grid).

    Parameters
    ----------
    stack : ndarray, (n_z, rows, cols)
        PSFs sorted by depth.
    z : ndarray, (n_z,)
        Depths, mm.
    steps : sequence of int
        Plane steps between neighbouring sources (>= 1).
    k_max : int
        Largest number of sources; fewer where the stack has too few planes.
    xz_px : float
        Lateral spacing (px, along ``axis``) of an x-z grid of sources (Fig. 4.4);
        0: one line along z.
    axis : {"x", "y"}
    start_plane : int, optional
        Plane of the first source (default: centred in the stack).

    Returns
    -------
    per_step : list of dict
        Per step: ``separation_planes``, ``ks``, ``condition_numbers``,
        ``source_depths_mm``, ``separation_inverse_mm`` (mean 1/z step between the
        planes used), ``two_point`` and ``limit``.
    warnings : list of str
        Steps with fewer sources than ``k_max`` or none.

    Raises
    ------
    ReconInputError
        See :func:`check_stack`; a step not an integer >= 1, ``k_max`` not an integer
        >= 2, ``xz_px`` not a finite number >= 0; no step fits two sources in the stack.
    """
    stack, z = check_stack(stack, z)
    k_max = as_int(k_max, "--k-max", 2)
    xz_px = finite_float(xz_px, "--xz-px", lo=0.0)
    planes = float_array(steps, "--separations-planes", ndims=(0, 1)).ravel()
    if np.any(planes < 1) or np.any(planes != np.round(planes)):
        raise ReconInputError(f"--separations-planes must be whole numbers >= 1, got "
                              f"{planes.tolist()}")
    steps = [int(v) for v in planes]
    n_z = len(z)
    per_step, warnings = [], []
    for s in steps:
        k_top, planes = k_max, None
        while k_top >= 2 and planes is None:  # the most sources that fit in the stack
            try:
                planes = axial_layout(n_z, k_top, s, separation_px=xz_px, axis=axis,
                                      start_plane=start_plane)[:, 0].astype(int)
            except ReconInputError:
                k_top -= 1
        if planes is None:
            warnings.append(f"{s} plane(s) apart: fewer than 2 sources fit in {n_z} planes")
            continue
        if k_top < k_max:
            warnings.append(f"{s} plane(s) apart: only {k_top} of {k_max} sources fit "
                            f"in the stack's {n_z} planes")
        ks = list(range(2, k_top + 1))
        cond = condition_vs_k_axial(stack, s, ks, separation_px=xz_px, axis=axis,
                                    start_plane=start_plane)
        used = np.unique(planes)
        per_step.append({"separation_planes": s, "ks": ks, "condition_numbers": cond,
                         "source_depths_mm": z[used],
                         "separation_inverse_mm": float(np.mean(np.abs(np.diff(1.0 / z[used]))))
                         if used.size > 1 else None,
                         "two_point": float(cond[0]), "limit": float(cond[-1])})
    if not per_step:
        raise ReconInputError(f"no separation fits two sources in the stack's {n_z} planes")
    return per_step, warnings


def distinguishability(psf: np.ndarray, separations_px, *, axis: str = "x",
                       iterations: int = 300) -> dict[int, tuple[float | None, list[Any]]]:
    """Sec. 4.4: two-point and 16-point (4 x 4) limits by reconstruction (20 % dip).

    Parameters
    ----------
    psf : ndarray, (rows, cols)
        Negative values are clipped to 0.
    separations_px : sequence of float
    axis : {"x", "y"}
    iterations : int
        FISTA iterations, regulariser off.

    Returns
    -------
    dict
        ``{2: (limit_px or None, results), 16: (...)}`` from
        :func:`recon.analysis.distinguishability_limit`.

    Raises
    ------
    ReconInputError
        A PSF that is not a real finite 2D image, separations not finite numbers > 0,
        ``iterations`` not an integer >= 1.
    """
    psf = np.clip(float_array(psf, "PSF"), 0.0, None)
    separations_px = _separations(separations_px, "--separations-px")
    iterations = as_int(iterations, "--iterations", 1)
    return {n: distinguishability_limit(psf, separations_px, n_points=n, axis=axis,
                                        iterations=iterations) for n in (2, 16)}


def support_width_px(h: np.ndarray, axis: int, energy: float) -> float:
    """Extent (px) of the central `energy` fraction of the PSF's marginal along `axis`.

    Parameters
    ----------
    h : ndarray, (rows, cols)
        Negative values count as 0.
    axis : int
        The axis summed over (0: the width along x, 1: along y).
    energy : float
        Central fraction, (0, 1].

    Returns
    -------
    float
        Width in pixels (>= 1).

    Raises
    ------
    ReconInputError
        ``h`` not a real finite 2D image without positive values, ``axis`` not 0 or 1,
        ``energy`` not in (0, 1].
    """
    h = float_array(h, "PSF")
    energy = _fraction(energy, "--support-energy")
    if axis not in (0, 1) or isinstance(axis, bool):
        raise ReconInputError(f"axis must be 0 or 1, got {axis!r}")
    if not np.any(h > 0):
        raise ReconInputError("the PSF has no positive values; its support has no width")
    marginal = np.clip(h, 0, None).sum(axis=axis, dtype=np.float64)
    cum = np.cumsum(marginal) / marginal.sum()
    tail = (1.0 - energy) / 2.0
    lo = int(np.searchsorted(cum, tail))
    hi = int(np.searchsorted(cum, 1.0 - tail))
    return float(hi - lo + 1)


def field_of_view(stack: np.ndarray, z: np.ndarray, *, pitch_mm: float, d_mm: float,
                  alpha_c_deg: float, beta_deg: float = 0.0,
                  support_energy: float = 0.99) -> dict:
    """The angular field of view (Eq. 3.12 / Eq. 4.6) at every depth of a stack.

    Parameters
    ----------
    stack : ndarray, (n_z, rows, cols)
        PSFs sorted by depth; the sensor width is the plane shape times the pitch.
    z : ndarray, (n_z,)
        Depths, mm.
    pitch_mm, d_mm : float
        Pixel pitch and diffuser-to-sensor distance, mm.
    alpha_c_deg : float
        Sensor angular cutoff (response at 20 % of normal incidence), deg.
    beta_deg : float
        Maximum deflection angle of the diffuser, deg.
    support_energy : float
        PSF width = extent holding this central fraction of its energy along each
        axis (:func:`support_width_px`).

    Returns
    -------
    dict
        ``sensor_width_mm`` (x, y), ``per_depth`` (``depth_mm``, ``psf_width_mm``,
        ``geometric_half_angle_deg``, ``fov_half_angle_deg``, ``limited_by``,
        ``field_width_mm``), ``fov_half_angle_deg`` (the smallest over depth) and
        ``fov_full_angle_deg``.

    Raises
    ------
    ReconInputError
        See :func:`check_stack`; ``pitch_mm`` or ``d_mm`` not a positive number,
        ``alpha_c_deg`` not in (0, 90], ``beta_deg`` not in [0, 90)
        (:func:`recon.analysis.fov_half_angle_deg`), ``support_energy`` outside (0, 1],
        or a plane without positive values.
    """
    stack, z = check_stack(stack, z)
    support_energy = _fraction(support_energy, "--support-energy")
    pitch_mm, d_mm = positive(pitch_mm, "pitch_mm"), positive(d_mm, "--d-mm")
    n, rows, cols = stack.shape
    sensor = {"x": cols * pitch_mm, "y": rows * pitch_mm}
    per = []
    for k in range(n):
        if not np.any(stack[k] > 0):
            raise ReconInputError(f"plane {k} (z = {z[k]:g} mm) has no positive values")
        width = {"x": support_width_px(stack[k], 0, support_energy) * pitch_mm,
                 "y": support_width_px(stack[k], 1, support_energy) * pitch_mm}
        fov, geo = {}, {}
        for a in ("x", "y"):
            fov[a] = fov_half_angle_deg(alpha_c_deg, beta_deg=beta_deg,
                                        sensor_width_mm=sensor[a], psf_width_mm=width[a],
                                        d_mm=d_mm)
            geo[a] = math.degrees(math.atan((sensor[a] + width[a]) / (2 * d_mm)))
        per.append({"depth_mm": float(z[k]), "psf_width_mm": width,
                    "geometric_half_angle_deg": geo, "fov_half_angle_deg": fov,
                    "limited_by": {a: "sensor angular cutoff" if alpha_c_deg < geo[a]
                                   else "geometry" for a in ("x", "y")},
                    "field_width_mm": {a: 2 * float(z[k]) * math.tan(math.radians(fov[a]))
                                       for a in ("x", "y")}})
    headline = {a: min(p["fov_half_angle_deg"][a] for p in per) for a in ("x", "y")}
    return {"sensor_width_mm": sensor, "per_depth": per, "fov_half_angle_deg": headline,
            "fov_full_angle_deg": {a: 2 * v for a, v in headline.items()}}

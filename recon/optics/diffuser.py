"""Diffuser surfaces for ray-traced lensless PSFs (Kuo 2020, Sec. 4.3, App. A.2, Sec. 6.3).

A diffuser is a thin transparent plate with a flat input face (towards the scene)
and a textured output face (towards the sensor) of height ``h(x, y)``; glass lies
on the source side of the surface (``Z < h``), so a local maximum of ``h`` (a convex
bump) is a converging lenslet. Two kinds are provided:

* :meth:`DiffuserSurface.smooth_random`: the off-the-shelf smooth diffuser of
  DiffuserCam (Luminit 0.5 deg): Gaussian low-pass-filtered white noise, feature size
  ~140 um, Gaussian-distributed slope with mean magnitude 0.7 deg, polycarbonate
  ``n = 1.58``; the deflection of a normally incident ray is at most ~0.5 deg
  (App. A.2).
* :meth:`DiffuserSurface.random_microlens`: the random microlens diffuser of
  Sec. 6.3: randomly placed spherical lenslets (~250 um, focal length ~1.5 mm).
* :meth:`DiffuserSurface.regular_microlens`: the same lenslets on a square lattice
  (the regular microlens array Sec. 6.3 compares against).

Coordinates. Sample ``(i, j)`` of ``height_um`` sits at lateral position
``x = (j - (cols - 1) / 2) * pitch_um``, ``y = (i - (rows - 1) / 2) * pitch_um`` (um):
the surface is centred on the optical axis, ``x`` runs along columns and ``y``
along rows (increasing index), the same convention as the sensor in
:mod:`recon.optics.lensless`.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..errors import ReconInputError
from ..validate import as_int

__all__ = ["DiffuserSurface"]


def _size_wh_mm(size_mm) -> tuple[float, float]:
    """``size_mm`` as (width_mm, height_mm): a scalar means a square."""
    if isinstance(size_mm, numbers.Real) and not isinstance(size_mm, bool):
        w = h = float(size_mm)
    else:
        try:
            w, h = (float(v) for v in size_mm)
        except (TypeError, ValueError) as exc:
            raise ReconInputError(
                f"diffuser size {size_mm!r} must be a number (square, mm) or "
                "(width_mm, height_mm)"
            ) from exc
    if not (math.isfinite(w) and math.isfinite(h) and w > 0 and h > 0):
        raise ReconInputError(
            f"diffuser size ({w}, {h}) mm must be finite and positive; e.g. 4.0 or (4.5, 3.5)"
        )
    return w, h


def finite_positive(value, name: str, example: str) -> float:
    """``value`` as a finite positive float.

    Raises
    ------
    ReconInputError
        Not a number, not finite or not positive; the message names ``name`` and
        gives ``example`` of a good value.
    """
    try:
        if isinstance(value, str | bytes):
            raise TypeError(value)
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ReconInputError(f"{name} must be a number, got {value!r}; e.g. {example}") from exc
    if not (math.isfinite(v) and v > 0):
        raise ReconInputError(f"{name} must be finite and positive, got {value!r}; e.g. {example}")
    return v


def _index(n) -> float:
    n = finite_positive(n, "refractive index", "1.58 (polycarbonate) or 1.5")
    if n <= 1.0:
        raise ReconInputError(
            f"refractive index {n} must exceed 1 (a glass or polymer in air); e.g. 1.58"
        )
    return n


def _lenslet_parameters(size_mm, pitch_um, lenslet_um, focal_mm, refractive_index):
    """Checked (width_mm, height_mm, pitch_um, lenslet_um, cap radius_um, n) of a
    microlens surface: the cap radius is ``R = f (n - 1)`` (plano-convex thin lens)."""
    w_mm, h_mm = _size_wh_mm(size_mm)
    pitch = finite_positive(pitch_um, "pitch_um", "2.5")
    lens = finite_positive(lenslet_um, "lenslet_um", "250.0")
    f_um = finite_positive(focal_mm, "focal_mm", "1.5") * 1e3
    n = _index(refractive_index)
    if pitch > lens / 8:
        raise ReconInputError(
            f"pitch {pitch} um cannot resolve lenslets of {lens} um; use at most "
            f"lenslet_um / 8 = {lens / 8:g} um (lenslet_um / 20 recommended)"
        )
    return w_mm, h_mm, pitch, lens, f_um * (n - 1.0), n


def _grid_shape(width_um: float, height_um: float, pitch_um: float) -> tuple[int, int]:
    """Samples so that the grid's extent ``(n - 1) * pitch`` covers the size."""
    rows = int(math.ceil(height_um / pitch_um - 1e-9)) + 1
    cols = int(math.ceil(width_um / pitch_um - 1e-9)) + 1
    if rows * cols > 64_000_000:
        raise ReconInputError(
            f"diffuser grid of {rows} x {cols} samples is too large; use a coarser pitch "
            "or a smaller size"
        )
    return rows, cols


def _poisson_disc(width: float, height: float, r_min: float, rng: np.random.Generator,
                  k: int = 30) -> np.ndarray:
    """Bridson's maximal Poisson-disc sampling of the rectangle [0, w] x [0, h].

    Every pair of points is at least ``r_min`` apart and (maximality) every point of
    the rectangle lies within ``2 r_min`` of a sample. Returns (N, 2) float64 (x, y).
    """
    cell = r_min / math.sqrt(2.0)
    gw, gh = int(math.ceil(width / cell)), int(math.ceil(height / cell))
    grid = -np.ones((gh, gw), np.int64)
    pts: list[tuple[float, float]] = []

    def add(p):
        pts.append(p)
        grid[int(p[1] / cell), int(p[0] / cell)] = len(pts) - 1

    add((rng.uniform(0, width), rng.uniform(0, height)))
    active = [0]
    r2 = r_min * r_min
    while active:
        a = int(rng.integers(len(active)))
        px, py = pts[active[a]]
        rad = r_min * np.sqrt(rng.uniform(1.0, 4.0, k))  # uniform in the annulus area
        ang = rng.uniform(0.0, 2.0 * math.pi, k)
        found = False
        for cx, cy in zip(px + rad * np.cos(ang), py + rad * np.sin(ang), strict=True):
            if not (0.0 <= cx < width and 0.0 <= cy < height):
                continue
            gi, gj = int(cy / cell), int(cx / cell)
            ok = True
            for ii in range(max(gi - 2, 0), min(gi + 3, gh)):
                for jj in range(max(gj - 2, 0), min(gj + 3, gw)):
                    q = grid[ii, jj]
                    if q >= 0:
                        qx, qy = pts[q]
                        if (qx - cx) ** 2 + (qy - cy) ** 2 < r2:
                            ok = False
                            break
                if not ok:
                    break
            if ok:
                add((float(cx), float(cy)))
                active.append(len(pts) - 1)
                found = True
                break
        if not found:
            active[a] = active[-1]
            active.pop()
    return np.asarray(pts, np.float64)


@dataclass(frozen=True, eq=False)
class DiffuserSurface:
    """Height map of a thin diffuser's textured (output) face.

    Parameters
    ----------
    height_um : ndarray, float64, shape (rows, cols)
        Surface height in um on a square grid of spacing ``pitch_um``, centred on
        the optical axis (see the module docstring for coordinates). Positive height
        means thicker material (glass on the source side), so bumps converge light.
    pitch_um : float
        Grid spacing in um (> 0).
    refractive_index : float
        Index of the diffuser material (> 1); the surrounding medium is air (1).
    centres_um : ndarray, float64, shape (N, 2), optional
        For microlens diffusers, the lenslet centres (x, y) in um in the same
        coordinates; None otherwise.

    Raises
    ------
    ReconInputError
        Non-2D, too small (< 2 x 2) or non-finite heights, non-positive pitch, index <= 1.
    """

    height_um: np.ndarray
    pitch_um: float
    refractive_index: float
    centres_um: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        h = np.ascontiguousarray(self.height_um, dtype=np.float64)
        if h.ndim != 2 or min(h.shape) < 2:
            raise ReconInputError(
                f"diffuser height map must be 2D with at least 2 x 2 samples, got shape "
                f"{h.shape}"
            )
        if not np.all(np.isfinite(h)):
            raise ReconInputError("diffuser height map contains NaN or inf")
        h.setflags(write=False)
        object.__setattr__(self, "height_um", h)
        object.__setattr__(self, "pitch_um", finite_positive(self.pitch_um, "pitch_um", "5.0"))
        object.__setattr__(self, "refractive_index", _index(self.refractive_index))

    # ------------------------------------------------------------------ geometry
    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the height map."""
        return self.height_um.shape

    @property
    def extent_mm(self) -> tuple[float, float]:
        """(width_mm, height_mm) spanned by the sample centres, ``(n - 1) * pitch``."""
        rows, cols = self.shape
        return (cols - 1) * self.pitch_um * 1e-3, (rows - 1) * self.pitch_um * 1e-3

    # ------------------------------------------------------------------ derived maps
    def slopes(self) -> np.ndarray:
        """Surface gradient ``(dh/dx, dh/dy)`` (dimensionless, um per um).

        Central differences inside, one-sided at the edges (:func:`numpy.gradient`).

        Returns
        -------
        ndarray, float64, shape (2, rows, cols)
            ``[0]`` = dh/dx (along columns), ``[1]`` = dh/dy (along rows). Read-only
            (cached).
        """
        return self._slopes

    @cached_property
    def _slopes(self) -> np.ndarray:
        gy, gx = np.gradient(self.height_um, self.pitch_um)
        g = np.stack([gx, gy])
        g.setflags(write=False)
        return g

    def deflection_rad(self) -> np.ndarray:
        """Deflection of a normally incident ray, thin-prism approximation.

        ``delta = (n - 1) * grad h`` (rad), pointing up the slope: rays bend towards
        the thicker side, so bumps converge (the ray tracer uses exact vector
        Snell refraction instead; they agree to first order in the slope).

        Returns
        -------
        ndarray, float64, shape (2, rows, cols)
            ``[0]`` along x (columns), ``[1]`` along y (rows), radians.
        """
        return (self.refractive_index - 1.0) * self._slopes

    def mean_slope_deg(self) -> float:
        """Mean surface-slope angle ``mean(arctan |grad h|)`` in degrees."""
        g = self._slopes
        return float(np.degrees(np.mean(np.arctan(np.hypot(g[0], g[1])))))

    def max_deflection_deg(self, region_mm: tuple[float, float] | None = None) -> float:
        """Largest thin-prism deflection ``(n - 1) max |grad h|`` in degrees.

        Parameters
        ----------
        region_mm : (width_mm, height_mm), optional
            Only samples inside this centred rectangle (e.g. the aperture) count;
            default the whole surface.
        """
        g = np.hypot(*self._slopes)
        if region_mm is not None:
            x, y = self.coordinates_mm()
            inside = (np.abs(x)[None, :] <= region_mm[0] / 2 + 1e-12) & (
                np.abs(y)[:, None] <= region_mm[1] / 2 + 1e-12)
            g = g[inside] if np.any(inside) else g
        return float(np.degrees((self.refractive_index - 1.0) * np.max(g)))

    def coordinates_mm(self) -> tuple[np.ndarray, np.ndarray]:
        """Sample positions ``(x, y)`` in mm: x (cols,), y (rows,), both float64."""
        rows, cols = self.shape
        p = self.pitch_um * 1e-3
        return (np.arange(cols) - (cols - 1) / 2) * p, (np.arange(rows) - (rows - 1) / 2) * p

    # ------------------------------------------------------------------ constructors
    @classmethod
    def smooth_random(cls, size_mm, pitch_um: float = 5.0, feature_um: float = 140.0,
                      slope_deg: float = 0.7, refractive_index: float = 1.58,
                      seed: int = 0) -> DiffuserSurface:
        """Smooth random diffuser: Gaussian-filtered white noise (Kuo 2020, Sec. 4.3).

        White Gaussian noise is low-pass filtered with a Gaussian kernel of standard
        deviation ``feature_um / 2`` (exactly, in the Fourier domain, on a grid padded
        by ``3 * feature_um`` so the periodic filter leaves no seam), which gives a
        stationary Gaussian height field with autocorrelation

            C(r) = sigma_h^2 exp(-r^2 / feature_um^2),

        i.e. ``feature_um`` is the correlation length at which the height
        autocorrelation falls to 1/e. The heights are then scaled so that the
        mean surface-slope angle ``mean(arctan |grad h|)`` on the sampled grid equals
        ``slope_deg`` (A.2: slope Gaussian-distributed with mean magnitude 0.7 deg;
        the maximum deflection ``(n - 1) |grad h|`` is then ~0.5 deg for the defaults).

        Parameters
        ----------
        size_mm : float or (width_mm, height_mm)
            Lateral size to cover (the grid's extent is at least this).
        pitch_um : float
            Grid spacing in um; keep it <= feature_um / 10 so slopes are resolved.
        feature_um : float
            Correlation length (1/e of the height autocorrelation), um.
        slope_deg : float
            Mean surface-slope magnitude, degrees (0 < slope_deg < 45).
        refractive_index : float
            1.58 (polycarbonate) by default.
        seed : int
            Seed of :func:`numpy.random.default_rng` (>= 0); same seed, same surface.

        Returns
        -------
        DiffuserSurface
            Heights (um) with zero minimum.
        """
        from scipy.optimize import brentq

        w_mm, h_mm = _size_wh_mm(size_mm)
        pitch = finite_positive(pitch_um, "pitch_um", "5.0")
        feat = finite_positive(feature_um, "feature_um", "140.0")
        slope = finite_positive(slope_deg, "slope_deg", "0.7")
        if slope >= 45.0:
            raise ReconInputError(f"slope_deg {slope} must be below 45 deg; e.g. 0.7")
        if pitch > feat / 4:
            raise ReconInputError(
                f"pitch {pitch} um cannot resolve features of {feat} um; use a pitch of at "
                f"most feature_um / 4 = {feat / 4:g} um (feature_um / 10 recommended)"
            )
        rows, cols = _grid_shape(w_mm * 1e3, h_mm * 1e3, pitch)
        pad = int(math.ceil(3 * feat / pitch))
        rng = np.random.default_rng(as_int(seed, "seed", 0))
        noise = rng.standard_normal((rows + 2 * pad, cols + 2 * pad))
        s = feat / 2.0 / pitch  # kernel standard deviation in samples
        fy = np.fft.fftfreq(noise.shape[0])[:, None]
        fx = np.fft.rfftfreq(noise.shape[1])[None, :]
        gain = np.exp(-2.0 * (math.pi * s) ** 2 * (fx * fx + fy * fy))
        raw = np.fft.irfft2(np.fft.rfft2(noise) * gain, noise.shape)[pad:pad + rows,
                                                                     pad:pad + cols]
        gy, gx = np.gradient(raw, pitch)
        mag = np.hypot(gx, gy)
        target = math.radians(slope)
        a0 = math.tan(target) / float(np.mean(mag))
        scale = brentq(lambda a: float(np.mean(np.arctan(a * mag))) - target,
                       0.1 * a0, 10.0 * a0, xtol=1e-14 * a0, rtol=1e-13)
        height = scale * raw
        height -= height.min()
        return cls(height, pitch, refractive_index)

    @classmethod
    def random_microlens(cls, size_mm, pitch_um: float, lenslet_um: float = 250.0,
                         focal_mm: float = 1.5, refractive_index: float = 1.5,
                         seed: int = 0) -> DiffuserSurface:
        """Random microlens diffuser (Kuo 2020, Sec. 6.3).

        Lenslet centres are a maximal Poisson-disc (Bridson) sample, rescaled so
        that the mean nearest-neighbour distance of the centres is ``lenslet_um``.
        Each lenslet is a spherical cap of radius ``R = focal_mm (n - 1)``
        (plano-convex thin-lens maker's equation, ``1/f = (n - 1)/R``) with its apex
        at a common height; the surface is the union (pointwise maximum) of the
        caps, so each lenslet fills the Voronoi cell of its centre:

            h(p) = max_k sqrt(R^2 - |p - c_k|^2) - R  (+ a constant, min h = 0).

        Parameters
        ----------
        size_mm : float or (width_mm, height_mm)
            Lateral size to cover.
        pitch_um : float
            Grid spacing in um; <= lenslet_um / 20 recommended (2-3 um).
        lenslet_um : float
            Mean nearest-neighbour spacing of the lenslet centres, um.
        focal_mm : float
            Focal length of every lenslet, mm.
        refractive_index : float
            1.5 by default.
        seed : int
            Seed of :func:`numpy.random.default_rng` (>= 0); same seed, same surface.

        Returns
        -------
        DiffuserSurface
            With ``centres_um`` (N, 2) holding the lenslet centres (x, y), um.

        Raises
        ------
        ReconInputError
            Non-positive parameters, a pitch too coarse for the lenslets, or a focal
            length so short that the caps cannot cover their cells.
        """
        from scipy.spatial import cKDTree

        w_mm, h_mm, pitch, lens, radius, n = _lenslet_parameters(
            size_mm, pitch_um, lenslet_um, focal_mm, refractive_index)
        rows, cols = _grid_shape(w_mm * 1e3, h_mm * 1e3, pitch)
        half_w, half_h = (cols - 1) * pitch / 2, (rows - 1) * pitch / 2
        rng = np.random.default_rng(as_int(seed, "seed", 0))
        margin = 4.0 * lens
        r_min = lens / 1.15  # Bridson's mean NN distance is ~1.1-1.2 r_min; rescaled below
        dom_w, dom_h = 2 * (half_w + margin), 2 * (half_h + margin)
        pts = _poisson_disc(dom_w, dom_h, r_min, rng) - [dom_w / 2, dom_h / 2]
        tree = cKDTree(pts)
        nn = tree.query(pts, k=2)[0][:, 1]
        interior = (np.abs(pts[:, 0]) < dom_w / 2 - 2 * lens) & (
            np.abs(pts[:, 1]) < dom_h / 2 - 2 * lens)
        scale = lens / float(np.mean(nn[interior]))
        pts = pts * scale
        # maximality: every point is within 2 r_min (scaled) of a centre
        if 2.0 * r_min * scale >= radius:
            raise ReconInputError(
                f"focal length {focal_mm} mm gives a cap radius {radius:g} um, too small to "
                f"cover lenslets of {lens} um; use a longer focal length or smaller lenslets"
            )
        keep = (np.abs(pts[:, 0]) <= half_w + 3 * lens) & (np.abs(pts[:, 1]) <= half_h + 3 * lens)
        return cls._from_lenslets(pts[keep], rows, cols, pitch, radius, n)

    @classmethod
    def _from_lenslets(cls, pts: np.ndarray, rows: int, cols: int, pitch: float,
                       radius: float, n: float) -> DiffuserSurface:
        """Union (pointwise maximum) of spherical caps of radius ``radius`` (um)
        centred on ``pts`` (N, 2) um, on a centred ``rows x cols`` grid of ``pitch``;
        the centres inside the grid are kept as ``centres_um``."""
        from scipy.spatial import cKDTree

        tree = cKDTree(pts)
        x = (np.arange(cols) - (cols - 1) / 2) * pitch
        y = (np.arange(rows) - (rows - 1) / 2) * pitch
        height = np.empty((rows, cols), np.float64)
        block = max(1, 2_000_000 // cols)
        for r0 in range(0, rows, block):
            yy, xx = np.meshgrid(y[r0:r0 + block], x, indexing="ij")
            dmin = tree.query(np.column_stack([xx.ravel(), yy.ravel()]), workers=-1)[0]
            height[r0:r0 + block] = (np.sqrt(radius * radius - dmin * dmin) - radius).reshape(
                xx.shape)
        height -= height.min()
        half_w, half_h = (cols - 1) * pitch / 2, (rows - 1) * pitch / 2
        inside = (np.abs(pts[:, 0]) <= half_w) & (np.abs(pts[:, 1]) <= half_h)
        return cls(height, pitch, n, centres_um=pts[inside].copy())

    @classmethod
    def regular_microlens(cls, size_mm, pitch_um: float, lenslet_um: float = 250.0,
                          focal_mm: float = 1.5, refractive_index: float = 1.5
                          ) -> DiffuserSurface:
        """Regular microlens array: the lenslets of :meth:`random_microlens` on a
        square lattice (Kuo 2020, Sec. 6.3, the light-field microscope's array).

        Centres at ``(i + 1/2) lenslet_um`` in x and y (i integer; no lenslet sits on
        the axis, as on a lattice cut symmetrically), each a spherical cap of radius
        ``R = focal_mm (n - 1)`` filling its square cell (the union of the caps).

        Parameters
        ----------
        size_mm : float or (width_mm, height_mm)
            Lateral size to cover.
        pitch_um : float
            Grid spacing in um; <= lenslet_um / 8 (lenslet_um / 20 recommended).
        lenslet_um : float
            Lattice period (centre-to-centre spacing), um.
        focal_mm : float
            Focal length of every lenslet, mm.
        refractive_index : float
            1.5 by default.

        Returns
        -------
        DiffuserSurface
            With ``centres_um`` (N, 2) the lattice points (x, y) inside the grid, um.

        Raises
        ------
        ReconInputError
            Non-positive parameters, a pitch too coarse for the lenslets, or a focal
            length so short that a cap cannot cover its cell (``R`` below the cell's
            half diagonal).
        """
        w_mm, h_mm, pitch, lens, radius, n = _lenslet_parameters(
            size_mm, pitch_um, lenslet_um, focal_mm, refractive_index)
        if lens / math.sqrt(2.0) >= radius:
            raise ReconInputError(
                f"focal length {focal_mm} mm gives a cap radius {radius:g} um, too small to "
                f"cover square cells of {lens} um; use a longer focal length or smaller lenslets"
            )
        rows, cols = _grid_shape(w_mm * 1e3, h_mm * 1e3, pitch)
        kx = int(math.ceil((cols - 1) * pitch / 2 / lens)) + 2
        ky = int(math.ceil((rows - 1) * pitch / 2 / lens)) + 2
        gx = (np.arange(-kx, kx) + 0.5) * lens
        gy = (np.arange(-ky, ky) + 0.5) * lens
        pts = np.column_stack([a.ravel() for a in np.meshgrid(gx, gy)])
        return cls._from_lenslets(pts, rows, cols, pitch, radius, n)

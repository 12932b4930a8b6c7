"""Scenes of several kinds for the automatic-regularisation benchmark and failure maps.

Each scene is a non-negative image of the fine sensor shape, rendered into a
measurement with :func:`recon.simulate.simulate_measurement` (the real tutorial PSF
at bin 2, reconstruction at bin 4: a finer rendering grid, Poisson shot noise and
Gaussian read noise, so never the "inverse crime"). Kinds:

* ``photo:NAME`` - an image scikit-image ships in its package
  (:data:`recon.scenes.BUNDLED`: photographs, dense texture, printed text) inset in
  the central ``inset`` of the field of view on a dark surround (a lensless camera's
  object lies inside its field of view;
  a scene running past the edge is mostly cropped from the sensor, Sec. 3.1);
* ``beads`` - sparse fluorescent beads (Gaussian spots of 1-2 fine pixels),
  ``density`` the fraction of the field they cover;
* ``text`` - black-on-white-inverted line art: a USAF bar target and printed text;
* ``hdr`` - a dim photograph with a few point sources 50x brighter (high dynamic
  range: the bright sources set the measurement's peak and so the photon count);
* ``points`` - isolated point sources of one fine pixel (sparser than beads);
* ``shapes`` - smooth shapes: overlapping discs and ellipses of graded brightness,
  blurred (Gaussian, sigma 3 fine px);
* ``lines`` - line patterns: a Siemens star beside gratings of 2-8 fine px periods.

Pure numpy plus scikit-image and matplotlib's Agg renderer (text), no download.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from recon.api import scaled_problem
from recon.errors import ReconInputError
from recon.operators import ConvolutionOperator
from recon.sample import load_sample
from recon.scenes import BUNDLED, load_scene, usaf_target
from recon.simulate import Simulation, simulate_measurement

__all__ = ["KINDS", "Case", "make_scene", "render_case"]

#: Scene kinds of :func:`make_scene` besides ``photo:NAME``.
KINDS = ("beads", "text", "hdr", "points", "shapes", "lines")


def _inset(image: np.ndarray, shape: tuple[int, int], inset: float) -> np.ndarray:
    out = np.zeros(shape, np.float32)
    rows, cols = image.shape
    top, left = (shape[0] - rows) // 2, (shape[1] - cols) // 2
    out[top:top + rows, left:left + cols] = image
    return out


def _inner(shape, inset):
    return (max(2, int(shape[0] * inset)), max(2, int(shape[1] * inset)))


def _text_image(shape: tuple[int, int]) -> np.ndarray:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows, cols = shape
    fig = Figure(figsize=(cols / 100, rows / 100), dpi=100)
    FigureCanvasAgg(fig)
    fig.patch.set_facecolor("black")
    lines = ("DiffuserLab", "lensless 3D", "ADMM  FISTA", "Kuo 2020")
    for k, line in enumerate(lines):
        fig.text(0.05, 0.82 - 0.22 * k, line, color="white", fontsize=min(rows / 12, cols / 11),
                 family="DejaVu Sans", weight="bold")
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba(), np.float32)[..., 0] / 255.0
    return rgba[:rows, :cols]


def _shapes(shape: tuple[int, int], rng) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    rows, cols = np.mgrid[:shape[0], :shape[1]]
    img = np.zeros(shape, np.float64)
    for _ in range(6):
        r0, c0 = rng.uniform(0.2, 0.8) * shape[0], rng.uniform(0.2, 0.8) * shape[1]
        a, b = rng.uniform(0.08, 0.25, 2) * min(shape)
        img += rng.uniform(0.3, 1.0) * (((rows - r0) / a) ** 2 + ((cols - c0) / b) ** 2 <= 1)
    return gaussian_filter(img, 3.0)


def _lines(shape: tuple[int, int]) -> np.ndarray:
    rows, cols = np.mgrid[:shape[0], :shape[1]].astype(np.float64)
    half = shape[1] // 2
    r0, c0 = shape[0] / 2, half / 2
    star = np.cos(18 * np.arctan2(rows - r0, cols - c0)) > 0  # 18 spokes
    star &= np.hypot(rows - r0, cols - c0) < 0.45 * min(shape[0], half)
    img = np.where(cols < half, star, 0.0)
    # gratings: bands of periods 2, 4, 6, 8 fine px, vertical lines
    band = np.minimum((rows * 4 // shape[0]).astype(int), 3)
    period = 2 * (band + 1)
    grating = (cols - half) % period < period / 2
    return np.where(cols >= half + 2, grating, img)


def make_scene(kind: str, shape: tuple[int, int], *, inset: float = 0.6,
               density: float = 0.002, seed: int = 0) -> np.ndarray:
    """A scene of one kind at the fine sensor shape.

    Parameters
    ----------
    kind : str
        ``"photo:NAME"`` (NAME in :data:`recon.scenes.BUNDLED`), or one of
        :data:`KINDS`.
    shape : (rows, cols)
        Fine sensor shape.
    inset : float
        Fraction of the field of view (per axis) the scene occupies, in (0, 1].
    density : float
        ``beads``: fraction of the inset's pixels that hold a bead centre
        (``points``: a quarter of it).
    seed : int
        Bead positions and brightnesses, HDR source positions.

    Returns
    -------
    ndarray, float32, ``shape``, non-negative, peak 1.

    Raises
    ------
    ReconInputError
        Unknown kind or scene name, ``inset`` outside (0, 1], ``density`` outside (0, 1].
    """
    if not 0 < inset <= 1:
        raise ReconInputError(f"inset {inset} must be in (0, 1]")
    inner = _inner(shape, inset)
    rng = np.random.default_rng(seed)
    if kind.startswith("photo:"):
        name = kind.split(":", 1)[1]
        if name not in BUNDLED:
            raise ReconInputError(f"unknown photograph {name!r}; use one of "
                                  f"{', '.join(BUNDLED)}")
        img = load_scene(name, inner)
    elif kind == "beads":
        if not 0 < density <= 1:
            raise ReconInputError(f"bead density {density} must be in (0, 1]")
        n = max(1, int(round(density * inner[0] * inner[1])))
        img = np.zeros(inner, np.float64)
        r = rng.integers(2, inner[0] - 2, n)
        c = rng.integers(2, inner[1] - 2, n)
        np.add.at(img, (r, c), rng.uniform(0.3, 1.0, n))
        from scipy.ndimage import gaussian_filter

        img = gaussian_filter(img, 1.0)
    elif kind == "text":
        img = np.zeros(inner, np.float64)
        half = inner[1] // 2
        img[:, :half] = usaf_target((inner[0], half)) if min(inner[0], half) >= 32 else 0
        img[:, half:] = _text_image((inner[0], inner[1] - half))
    elif kind == "hdr":
        img = 0.02 * load_scene("astronaut", inner).astype(np.float64)
        for _ in range(4):
            rr, cc = rng.integers(4, inner[0] - 4), rng.integers(4, inner[1] - 4)
            img[rr - 1:rr + 2, cc - 1:cc + 2] = 1.0
    elif kind == "points":
        n = max(1, int(round(density / 4 * inner[0] * inner[1])))
        img = np.zeros(inner, np.float64)
        img[rng.integers(1, inner[0] - 1, n), rng.integers(1, inner[1] - 1, n)] = \
            rng.uniform(0.3, 1.0, n)
    elif kind == "shapes":
        img = _shapes(inner, rng)
    elif kind == "lines":
        img = _lines(inner)
    else:
        raise ReconInputError(f"unknown scene kind {kind!r}; use photo:NAME, "
                              f"{', '.join(KINDS)}")
    img = np.clip(np.asarray(img, np.float64), 0, None)
    peak = float(img.max())
    if peak > 0:
        img /= peak
    return _inset(img.astype(np.float32), tuple(shape), inset)


@dataclass
class Case:
    """A rendered benchmark case: operator, scaled measurement and truth.

    Attributes
    ----------
    op : ConvolutionOperator
        Reconstruction model (real PSF at ``coarse_bin``, unit sum).
    b : ndarray, float32, ``op.shape_out``
        Measurement divided by its maximum (the scaled problem of
        :func:`recon.api.scaled_problem`).
    truth : ndarray, float32, ``op.shape_out``
        Ground truth on the sensor field of view (``truth[op.crop]`` of the padded one).
    sim : Simulation
        The simulation (noise figures, electrons).
    raw_e : ndarray, float32
        The measurement in photo-electrons (``b * scale``), for noise models.
    """

    op: ConvolutionOperator
    b: np.ndarray
    truth: np.ndarray
    sim: Simulation
    raw_e: np.ndarray


def render_case(kind: str, photons: float, *, coarse_bin: int = 4, read_noise_e: float = 3.0,
                seed: int = 0, inset: float = 0.6, density: float = 0.002,
                dark_e: float = 0.0) -> Case:
    """Render one scene through the real PSF with model mismatch and noise.

    The scene is rendered with the real tutorial PSF binned by ``coarse_bin // 2``
    (fine grid) and reconstructed with the PSF binned by ``coarse_bin``.

    Parameters
    ----------
    kind, inset, density, seed
        As in :func:`make_scene` (``seed`` also seeds the noise).
    photons : float
        Peak photo-electrons of the noise-free measurement.
    coarse_bin : int
        Even reconstruction binning of the 1200 x 1600 tutorial frames (4: 300 x 400).
    read_noise_e : float
        Read noise, electrons.
    dark_e : float
        Dark level of the raw, electrons (> 0: added to the measurement, then a dark
        frame of the same level with its own read noise subtracted pixel by pixel, as
        the bench does; the subtraction adds its read noise).

    Returns
    -------
    Case

    Raises
    ------
    ReconInputError
        Odd ``coarse_bin``, or the errors of :func:`make_scene` and
        :func:`recon.simulate.simulate_measurement`.
    """
    if coarse_bin < 2 or coarse_bin % 2:
        raise ReconInputError(f"coarse_bin {coarse_bin} must be even (rendered at half)")
    fine, coarse = load_sample(coarse_bin // 2).psf, load_sample(coarse_bin).psf
    scene = make_scene(kind, fine.shape, inset=inset, density=density, seed=seed)
    sim = simulate_measurement(fine, scene, bin_factor=2, photons=photons,
                               read_noise_e=read_noise_e, seed=seed)
    if dark_e > 0:
        rng = np.random.default_rng(seed + 7919)
        dark = dark_e + rng.normal(0.0, read_noise_e, sim.b.shape)
        sim = dataclasses.replace(sim, b=(sim.b + dark_e - dark).astype(np.float32))
    op, b = scaled_problem(coarse, sim.b)
    return Case(op, b, np.ascontiguousarray(sim.truth[op.crop]), sim, sim.b.astype(np.float32))

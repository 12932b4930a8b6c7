"""Simulated DiffuserCam measurements without the inverse crime.

A measurement is rendered on a grid ``bin_factor`` times finer than the one the
reconstruction uses, with a PSF preprocessed at that finer binning, then box-binned
to the reconstruction grid and corrupted with Poisson shot noise and Gaussian read
noise. The reconstruction (on the coarse grid, with the coarse PSF) therefore never
sees the exact operator that generated its data: discretisation, the PSF's
preprocessing and the noise all differ, as they do on the bench.

Geometry (Kuo 2020, Eq. 3.4): an object on the padded grid, a point at the centre of
the padded grid images to the PSF as measured (see
:class:`recon.operators.ConvolutionOperator`). The scene fills the central
sensor-sized region of the fine padded grid; the coarse truth is the box-binned scene
on the coarse padded grid (``fast_padded_shape`` of the coarse sensor, the
``ConvolutionOperator`` default), placed so that a coarse object pixel ``k`` stands
for the fine pixels ``bin_factor * k ... bin_factor * k + bin_factor - 1`` and shifts
the PSF by exactly ``bin_factor`` fine pixels per coarse pixel. Compare
``truth[op.crop]`` with ``x[op.crop]`` of a coarse reconstruction.

Scenes are natural images bundled with scikit-image (no download):
:data:`recon.scenes.SCENES`, loaded with :func:`recon.scenes.load_scene`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import ReconInputError
from .fft import fast_padded_shape
from .operators import ConvolutionOperator
from .preprocess import box_bin

logger = logging.getLogger(__name__)

__all__ = ["Simulation", "add_camera_noise", "simulate_measurement"]

@dataclass(frozen=True)
class Simulation:
    """A simulated measurement, its ground truth and its noise figures.

    Unpacks as ``b, truth = simulate_measurement(...)``; the other fields are
    attributes.

    Attributes
    ----------
    b : numpy.ndarray
        float32, coarse sensor shape: the noisy measurement in photo-electrons
        (Poisson counts plus Gaussian read noise, so it can be slightly negative).
    truth : numpy.ndarray
        float32, coarse padded shape (``fast_padded_shape`` of the coarse sensor):
        the box-binned scene in the central sensor-sized region, zero elsewhere.
    b_clean : numpy.ndarray
        float32, the noise-free measurement in the same electron units as ``b``.
    photons : float
        Photo-electrons collected by the brightest noise-free pixel.
    read_noise_e : float
        Standard deviation of the Gaussian read noise, electrons.
    snr_db : float
        Measured SNR, ``10 log10(mean(b_clean^2) / mean((b - b_clean)^2))``.
    electrons_per_unit : float
        ``b_clean = electrons_per_unit * bin(A_fine scene)`` with a unit-sum fine
        PSF; with a unit-sum coarse PSF, ``b_clean ~ electrons_per_unit * A_coarse
        truth``.
    bin_factor : int
    fine_padded_shape : tuple of int
        Padded grid of the fine (rendering) operator.
    info : dict
        JSON-ready summary (shapes, offsets, noise figures).
    """

    b: np.ndarray
    truth: np.ndarray
    b_clean: np.ndarray
    photons: float
    read_noise_e: float
    snr_db: float
    electrons_per_unit: float
    bin_factor: int
    fine_padded_shape: tuple[int, int]
    info: dict[str, Any] = field(default_factory=dict)

    def __iter__(self):
        yield self.b
        yield self.truth

    @property
    def snr(self) -> dict[str, float]:
        """The stated SNR: ``{"photons", "read_noise_e", "snr_db"}``."""
        return {"photons": self.photons, "read_noise_e": self.read_noise_e,
                "snr_db": self.snr_db}


def _coarse_geometry(coarse_sensor: tuple[int, int]) -> tuple[tuple[int, int],
                                                               tuple[int, int]]:
    """Padded shape and sensor offset of a default ConvolutionOperator."""
    padded = tuple(int(p) for p in fast_padded_shape(coarse_sensor))
    offset = tuple((p - s) // 2 for p, s in zip(padded, coarse_sensor, strict=True))
    return padded, offset


def _check_noise(photons: float, read_noise_e: float) -> None:
    if not (math.isfinite(photons) and photons > 0):
        raise ReconInputError(f"photons must be positive and finite, got {photons}")
    if not (math.isfinite(read_noise_e) and read_noise_e >= 0):
        raise ReconInputError(f"read noise must be >= 0 and finite, got {read_noise_e}")


def add_camera_noise(image: np.ndarray, photons: float, read_noise_e: float,
                     seed: int | np.random.Generator = 0
                     ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Scale a noise-free image to photo-electrons and add shot and read noise.

    The image is scaled so its brightest pixel collects ``photons`` electrons, then
    Poisson counts are drawn and Gaussian read noise is added (in that order, from
    one generator).

    Parameters
    ----------
    image : ndarray, 2D, non-negative, finite
        Noise-free sensor image in any unit (e.g. photons / s per pixel).
    photons : float
        Photo-electrons of the brightest pixel (> 0).
    read_noise_e : float
        Standard deviation of the read noise, electrons (>= 0).
    seed : int or numpy.random.Generator
        Seed of :func:`numpy.random.default_rng` (or a generator to draw from).

    Returns
    -------
    noisy : ndarray, float64
        Electrons (Poisson counts plus read noise; can be slightly negative).
    clean : ndarray, float64
        The scaled noise-free image, electrons.
    gain : float
        Electrons per unit of ``image``.
    snr_db : float
        ``10 log10(mean(clean^2) / mean((noisy - clean)^2))`` (inf without noise).

    Raises
    ------
    ReconInputError
        Invalid noise parameters, a negative or non-finite image, or an all-zero one.
    """
    _check_noise(photons, read_noise_e)
    img = np.asarray(image, dtype=np.float64)
    if not np.all(np.isfinite(img)) or np.any(img < 0):
        raise ReconInputError("the noise-free image must be finite and non-negative")
    peak = float(img.max()) if img.size else 0.0
    if not peak > 0:
        raise ReconInputError("the scene renders to an all-zero measurement; use a "
                              "scene with some light in the field of view")
    gain = photons / peak
    clean = img * gain
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    noisy = rng.poisson(clean).astype(np.float64)
    if read_noise_e > 0:
        noisy += rng.normal(0.0, read_noise_e, clean.shape)
    noise = noisy - clean
    noise_power = float(np.mean(noise**2))
    signal_power = float(np.mean(clean**2))
    snr_db = 10.0 * math.log10(signal_power / noise_power) if noise_power > 0 else math.inf
    return noisy, clean, gain, snr_db


def simulate_measurement(psf_fine: np.ndarray, scene_fine: np.ndarray, *,
                         bin_factor: int = 2, photons: float = 5000.0,
                         read_noise_e: float = 2.0, seed: int = 0) -> Simulation:
    """Render a noisy lensless measurement on a finer grid than the reconstruction's.

    Steps: normalise ``psf_fine`` to unit sum and build a
    :class:`~recon.operators.ConvolutionOperator` on a padded grid ``bin_factor``
    times the coarse one; place ``scene_fine`` in the central sensor-sized region
    (zero elsewhere); ``forward``; box-bin by ``bin_factor``
    (:func:`recon.preprocess.box_bin`); scale so the brightest pixel collects
    ``photons`` photo-electrons; draw Poisson counts; add Gaussian read noise.

    Parameters
    ----------
    psf_fine : numpy.ndarray
        2D PSF at the fine binning (e.g. the real PSF preprocessed with
        ``bin_factor=2`` when the reconstruction uses 4), non-negative, finite.
    scene_fine : numpy.ndarray
        2D non-negative scene of the fine sensor shape (see :func:`recon.scenes.load_scene`).
    bin_factor : int
        Ratio of the reconstruction pixel to the rendering pixel (>= 1; 1 is the
        inverse crime and only meant for tests). If the fine shape is not a multiple,
        the bottom rows / right columns are cropped.
    photons : float
        Peak photo-electrons (brightest noise-free pixel); > 0.
    read_noise_e : float
        Read noise standard deviation in electrons; >= 0.
    seed : int
        Seed of :func:`numpy.random.default_rng`.

    Returns
    -------
    Simulation
        Unpacks as ``(b, truth)``: ``b`` float32 of the coarse sensor shape (in
        electrons), ``truth`` float32 on the coarse padded grid (box-binned scene,
        in the scene's units); ``.snr`` gives the stated SNR.

    Raises
    ------
    ReconInputError
        Non-2D or mismatched shapes, a PSF without positive energy, negative or
        non-finite values, or invalid noise parameters.

    Notes
    -----
    Centring: the fine scene starts at fine padded index
    ``q_f = P_f // 2 + bin_factor * (top_c - P_c // 2)`` (per axis), where ``P_c``,
    ``top_c`` are the coarse padded length and sensor offset, so a coarse object pixel
    shifts the PSF by exactly ``bin_factor`` fine pixels; for the usual even sizes
    this is the fine operator's own crop. The coarse PSF should be the same
    calibration binned by the total factor (``box_bin(psf_fine, bin_factor)`` up to
    the preprocessing's clipping).
    """
    if isinstance(bin_factor, bool) or not isinstance(bin_factor, int | np.integer) \
            or bin_factor < 1:
        raise ReconInputError(f"bin factor must be an integer >= 1, got {bin_factor!r}")
    bf = int(bin_factor)
    _check_noise(photons, read_noise_e)
    psf = np.asarray(psf_fine, dtype=np.float64)
    scene = np.asarray(scene_fine, dtype=np.float64)
    if psf.ndim != 2 or scene.ndim != 2:
        raise ReconInputError(
            f"PSF and scene must be 2D, got shapes {psf.shape} and {scene.shape}"
        )
    if psf.shape != scene.shape:
        raise ReconInputError(
            f"scene shape {scene.shape} differs from the fine PSF shape {psf.shape}; "
            "resize the scene to the fine sensor, e.g. "
            "recon.scenes.load_scene(name, psf_fine.shape)"
        )
    if not (np.all(np.isfinite(psf)) and np.all(np.isfinite(scene))):
        raise ReconInputError("PSF or scene contains NaN/inf")
    if np.any(psf < 0) or not psf.sum() > 0:
        raise ReconInputError(
            "the fine PSF must be non-negative with positive sum (preprocess it with "
            "recon.preprocess.prepare_pair, which clips at 0)"
        )
    if np.any(scene < 0):
        raise ReconInputError("the scene is an intensity and must be non-negative")
    rows, cols = (s // bf * bf for s in psf.shape)
    if rows < 2 * bf or cols < 2 * bf:
        raise ReconInputError(f"fine shape {psf.shape} is too small for bin factor {bf}")
    if (rows, cols) != psf.shape:
        logger.warning("simulate: cropping fine shape %s to %s (multiple of bin factor %d)",
                       psf.shape, (rows, cols), bf)
        psf, scene = psf[:rows, :cols], scene[:rows, :cols]
    coarse_sensor = (rows // bf, cols // bf)
    coarse_padded, coarse_offset = _coarse_geometry(coarse_sensor)
    fine_padded = tuple(bf * p for p in coarse_padded)

    op = ConvolutionOperator((psf / psf.sum()).astype(np.float32), padded_shape=fine_padded)
    start = tuple(pf // 2 + bf * (tc - pc // 2)
                  for pf, tc, pc in zip(fine_padded, coarse_offset, coarse_padded, strict=True))
    obj = np.zeros(fine_padded, np.float32)
    obj[start[0]:start[0] + rows, start[1]:start[1] + cols] = scene
    sensor = box_bin(op.forward(obj), bf).astype(np.float64)
    np.maximum(sensor, 0.0, out=sensor)  # FFT round-off around zero
    noisy, clean, gain, snr_db = add_camera_noise(sensor, photons, read_noise_e, seed)

    truth = np.zeros(coarse_padded, np.float32)
    truth[coarse_offset[0]:coarse_offset[0] + coarse_sensor[0],
          coarse_offset[1]:coarse_offset[1] + coarse_sensor[1]] = box_bin(scene, bf)
    info = {
        "bin_factor": bf,
        "fine_sensor_shape": [rows, cols],
        "fine_padded_shape": list(fine_padded),
        "fine_scene_offset": list(start),
        "coarse_sensor_shape": list(coarse_sensor),
        "coarse_padded_shape": list(coarse_padded),
        "coarse_offset": list(coarse_offset),
        "photons": float(photons),
        "read_noise_e": float(read_noise_e),
        "snr_db": snr_db,
        "seed": int(seed),
        "electrons_per_unit": gain,
    }
    return Simulation(b=noisy.astype(np.float32), truth=truth,
                      b_clean=clean.astype(np.float32), photons=float(photons),
                      read_noise_e=float(read_noise_e), snr_db=snr_db,
                      electrons_per_unit=gain, bin_factor=bf,
                      fine_padded_shape=fine_padded, info=info)

"""Small synthetic cameras for the scene calibration's tests.

A sparse blurred PSF, smooth non-negative scenes, and each scene's measurement
``C (x * P h)`` (Kuo 2020, Eq. 3.4) by :class:`recon.operators.ConvolutionOperator`
with the scene in the PSF's role. :func:`semiconvergent_pairs` adds 3 % noise, so that
a prior-free non-negative FISTA semi-converges: the error against the scene falls,
then rises as the solve fits the noise and the PSF's estimation error. Used by the
recipe's and the sensor response's tests (tests/recon/test_early_stop.py,
test_in_sample_choice.py, test_sensor_response.py, test_recipe_binning.py).
"""

import numpy as np
from scipy.ndimage import gaussian_filter

from recon.operators import ConvolutionOperator


def sparse_psf(rng, rows: int, cols: int, *, points: int = 12, margin: int = 2,
               sigma_px: float = 0.7) -> np.ndarray:
    """A PSF of ``points`` random points (weights 0.5-1.5) at least ``margin`` px from
    the edge, blurred by a Gaussian of ``sigma_px``: (rows, cols) float32."""
    h = np.zeros((rows, cols), np.float32)
    for _ in range(points):
        h[rng.integers(margin, rows - margin), rng.integers(margin, cols - margin)] = (
            rng.random() + 0.5)
    return gaussian_filter(h, sigma_px)


def smooth_scene(rng, rows: int, cols: int, *, sigma_px: float = 1.5, gain: float = 4.0,
                 floor: float = 1.5) -> np.ndarray:
    """Smoothed uniform noise, ``gain`` times it less ``floor``, clipped at 0, plus 0.05
    (patches of dark and light, nowhere zero): (rows, cols) float32."""
    x = np.clip(gaussian_filter(rng.random((rows, cols)), sigma_px) * gain - floor, 0, None)
    return (x + 0.05).astype(np.float32)


def measure(scene: np.ndarray, psf: np.ndarray) -> np.ndarray:
    """The noiseless measurement ``C (x * P h)`` of ``scene`` through ``psf``, both
    (rows, cols): (rows, cols) float32."""
    op = ConvolutionOperator(scene)  # the scene in the PSF's role
    padded = np.zeros(op.padded_shape, np.float32)
    padded[op.crop] = psf
    return op.forward(padded)


def semiconvergent_pairs(rows: int, cols: int, n: int, seed: int = 3):
    """``n`` (scene, measurement) pairs of one camera (:func:`sparse_psf` of 12 points,
    :func:`smooth_scene`), each measurement with Gaussian noise of 3 % of its standard
    deviation.

    Returns
    -------
    scenes, measurements : list of ndarray, (rows, cols) float32
    """
    rng = np.random.default_rng(seed)
    h = sparse_psf(rng, rows, cols)
    scenes, measurements = [], []
    for _ in range(n):
        x = smooth_scene(rng, rows, cols)
        b = measure(x, h)
        scenes.append(x)
        measurements.append((b + 0.03 * b.std() * rng.standard_normal(b.shape))
                            .astype(np.float32))
    return scenes, measurements

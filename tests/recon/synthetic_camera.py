"""A small synthetic camera whose prior-free non-negative FISTA semi-converges.

A sparse blurred PSF (12 points, Gaussian sigma 0.7 px), smooth non-negative scenes,
measurements with 3 % noise: the error against the scene falls, then rises as the
solve fits the noise and the PSF's estimation error. Used by the recipe's tests
(tests/recon/test_early_stop.py, tests/recon/test_in_sample_choice.py).
"""

import numpy as np
from scipy.ndimage import gaussian_filter

from recon.operators import ConvolutionOperator


def semiconvergent_pairs(rows: int, cols: int, n: int, seed: int = 3):
    """``n`` (scene, measurement) pairs of one camera, each (rows, cols) float32.

    Returns
    -------
    scenes, measurements : list of ndarray
    """
    rng = np.random.default_rng(seed)
    h = np.zeros((rows, cols), np.float32)
    for _ in range(12):
        h[rng.integers(2, rows - 2), rng.integers(2, cols - 2)] = rng.random() + 0.5
    h = gaussian_filter(h, 0.7)
    padded = np.pad(h, ((rows // 2, rows // 2), (cols // 2, cols // 2)))
    scenes, measurements = [], []
    for _ in range(n):
        x = np.clip(gaussian_filter(rng.random((rows, cols)), 1.5) * 4 - 1.5, 0, None) + 0.05
        b = ConvolutionOperator(x.astype(np.float32)).forward(padded)
        scenes.append(x.astype(np.float32))
        measurements.append((b + 0.03 * b.std() * rng.standard_normal(b.shape))
                            .astype(np.float32))
    return scenes, measurements

"""Small shared fixtures for the recon operator and solver tests.

``conv_problem`` is a synthetic lensless problem with a known answer: a random,
sparse-ish, non-negative PSF (unit sum) on a 32x32 sensor, whose support is the
central 16x16 (the diffuser aperture, Kuo 2020 Sec. 3.1), and a piecewise-constant
non-negative scene on the 64x64 padded grid that is zero outside the central
sensor-sized region.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from recon.operators import ConvolutionOperator

SENSOR = (32, 32)


@dataclass
class ConvProblem:
    """Operator, ground truth and measurements (clean and with 1 % noise)."""

    op: ConvolutionOperator
    truth: np.ndarray
    b_clean: np.ndarray
    b_noisy: np.ndarray

    def psnr(self, x: np.ndarray) -> float:
        """PSNR (dB) of an estimate on the central sensor-sized region, peak 1."""
        err = np.asarray(x, np.float64)[self.op.crop] - self.truth[self.op.crop]
        return float(10.0 * np.log10(float(self.truth.max()) ** 2 / np.mean(err * err)))

    @staticmethod
    def zero_objective(b: np.ndarray) -> float:
        """Objective of the all-zero image, 1/2 ||b||^2."""
        return 0.5 * float(np.vdot(b.astype(np.float64), b.astype(np.float64)))


def make_psf(seed: int = 0, shape=SENSOR, support: int = 16) -> np.ndarray:
    """Sparse-ish non-negative PSF of unit sum, non-zero on a central square."""
    rng = np.random.default_rng(seed)
    h = np.zeros(shape, np.float64)
    top, left = (shape[0] - support) // 2, (shape[1] - support) // 2
    h[top:top + support, left:left + support] = rng.random((support, support)) ** 6
    return (h / h.sum()).astype(np.float32)


def make_scene(op: ConvolutionOperator) -> np.ndarray:
    """Piecewise-constant scene in [0, 1] on the padded grid, zero off the centre."""
    truth = np.zeros(op.padded_shape, np.float32)
    c = truth[op.crop]  # a view
    c[4:14, 5:20] = 1.0
    c[18:28, 8:16] = 0.5
    c[10:24, 22:29] = 0.8
    c[20:26, 18:30] += 0.2
    return truth


@pytest.fixture
def conv_problem() -> ConvProblem:
    op = ConvolutionOperator(make_psf())
    truth = make_scene(op)
    b = op.forward(truth)
    rng = np.random.default_rng(7)
    noise = 0.01 * float(b.max()) * rng.standard_normal(b.shape)
    return ConvProblem(op, truth, b, (b + noise).astype(np.float32))

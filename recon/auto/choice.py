"""Automatic method and regulariser choice (``method="auto"``): model no more than a
scene needs, within the time the user gives.

Rules, each from a measurement of the data or of the benchmarks, in this order:

1. **Signal.** Under the fitted Poisson-Gaussian model (:mod:`recon.auto.noise`) the
   frame's energy ||b||^2 is compared with the energy the noise alone would have,
   E||n||^2. When ||b||^2 < :data:`NO_SIGNAL_RATIO` E||n||^2 the data carry no signal
   and :class:`NoSignalError` says so (nothing to reconstruct; an image would be noise).
   Before it, in every method, :func:`recon.preprocess.check_raw_signal` has checked the
   raw after its dark level (a raw below the dark level, a constant or a noise-only
   frame is refused there), so ||b||^2 here is light, not a dark offset.
2. **Time budget.** With ``seconds`` given, an iteration costs about
   :data:`ITERATION_COST` FFT pairs (ADMM at 300 x 400 in the speed benchmark,
   2.7-3.2x the FFT floor) and the automatic weight up to
   :data:`recon.auto.weight.BUDGET` times the iterations, so the budget affords
   ``seconds / (BUDGET * ITERATION_COST * fft_pair_s)`` iterations (and the weight's
   path also stops on the wall clock, :func:`recon.auto.weight.admm_auto`). Below
   :data:`MIN_ITERATIONS` (a single video frame period at 30 fps, for instance),
   the Wiener filter, one FFT pair, is the only method that fits.
3. **Regulariser.** ADMM with the TV weight chosen by hold-out cross-validation
   (:mod:`recon.auto.weight`): as much TV as the held-out pixels show the scene
   needs, from 1e-2 (flat patches) down to 1e-5 (about none: below it ADMM does
   worse than without TV). l1 (``l1="auto"``) is there for sparse scenes, but on
   sparse scenes non-negativity is the prior that counts and l1 adds nothing
   measurable, so auto keeps TV, whose held-out path runs down to next to none on
   them (1e-5). Measured (real PSF, bin 4, 300 and 3000 e-, ADMM at 200 iterations,
   best weight of each): the benchmark's beads (Gaussian, sigma 1 fine px) TV
   33.6-39.9 dB against l1 29.5-33.6, TV with l1 added at most +0.1; point beads of
   one pixel TV 35.0-38.7 against l1 32.0-34.7; FISTA without TV (non-negative least
   squares, 1000 iterations) 36.9 / 34.2 dB, with its best l1 37.0 / 34.2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..errors import ReconInputError
from .weight import BUDGET

__all__ = ["ITERATION_COST", "MIN_ITERATIONS", "NO_SIGNAL_RATIO", "MethodChoice",
           "NoSignalError", "choose_method", "check_signal"]

#: Frame energy below this multiple of the noise energy: no signal.
NO_SIGNAL_RATIO = 1.5
#: Seconds per ADMM iteration in FFT pairs (``diffuserlab benchmark recon``, speed).
ITERATION_COST = 3.0
#: Fewer affordable iterations than this: Wiener.
MIN_ITERATIONS = 20


class NoSignalError(ReconInputError):
    """The measurement holds no more energy than its noise would alone."""


@dataclass
class MethodChoice:
    """What ``method="auto"`` chose and why.

    Attributes
    ----------
    method : str
        ``"wiener"`` or ``"admm"``.
    iterations : int
        Maximum iterations for the iterative method (1 for Wiener).
    reasons : list of str
        One sentence per rule that decided.
    """

    method: str
    iterations: int
    reasons: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"method": self.method, "iterations": self.iterations,
                "reasons": list(self.reasons)}


def check_signal(b_energy: float, noise_energy: float) -> float:
    """SNR of a frame in dB; raises when the frame is noise only.

    Parameters
    ----------
    b_energy : float
        ||b||^2 of the (scaled) measurement.
    noise_energy : float
        E||n||^2 under the fitted noise model, same scaling.

    Returns
    -------
    float
        ``10 log10((||b||^2 - E||n||^2) / E||n||^2)`` (inf without noise).

    Raises
    ------
    NoSignalError
        ``||b||^2 < NO_SIGNAL_RATIO * E||n||^2``.
    """
    if not noise_energy > 0:
        return math.inf
    if b_energy < NO_SIGNAL_RATIO * noise_energy:
        raise NoSignalError(
            f"the data carry no signal: the frame's energy is {b_energy / noise_energy:.2f}x "
            "what its noise alone would give (Poisson-Gaussian model fitted to the frame); "
            "check the exposure, the light source and the lens cap, or the dark frame")
    return 10 * math.log10((b_energy - noise_energy) / noise_energy)


def choose_method(iterations: int, *, seconds: float | None = None,
                  fft_pair_s: float | None = None, snr_db: float | None = None
                  ) -> MethodChoice:
    """Choose the method for ``method="auto"`` (rules 2-3 of the module docstring).

    Parameters
    ----------
    iterations : int
        Maximum iterations asked for.
    seconds : float, optional
        Time budget of the solve, s.
    fft_pair_s : float, optional
        Measured FFT floor at the padded shape (needed with ``seconds``).
    snr_db : float, optional
        From :func:`check_signal`, for the record.

    Returns
    -------
    MethodChoice

    Raises
    ------
    ReconInputError
        ``seconds`` not positive, or given without ``fft_pair_s``.
    """
    reasons = []
    if snr_db is not None:
        reasons.append(f"signal: SNR {snr_db:.1f} dB under the fitted noise model")
    if seconds is not None:
        if not (seconds > 0 and math.isfinite(seconds)):
            raise ReconInputError(f"time budget {seconds} s: give a positive number of seconds")
        if not fft_pair_s:
            raise ReconInputError("a time budget needs the measured FFT floor (fft_pair_s)")
        affordable = int(seconds / (BUDGET * ITERATION_COST * fft_pair_s))
        if affordable < MIN_ITERATIONS:
            reasons.append(
                f"time budget {seconds:g} s affords {affordable} automatic ADMM iterations "
                f"(< {MIN_ITERATIONS}; an iteration costs ~{ITERATION_COST:g} FFT pairs of "
                f"{fft_pair_s * 1e3:.2f} ms): Wiener, one FFT pair")
            return MethodChoice("wiener", 1, reasons)
        if affordable < iterations:
            reasons.append(f"time budget {seconds:g} s: at most {affordable} iterations")
            iterations = affordable
    reasons.append("ADMM (best PSNR per second in the speed-vs-accuracy benchmark) with the "
                   "TV weight chosen by hold-out cross-validation (TV, not l1: on sparse "
                   "scenes non-negativity is the prior that counts, and l1 measured no "
                   "better than TV's smallest weight)")
    return MethodChoice("admm", iterations, reasons)

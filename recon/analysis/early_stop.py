"""Early stopping fitted on calibration pairs: the iteration count of a prior-free solve.

With a PSF calibrated from a few known scenes (:mod:`recon.analysis.psf_from_scenes`),
the model's error, not the sensor's noise, limits a reconstruction: the PSF carries
the estimation error of a few pairs and the camera departs from a shift-invariant
convolution. A non-negative FISTA without any prior (Eq. 2.5 with no TV term, Kuo 2020
Sec. 2.3) first fits the scene's structure and then, iteration after iteration, the
model error, amplified by the ill-conditioned inverse: stopping it early is the
regularisation (semi-convergence; Landweber's iteration count as the regularisation
parameter, Engl, Hanke & Neubauer 1996, Ch. 6). It has no block tiling, unlike TV at
the weight that the held-out pixels choose on such data.

The iteration count is the one hyperparameter, and it is fitted on calibration data
only: each calibration pair ``k`` is reconstructed with the PSF estimated *without*
it (:func:`recon.analysis.psf_from_scenes.leave_one_out`'s PSFs), for each candidate
count, and scored against its known scene after a per-channel least-squares gain
(the scene's scale is not the reconstruction's); the count with the least mean
relative error wins (:func:`fit_early_stop`). The fit ships with the PSF it was
made for (:class:`EarlyStop`, identified by a SHA-256 of the PSF's values) and
:func:`reconstruct_early_stopped` refuses another PSF.

:func:`fit_held_out` makes the fit a pair may be scored with (a benchmark's
leave-one-out entry); docs/reconstruction.md has the counts and scores on the five real
DiffuserCam pairs.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ReconInputError
from .psf_from_scenes import check_pairs

__all__ = ["CANDIDATES", "FILE", "EarlyStop", "fit_early_stop", "fit_held_out",
           "gain_fitted_error", "psf_identity", "reconstruct_early_stopped"]

#: Candidate iteration counts of :func:`fit_early_stop` (each a separate solve).
CANDIDATES = (30, 50, 70, 100, 140, 200)
#: The file name of the fit in a PSF-from-scenes calibration run.
FILE = "early_stop.json"
#: The solve the fitted count belongs to, in words (records).
SOLVE = "non-negative FISTA without a prior (recon.reconstruct method='fista', tv=0, l1=0)"


def psf_identity(psf) -> str:
    """SHA-256 (hex) of a PSF's shape and float32 values: what an :class:`EarlyStop`
    is tied to.

    Parameters
    ----------
    psf : array_like, (rows, cols) or (rows, cols, channels)

    Returns
    -------
    str
        64 hex digits; equal for equal float32 values and shape.
    """
    a = np.ascontiguousarray(np.asarray(psf, np.float32))
    digest = hashlib.sha256(repr(a.shape).encode())
    digest.update(a.tobytes())
    return digest.hexdigest()


@dataclass(frozen=True)
class EarlyStop:
    """A fitted iteration count, tied to one PSF (module docstring).

    Attributes
    ----------
    iterations : int
        The count fitted (one of ``candidates``).
    candidates : tuple of int
        The counts tried.
    errors : ndarray, float64, (n_candidates, n_pairs)
        Each calibration pair's gain-fitted relative error (:func:`gain_fitted_error`,
        mean over channels) at each count, the pair reconstructed with the PSF
        estimated without it.
    psf_sha256 : str
        :func:`psf_identity` of the PSF the count is for (the one estimated from every
        calibration pair).
    pairs : tuple of str
        The calibration pairs' names.
    """

    iterations: int
    candidates: tuple
    errors: np.ndarray
    psf_sha256: str
    pairs: tuple = field(default=())

    @property
    def method(self) -> str:
        """The calibration product in words, for records."""
        return (f"{SOLVE}, {self.iterations} iterations: the count of {list(self.candidates)} "
                f"with the least gain-fitted error on {len(self.pairs) or 'the'} calibration "
                "pairs, each reconstructed with the PSF estimated without it")

    def to_dict(self) -> dict:
        """JSON-able form (:meth:`from_dict` reads it back)."""
        return {"kind": "early-stop", "solve": SOLVE, "iterations": int(self.iterations),
                "candidates": [int(c) for c in self.candidates],
                "errors": np.asarray(self.errors, float).round(6).tolist(),
                "psf_sha256": self.psf_sha256, "pairs": list(self.pairs)}

    @classmethod
    def from_dict(cls, d: dict) -> EarlyStop:
        """An :class:`EarlyStop` from :meth:`to_dict`'s form.

        Raises
        ------
        ReconInputError
            Not such a record (another kind, or a field missing).
        """
        if not isinstance(d, dict) or d.get("kind") != "early-stop":
            raise ReconInputError("not an early-stop calibration (no kind 'early-stop'); give "
                                  "the file a PSF-from-scenes calibration wrote")
        try:
            return cls(int(d["iterations"]), tuple(int(c) for c in d["candidates"]),
                       np.asarray(d["errors"], float), str(d["psf_sha256"]),
                       tuple(d.get("pairs", ())))
        except (KeyError, TypeError, ValueError) as exc:
            raise ReconInputError(f"early-stop calibration incomplete ({exc!r}); give the "
                                  "file a PSF-from-scenes calibration wrote") from None

    def save(self, path, overwrite: bool = False) -> Path:
        """Write :meth:`to_dict` as JSON to ``path``.

        Parameters
        ----------
        path : str or Path
        overwrite : bool
            Replace an existing file (a calibration run rewriting its own product);
            by default an existing file is refused.

        Raises
        ------
        ReconInputError
            ``path`` exists (without ``overwrite``).
        """
        path = Path(path)
        if path.exists() and not overwrite:
            raise ReconInputError(f"{path} exists; choose a new file name (an earlier fit is "
                                  "never overwritten)")
        path.write_text(json.dumps(self.to_dict(), indent=1))
        return path

    @classmethod
    def load(cls, path) -> EarlyStop:
        """Read a file :meth:`save` wrote, or a calibration run's (a directory holding
        ``early_stop.json``).

        Raises
        ------
        ReconInputError
            Missing or unreadable file, or not an early-stop calibration.
        """
        path = Path(path)
        path = path / FILE if path.is_dir() else path
        try:
            d = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise ReconInputError(f"cannot read the early-stop calibration {path}: "
                                  f"{exc.__class__.__name__}; give the JSON file a "
                                  "PSF-from-scenes calibration wrote") from None
        return cls.from_dict(d)

    def check_psf(self, psf) -> None:
        """Refuse a PSF other than the one this count was fitted for.

        Raises
        ------
        ReconInputError
            ``psf`` is not that PSF (one line: the count belongs to its calibration).
        """
        if psf_identity(psf) != self.psf_sha256:
            raise ReconInputError(
                "the early-stop calibration was fitted for another PSF (its SHA-256 "
                f"{self.psf_sha256[:12]}... differs); use it with the PSF of the same "
                "PSF-from-scenes calibration, or fit one for this camera")


def gain_fitted_error(estimate: np.ndarray, scene: np.ndarray) -> float:
    """Relative error of ``estimate`` against ``scene`` after a per-channel
    least-squares gain, averaged over channels.

    Per channel ``min_g ||g e - s|| / ||s|| = sqrt(1 - <e, s>^2 / (|e|^2 |s|^2))``.

    Parameters
    ----------
    estimate, scene : ndarray, (rows, cols) or (rows, cols, channels), same shape

    Returns
    -------
    float
        In [0, 1]; 1 for an all-zero estimate.
    """
    e = np.asarray(estimate, np.float64)
    s = np.asarray(scene, np.float64)
    e, s = (e[..., None], s[..., None]) if e.ndim == 2 else (e, s)
    out = []
    for c in range(s.shape[-1]):
        ee, ss, es = (float(np.vdot(e[..., c], e[..., c])), float(np.vdot(s[..., c], s[..., c])),
                      float(np.vdot(e[..., c], s[..., c])))
        cos2 = es * es / (ee * ss) if ee > 0 and ss > 0 else 0.0
        out.append(np.sqrt(max(1.0 - cos2, 0.0)))
    return float(np.mean(out))


def _solve(psf: np.ndarray, raw: np.ndarray, iterations: int, **options) -> np.ndarray:
    from ..api import reconstruct

    res = reconstruct(psf, raw, method="fista", tv=0.0, l1=0.0, iterations=iterations,
                      auto_stop=False, **options)
    return np.asarray(res.image)


def fit_early_stop(scenes, measurements, held_out_psfs: Sequence, psf, *,
                   candidates: Sequence[int] = CANDIDATES, names: Sequence[str] = (),
                   on_candidate=None) -> EarlyStop:
    """Fit the iteration count on calibration pairs (module docstring).

    Parameters
    ----------
    scenes, measurements
        The calibration pairs, as for
        :func:`recon.analysis.psf_from_scenes.estimate_psf_from_scenes` (measurements
        dark-subtracted), at least two.
    held_out_psfs : sequence of ndarray
        Pair ``k``'s PSF estimated without it (``leave_one_out(...).psfs``), each of
        the measurements' shape.
    psf : ndarray
        The PSF estimated from every pair: the one the count ships with.
    candidates : sequence of int
        Iteration counts to try (each >= 1; default :data:`CANDIDATES`).
    names : sequence of str
        The pairs' names, for the record.
    on_candidate : callable, optional
        ``on_candidate(iterations, errors_per_pair)`` after each count (progress).

    Returns
    -------
    EarlyStop

    Raises
    ------
    ReconInputError
        Fewer than two pairs, one held-out PSF per pair missing, a PSF of another
        shape, or a candidate count < 1.
    """
    xs, bs = check_pairs(scenes, measurements)
    if len(xs) < 2 or len(held_out_psfs) != len(xs):
        raise ReconInputError(
            f"{len(xs)} calibration pairs and {len(held_out_psfs)} held-out PSFs: give at "
            "least two pairs and each one's PSF estimated without it (leave_one_out)")
    cands = sorted({int(c) for c in candidates})
    if not cands or cands[0] < 1:
        raise ReconInputError(f"candidate iteration counts {list(candidates)}: give counts >= 1")
    for h in (*held_out_psfs, psf):
        if np.shape(h)[:2] != xs[0].shape[:2]:
            raise ReconInputError(f"PSF of shape {np.shape(h)} for pairs of shape "
                                  f"{xs[0].shape}: give PSFs of the measurements' shape")
    errors = np.zeros((len(cands), len(xs)))
    for i, k_iter in enumerate(cands):
        for k, (x, b) in enumerate(zip(xs, bs, strict=True)):
            errors[i, k] = gain_fitted_error(
                _solve(np.asarray(held_out_psfs[k], np.float32), b, k_iter, dark="none"), x)
        if on_candidate is not None:
            on_candidate(k_iter, errors[i])
    best = cands[int(np.argmin(errors.mean(axis=1)))]
    return EarlyStop(best, tuple(cands), errors, psf_identity(psf), tuple(names))


def fit_held_out(scenes, measurements, k: int, *, psf=None,
                 candidates: Sequence[int] = CANDIDATES, **psf_options) -> EarlyStop:
    """The early-stop fit that pair ``k`` may be scored with: fitted on the other pairs
    only (a benchmark's leave-one-out entry).

    The PSF is estimated from the other pairs (or ``psf``, that estimate, given);
    each of those pairs is reconstructed with the PSF estimated from the rest of them
    (:func:`recon.analysis.psf_from_scenes.leave_one_out` on the other pairs), so pair
    ``k`` touches neither the PSF nor the count.

    Parameters
    ----------
    scenes, measurements
        Every pair, as for :func:`fit_early_stop` (at least three).
    k : int
        The held-out pair's index.
    psf : ndarray, optional
        The PSF estimated from every pair but ``k`` (computed when not given).
    candidates : sequence of int
        As for :func:`fit_early_stop`.
    **psf_options
        Of :func:`recon.analysis.psf_from_scenes.estimate_psf_from_scenes`.

    Returns
    -------
    EarlyStop
        Tied to that PSF; reconstruct pair ``k`` with :func:`reconstruct_early_stopped`.

    Raises
    ------
    ReconInputError
        Fewer than three pairs, ``k`` out of range, or what :func:`fit_early_stop`
        refuses.
    """
    from .psf_from_scenes import estimate_psf_from_scenes, leave_one_out

    scenes, measurements = list(scenes), list(measurements)
    if len(scenes) < 3 or not 0 <= int(k) < len(scenes):
        raise ReconInputError(f"pair {k} of {len(scenes)}: give at least three pairs and "
                              "the index of one of them")
    xs = [x for i, x in enumerate(scenes) if i != k]
    bs = [b for i, b in enumerate(measurements) if i != k]
    if psf is None:
        psf = estimate_psf_from_scenes(xs, bs, **psf_options).psf
    return fit_early_stop(xs, bs, leave_one_out(xs, bs, **psf_options).psfs, psf,
                          candidates=candidates)


def reconstruct_early_stopped(psf, raw, fit: EarlyStop, **options):
    """Reconstruct with a fitted count: non-negative FISTA, no prior, ``fit.iterations``
    iterations exactly, after checking that ``psf`` is the fit's PSF.

    Parameters
    ----------
    psf, raw
        As for :func:`recon.reconstruct` (one PSF).
    fit : EarlyStop
    **options
        Further options of :func:`recon.reconstruct` (``dark``, ``bin_factor``,
        ``device``, ...), not the method, iterations or weights.

    Returns
    -------
    recon.result.Reconstruction

    Raises
    ------
    ReconInputError
        ``psf`` is not the fit's PSF, an option that the fit fixes, or what
        :func:`recon.reconstruct` refuses.
    """
    fixed = sorted({"method", "iterations", "tv", "l1", "auto_stop"} & set(options))
    if fixed:
        raise ReconInputError(f"{', '.join(fixed)}: fixed by the early-stop calibration; "
                              "leave them out")
    fit.check_psf(psf)
    from ..api import reconstruct

    return reconstruct(psf, raw, method="fista", tv=0.0, l1=0.0, iterations=fit.iterations,
                       auto_stop=False, **options)

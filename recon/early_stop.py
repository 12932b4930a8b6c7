"""An early-stop calibration: the iteration count fitted for one PSF, as a product.

:class:`EarlyStop` is what ``calibrate psf-from-scenes`` writes into its run
(``early_stop.json``) and what ``recon --early-stop`` and
:func:`recon.analysis.early_stop.reconstruct_early_stopped` read: the iteration count
of a prior-free non-negative FISTA fitted on the calibration pairs
(:func:`recon.analysis.early_stop.fit_early_stop`), tied to the PSF it was fitted for
by a SHA-256 of the PSF's values (:func:`psf_identity`) and refused with another.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import ReconInputError

__all__ = ["FILE", "SOLVE", "EarlyStop", "psf_identity"]

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
    """A fitted iteration count, tied to one PSF (:mod:`recon.analysis.early_stop`).

    Attributes
    ----------
    iterations : int
        The count fitted (one of ``candidates``).
    candidates : tuple of int
        The counts tried.
    errors : ndarray, float64, (n_candidates, n_pairs)
        Each calibration pair's gain-fitted relative error
        (:func:`recon.analysis.early_stop.gain_fitted_error`, mean over channels) at
        each count, the pair reconstructed with the PSF
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

    @classmethod
    def load(cls, path) -> EarlyStop:
        """Read :meth:`to_dict`'s JSON (written by the calibration routine,
        ``calibrate psf-from-scenes``), or a calibration run's
        (a directory holding ``early_stop.json``).

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

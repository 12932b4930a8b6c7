"""A scene calibration's reconstruction recipe, fitted for one PSF, as a product.

:class:`EarlyStop` is what ``calibrate psf-from-scenes`` writes into its run
(``early_stop.json``) and what ``recon`` (by default with such a run's PSF, or with
``--early-stop``) and :func:`recon.analysis.early_stop.reconstruct_early_stopped`
read. Three numbers, each fitted on the calibration pairs
(:func:`recon.analysis.early_stop.fit_early_stop`):

1. ``psf_threshold``: the PSF estimated from a few scenes carries a floor of
   estimation noise spread over the whole sensor; it is soft-thresholded at this
   fraction of each channel's maximum (:func:`clean_psf`; a sparsity prior on the PSF,
   the caustic pattern of a diffuser being sparse, Kuo 2020 Sec. 2.2);
2. ``iterations``: the count of a prior-free non-negative FISTA (Eq. 2.5 without TV),
   stopped early (semi-convergence is the regulariser);
3. ``denoise_weight``: an isotropic TV denoising of the result (Chambolle 2004,
   :func:`denoise_tv`; round outlines, no axis-aligned blocks), 0 for none;

and, where it paid on held-out pairs, a ``field_response``: a smooth gain over the
field of view that multiplies the result (:mod:`recon.field_response`).

The recipe is tied to the PSF it was fitted for by a SHA-256 of the PSF's values
(:func:`psf_identity`) and refused with another. A file of the earlier form (a count
only) reads as threshold 0 and no denoising.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from dataclasses import replace as _replace
from pathlib import Path

import numpy as np

from .errors import ReconInputError
from .field_response import apply_field_response, check_field_response

__all__ = ["FILE", "MAX_ITERATIONS", "OFF", "SOLVE", "TRUSTED_RESIDUAL", "EarlyStop",
           "clean_psf", "denoise_tv", "named", "psf_identity", "psf_signature"]

#: The file name of the fit in a PSF-from-scenes calibration run.
FILE = "early_stop.json"
#: ``--early-stop off``: reconstruct a scene-calibrated run's PSF without its recipe.
OFF = "off"


def named(early_stop) -> bool:
    """Whether the ``early_stop`` option names a recipe (neither None nor :data:`OFF`).

    Parameters
    ----------
    early_stop : str or None
        The option's value: a calibration run or its ``early_stop.json``, ``"off"`` or
        None.
    """
    return early_stop is not None and early_stop != OFF


#: The solve the fitted count belongs to, in words (records).
SOLVE = "non-negative FISTA without a prior (recon.reconstruct method='fista', tv=0, l1=0)"
#: The percentile of the image that :func:`denoise_tv` scales to 1 before denoising.
DENOISE_PERCENTILE = 99.5
#: The most iterations a recipe may name (its candidates are checkpoints of one solve:
#: the calibration tries 10 to 200).
MAX_ITERATIONS = 10_000
#: The quality bar of a recipe: the mean held-out relative residual of its
#: calibration's leave-one-out PSFs (each pair predicted by the PSF estimated without
#: it, ``summary["held_out_mean"]``) above which the PSF explains too little of the
#: scenes for its recipe to be anyone's default (docs/reconstruction.md, "Scene
#: calibration"): the real pairs give ~0.08, PSFs that explain nothing (swapped names,
#: all-negative scenes) 1.06-1.20, the simulated bench's run of dim photographs 0.30
#: (its run of random patterns 0.058); a recipe above it is recorded as not trusted
#: (:attr:`EarlyStop.trusted`).
TRUSTED_RESIDUAL = 0.2


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


def psf_signature(psf) -> tuple:
    """A PSF's shape and the means of an 8 x 8 grid of blocks per channel: what an
    :class:`EarlyStop` compares a PSF with, to a relative 1e-4, when its SHA-256 differs
    only by float rounding (a dark level added to the PSF and subtracted again).

    Parameters
    ----------
    psf : array_like, (rows, cols) or (rows, cols, channels)

    Returns
    -------
    tuple of float
        ``(rows, cols, channels, block means...)``.
    """
    a = np.atleast_3d(np.asarray(psf, np.float64))
    rows, cols, channels = a.shape
    br, bc = max(rows // 8, 1), max(cols // 8, 1)
    a = a[:rows - rows % br, :cols - cols % bc]
    blocks = a.reshape(a.shape[0] // br, br, a.shape[1] // bc, bc, channels).mean(axis=(1, 3))
    return (float(rows), float(cols), float(channels), *blocks.ravel().tolist())


def _signature_matches(psf, stored) -> bool:
    mine = np.asarray(psf_signature(psf))
    ref = np.asarray(stored, float)
    if mine.shape != ref.shape or not np.array_equal(mine[:3], ref[:3]):
        return False
    scale = float(np.abs(ref[3:]).max()) or 1.0
    return bool(np.allclose(mine[3:], ref[3:], rtol=1e-4, atol=1e-6 * scale))


def clean_psf(psf, threshold: float) -> np.ndarray:
    """Soft-threshold a PSF at ``threshold`` times each channel's maximum.

    ``h <- max(h - threshold * max(h), 0)`` per channel: the estimation noise that a
    PSF calibrated from a few scenes spreads over the whole sensor goes, the caustics
    stay (their peaks lowered by the same amount).

    Parameters
    ----------
    psf : array_like, (rows, cols) or (rows, cols, channels), real
    threshold : float
        Fraction of the maximum, in [0, 1); 0 returns the PSF as float32.

    Returns
    -------
    ndarray, float32, the PSF's shape

    Raises
    ------
    ReconInputError
        ``threshold`` outside [0, 1).

    Examples
    --------
    >>> clean_psf(np.array([[0.0, 0.1], [0.5, 1.0]]), 0.2).tolist()
    [[0.0, 0.0], [0.30000001192092896, 0.800000011920929]]
    """
    t = float(threshold)
    if not 0.0 <= t < 1.0:
        raise ReconInputError(f"PSF threshold {threshold}: give a fraction of the maximum "
                              "in [0, 1)")
    h = np.asarray(psf, np.float32)
    if t == 0.0:
        return h.copy()
    peak = h.max(axis=(0, 1), keepdims=True)
    return np.maximum(h - np.float32(t) * peak, 0.0).astype(np.float32)


def denoise_tv(image, weight: float) -> np.ndarray:
    """Isotropic TV denoising of a reconstruction (Chambolle 2004, by
    :func:`skimage.restoration.denoise_tv_chambolle`), scale-free.

    The image is divided by its 99.5th percentile (``DENOISE_PERCENTILE``), so that
    ``weight`` means the same for any exposure, denoised (colour channels jointly), and
    scaled back.

    Parameters
    ----------
    image : array_like, (rows, cols) or (rows, cols, channels), real
    weight : float
        >= 0; 0 returns the image as float32.

    Returns
    -------
    ndarray, float32, the image's shape

    Raises
    ------
    ReconInputError
        A negative or non-finite weight.
    """
    w = float(weight)
    if not (np.isfinite(w) and w >= 0):
        raise ReconInputError(f"denoising weight {weight}: give a number >= 0")
    x = np.asarray(image, np.float32)
    scale = float(np.percentile(x, DENOISE_PERCENTILE))
    if w == 0.0 or not scale > 0:
        return x.copy()
    from skimage.restoration import denoise_tv_chambolle

    out = denoise_tv_chambolle(x / scale, weight=w, channel_axis=-1 if x.ndim == 3 else None)
    return (out * scale).astype(np.float32)


@dataclass(frozen=True)
class EarlyStop:
    """A fitted reconstruction recipe, tied to one PSF (module docstring;
    :mod:`recon.analysis.early_stop` fits it).

    Attributes
    ----------
    iterations : int
        The FISTA iteration count fitted (one of ``candidates``).
    candidates : tuple of int
        The counts tried.
    errors : ndarray, float64, (n_thresholds, n_candidates, n_weights, n_pairs)
        Each calibration pair's gain-fitted relative error
        (:func:`recon.analysis.early_stop.gain_fitted_error`, mean over channels) for
        each PSF threshold, count and denoising weight, the pair reconstructed with
        the PSF estimated without it.
    psf_sha256 : str
        :func:`psf_identity` of the PSF the recipe is for (the one estimated from every
        calibration pair, before thresholding).
    pairs : tuple of str
        The calibration pairs' names.
    psf_threshold : float
        The fitted PSF threshold (:func:`clean_psf`), one of ``thresholds``.
    denoise_weight : float
        The fitted weight of :func:`denoise_tv` (0: none), one of ``weights``.
    thresholds, weights : tuple of float
        The thresholds and denoising weights tried.
    psf_block_means : tuple of float
        :func:`psf_signature` of that PSF (empty in files of the earlier form).
    held_out_residual : float or None
        The calibration's mean held-out relative residual (:data:`TRUSTED_RESIDUAL`);
        None in files written before it was recorded.
    fit_bin_factor : int
        The binning the recipe was fitted at (its pairs and held-out PSFs averaged in
        ``fit_bin_factor`` x ``fit_bin_factor`` blocks; 1 in files of the earlier form);
        the recipe is applied at the PSF's own size.
    field_response : ndarray, float64, (n_rows, n_cols), or None
        The gain over the field that multiplies the denoised image
        (:mod:`recon.field_response`), or None: none (it did not pay on held-out
        pairs, or a file of the earlier form).
    field_gain_db : float or None
        What the field response bought the calibration pairs held out from its fit
        (mean dB, :func:`recon.analysis.field_response.held_out_field_gain_db`),
        recorded also when it did not pay; None when not fitted.
    lead_errors : ndarray, float64, (2, n_thresholds, n_candidates, n_pairs), or None
        The lead (green) channel's errors undenoised, each pair reconstructed with its
        held-out PSF (``[0]``) and with the PSF the recipe is for, estimated from every
        pair, itself included (``[1]``): the fit moved the held-out errors at each
        count halfway towards the in-sample ones by their gap
        (:func:`recon.analysis.early_stop.fit_early_stop`'s ``in_sample``); None: the
        held-out errors alone chose (and files of the earlier form).
    """

    iterations: int
    candidates: tuple
    errors: np.ndarray
    psf_sha256: str
    pairs: tuple = field(default=())
    psf_threshold: float = 0.0
    denoise_weight: float = 0.0
    thresholds: tuple = (0.0,)
    weights: tuple = (0.0,)
    psf_block_means: tuple = ()
    held_out_residual: float | None = None
    fit_bin_factor: int = 1
    field_response: np.ndarray | None = None
    field_gain_db: float | None = None
    lead_errors: np.ndarray | None = None

    @property
    def trusted(self) -> bool:
        """Whether the calibration's PSF explained its scenes well enough for the recipe
        to be a default: its held-out residual at most :data:`TRUSTED_RESIDUAL` (a file
        that records none: True)."""
        r = self.held_out_residual
        return r is None or r <= TRUSTED_RESIDUAL

    def __post_init__(self):
        e = np.asarray(self.errors, float)
        if e.ndim == 2:  # the earlier form: counts x pairs
            e = e[None, :, None, :]
        object.__setattr__(self, "errors", e)
        if self.lead_errors is not None:
            lead = np.asarray(self.lead_errors, float)
            if lead.shape != (2,) + e.shape[:2] + e.shape[3:]:
                raise ReconInputError(f"lead-channel errors of shape {lead.shape} for errors "
                                      f"of shape {e.shape}: give two (held out, in-sample) "
                                      "per threshold, count and pair")
            object.__setattr__(self, "lead_errors", lead)

    def clean_psf(self, psf, dark_level=None) -> np.ndarray:
        """``psf`` thresholded at ``psf_threshold`` (:func:`clean_psf`), after
        :meth:`check_psf`.

        Parameters
        ----------
        psf : ndarray
        dark_level : float, ndarray or str, optional
            A dark level that ``psf`` carries on top of the recipe's dark-subtracted
            PSF (a calibration run's PSF given with ``--dark``: the reconstruction
            subtracts it again); the threshold applies below it and it is added back.
            A word (``"auto"``, ``"none"``) or None: no level.

        Raises
        ------
        ReconInputError
            ``psf`` is not the recipe's PSF.
        """
        base = self.check_psf(psf, dark_level)
        cleaned = clean_psf(base, self.psf_threshold)
        return cleaned if dark_level is None or isinstance(dark_level, str) else (
            cleaned + np.asarray(dark_level, np.float32)).astype(np.float32)

    def finish(self, rec):
        """The reconstruction ``rec`` of the recipe's solve with its image denoised
        (:func:`denoise_tv` at ``denoise_weight``), multiplied by the field response
        if the recipe has one (:func:`recon.field_response.apply_field_response`), and
        the recipe recorded in ``info.extra["calibration"]``.

        Parameters
        ----------
        rec : recon.result.Reconstruction
            From the thresholded PSF, ``iterations`` FISTA iterations.

        Returns
        -------
        recon.result.Reconstruction
            A new one (``estimate`` is the solver's, not denoised).
        """
        rec.info.extra["calibration"] = self.record()
        return _replace(rec, image=apply_field_response(
            denoise_tv(rec.image, self.denoise_weight), self.field_response))

    def record(self) -> dict:
        """The recipe in a reconstruction's record (method, numbers, PSF hash)."""
        return {"method": self.method, "psf_threshold": self.psf_threshold,
                "iterations": int(self.iterations), "denoise_weight": self.denoise_weight,
                "field_response": self.field_response is not None,
                "field_gain_db": self.field_gain_db, "psf_sha256": self.psf_sha256}

    @property
    def method(self) -> str:
        """The calibration product in words, for records."""
        post = (f", then isotropic TV denoising at weight {self.denoise_weight:g}"
                if self.denoise_weight else "") + (
            f", then the field response (+{self.field_gain_db:.2f} dB on held-out pairs)"
            if self.field_response is not None else "")
        return (f"PSF soft-thresholded at {self.psf_threshold:g} of its maximum, {SOLVE}, "
                f"{self.iterations} iterations{post}: the least mean gain-fitted error (dB) "
                f"on {len(self.pairs) or 'the'} calibration pairs, each reconstructed with "
                "the PSF estimated without it" + (
                    ", moved halfway at each count towards the errors with the PSF "
                    "from every pair" if self.lead_errors is not None else "") + (
                    f" (binned {self.fit_bin_factor} x {self.fit_bin_factor})"
                    if self.fit_bin_factor > 1 else ""))

    def to_dict(self) -> dict:
        """JSON-able form (:meth:`from_dict` reads it back)."""
        return {"kind": "early-stop", "solve": SOLVE, "iterations": int(self.iterations),
                "psf_threshold": float(self.psf_threshold),
                "denoise_weight": float(self.denoise_weight),
                "candidates": [int(c) for c in self.candidates],
                "thresholds": [float(t) for t in self.thresholds],
                "weights": [float(w) for w in self.weights],
                "errors_axes": ["threshold", "iterations", "denoise_weight", "pair"],
                "errors": np.asarray(self.errors, float).round(6).tolist(),
                **({} if self.lead_errors is None else
                   {"lead_errors_axes": ["psf (held out, from every pair)", "threshold",
                                         "iterations", "pair"],
                    "lead_errors": np.asarray(self.lead_errors, float).round(6).tolist()}),
                "psf_sha256": self.psf_sha256, "pairs": list(self.pairs),
                "psf_block_means": [float(v) for v in self.psf_block_means],
                "fit_bin_factor": int(self.fit_bin_factor), "method": self.method,
                "field_response": (None if self.field_response is None else
                                   np.asarray(self.field_response).round(4).tolist()),
                **({} if self.field_gain_db is None else
                   {"field_gain_db": round(float(self.field_gain_db), 4)}),
                **({} if self.held_out_residual is None else
                   {"held_out_residual": float(self.held_out_residual),
                    "trusted": self.trusted})}

    @classmethod
    def from_dict(cls, d: dict) -> EarlyStop:
        """An :class:`EarlyStop` from :meth:`to_dict`'s form, validated: the fitted values
        must be among the candidates the file lists (the fit chooses among them), the
        counts whole numbers in [1, :data:`MAX_ITERATIONS`], the thresholds in [0, 1),
        the weights finite and >= 0, the errors (the lead channel's too) and the held-out
        residual finite.

        Raises
        ------
        ReconInputError
            Not such a record (another kind, or a field missing), or a value outside
            what a calibration writes (one line naming the field, the value and the
            values allowed).
        """
        if not isinstance(d, dict) or d.get("kind") != "early-stop":
            raise ReconInputError("not an early-stop calibration (no kind 'early-stop'); give "
                                  "the file a PSF-from-scenes calibration wrote")
        try:
            candidates = tuple(_count(c, "candidates") for c in d["candidates"])
            thresholds = tuple(_number(t, "thresholds", 0.0, 1.0)
                               for t in d.get("thresholds", (0.0,)))
            weights = tuple(_number(w, "weights", 0.0) for w in d.get("weights", (0.0,)))
            iterations = _among(_count(d["iterations"], "iterations"), candidates,
                                "iterations", "candidates")
            threshold = _among(_number(d.get("psf_threshold", 0.0), "psf_threshold", 0.0, 1.0),
                               thresholds, "psf_threshold", "thresholds")
            weight = _among(_number(d.get("denoise_weight", 0.0), "denoise_weight", 0.0),
                            weights, "denoise_weight", "weights")
            errors = np.asarray(d["errors"], float)
            if not np.all(np.isfinite(errors)):
                raise _bad("errors", "a non-finite value", "finite numbers")
            lead = d.get("lead_errors")
            if lead is not None:
                lead = np.asarray(lead, float)
                if not np.all(np.isfinite(lead)):
                    raise _bad("lead_errors", "a non-finite value", "finite numbers")
            residual = d.get("held_out_residual")
            residual = None if residual is None else _number(residual, "held_out_residual",
                                                             0.0)
            field_grid = d.get("field_response")
            field_grid = None if field_grid is None else check_field_response(field_grid)
            field_db = d.get("field_gain_db")
            if field_db is not None and not (
                    isinstance(field_db, int | float) and not isinstance(field_db, bool)
                    and np.isfinite(field_db)):
                raise _bad("field_gain_db", field_db, "a finite number")
            return cls(iterations, candidates, errors, str(d["psf_sha256"]),
                       tuple(d.get("pairs", ())), threshold, weight, thresholds, weights,
                       tuple(float(v) for v in d.get("psf_block_means", ())), residual,
                       _count(d.get("fit_bin_factor", 1), "fit_bin_factor"), field_grid,
                       None if field_db is None else float(field_db), lead)
        except ReconInputError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise ReconInputError(f"early-stop calibration incomplete ({exc!r}); give the "
                                  "file a PSF-from-scenes calibration wrote") from None

    @classmethod
    def load(cls, path) -> EarlyStop:
        """Read :meth:`to_dict`'s JSON (written by the calibration routine,
        ``calibrate psf-from-scenes``), or a calibration run's
        (a directory holding ``early_stop.json``); an :class:`EarlyStop` read already
        is returned as it is (a batch reads its recipe once and hands it to every
        frame's solve).

        Raises
        ------
        ReconInputError
            Missing or unreadable file, or not an early-stop calibration
            (:meth:`from_dict`).
        """
        if isinstance(path, EarlyStop):
            return path
        path = Path(path)
        path = path / FILE if path.is_dir() else path
        try:
            d = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise ReconInputError(f"cannot read the early-stop calibration {path}: "
                                  f"{exc.__class__.__name__}; give the JSON file a "
                                  "PSF-from-scenes calibration wrote") from None
        try:
            return cls.from_dict(d)
        except ReconInputError as exc:
            raise ReconInputError(f"{path}: {exc}") from None

    def check_psf(self, psf, dark_level=None) -> np.ndarray:
        """Refuse a PSF other than the one this recipe was fitted for.

        The same float32 values (SHA-256), or, less a ``dark_level`` the PSF carries,
        the same :func:`psf_signature` to a relative 1e-4.

        Parameters
        ----------
        psf : ndarray
        dark_level : float, ndarray or str, optional
            A dark level added to the recipe's PSF (see :meth:`clean_psf`); a word
            (``"auto"``, ``"none"``: the ``dark`` option's) or None: no level.

        Returns
        -------
        ndarray, float32
            The recipe's PSF (``psf`` less ``dark_level``).

        Raises
        ------
        ReconInputError
            ``psf`` is not that PSF (one line: the recipe belongs to its calibration).
        """
        a = np.asarray(psf, np.float32)
        if isinstance(dark_level, str):  # "auto", "none": no level on the PSF
            dark_level = None
        base = a if dark_level is None else (
            a - np.asarray(dark_level, np.float32)).astype(np.float32)
        if self._is_mine(base):
            return base
        if dark_level is not None and self._is_mine(a):
            level = (f"{float(dark_level):g} DN" if np.ndim(dark_level) == 0
                     else "the dark frame")
            raise ReconInputError(
                f"the PSF is the early-stop calibration's own PSF, already dark-subtracted, "
                f"but the dark level ({level}) would be subtracted from it again: give the "
                "calibration run itself as --psf (its PSF takes the frames' dark level), or "
                "--dark none for a raw that is dark-subtracted too")
        raise ReconInputError(
            "the early-stop calibration was fitted for another PSF (its SHA-256 "
            f"{self.psf_sha256[:12]}... differs); use it with the PSF of the same "
            "PSF-from-scenes calibration, or fit one for this camera")

    def _is_mine(self, psf) -> bool:
        return psf_identity(psf) == self.psf_sha256 or bool(
            self.psf_block_means and _signature_matches(psf, self.psf_block_means))


def _bad(field_name: str, value, allowed: str) -> ReconInputError:
    return ReconInputError(f"early-stop calibration: {field_name} {value!r} is not allowed; "
                           f"allowed: {allowed} (give the file a PSF-from-scenes "
                           "calibration wrote, or calibrate again)")


def _count(value, field_name: str) -> int:
    """A whole iteration count in [1, MAX_ITERATIONS] (2.7 and 1e9 refused)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
            np.isfinite(value) and float(value) == int(value)
            and 1 <= value <= MAX_ITERATIONS):
        raise _bad(field_name, value, f"whole numbers from 1 to {MAX_ITERATIONS}")
    return int(value)


def _number(value, field_name: str, low: float, high: float | None = None) -> float:
    """A finite number >= low (and < high)."""
    ok = (not isinstance(value, bool) and isinstance(value, int | float)
          and np.isfinite(value) and value >= low and (high is None or value < high))
    if not ok:
        raise _bad(field_name, value, f"finite numbers >= {low:g}" + (
            "" if high is None else f" and < {high:g}"))
    return float(value)


def _among(value, allowed: tuple, field_name: str, listed: str):
    """``value`` if it is one of ``allowed`` (the file's own candidate list)."""
    if value not in allowed:
        raise _bad(field_name, value, f"one of its {listed} {list(allowed)}")
    return value

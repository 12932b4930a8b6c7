"""A scene calibration's recipe (``early_stop.json``, :mod:`recon.early_stop`) as part
of its run's integrity record.

``calibrate psf-from-scenes`` writes the recipe beside the run's arrays
(:func:`write_run_recipe`) and records the file's SHA-256 in the run's summary
(``summary["early_stop"]["sha256"]``), with the calibration's held-out residual and
whether the recipe is trusted as a default (:data:`recon.early_stop.TRUSTED_RESIDUAL`).
``runs verify`` compares the file with that record (:func:`recipe_problems`): a recipe
edited, deleted or copied in from another run is damage. The reconstruction commands
read a run's recipe once, through :func:`load_run_recipe`, which refuses such a recipe
in one line with the fix: a deleted recipe never becomes the automatic method in
silence.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

__all__ = ["load_recipe", "load_run_recipe", "recipe_problems", "recorded_recipe",
           "write_run_recipe"]

log = logging.getLogger(__name__)

#: What a run's record of its recipe must equal in the file, for runs written before
#: the file's SHA-256 was recorded.
_RECORDED_FIELDS = ("iterations", "psf_threshold", "denoise_weight", "psf_sha256")


def write_run_recipe(store, fit, held_out_residual: float | None = None) -> dict:
    """Write ``fit`` as the run's ``early_stop.json`` and return the summary's record
    of it (what :func:`recipe_problems` and :func:`load_run_recipe` compare with).

    Parameters
    ----------
    store : instrument.runs.runstore.RunStore
        The calibration run (writable).
    fit : recon.early_stop.EarlyStop
        The recipe fitted for the run's PSF.
    held_out_residual : float, optional
        The calibration's mean held-out relative residual; recorded in the recipe,
        which is not trusted as a default above
        :data:`recon.early_stop.TRUSTED_RESIDUAL` (a warning is logged).

    Returns
    -------
    dict
        ``{"file", "sha256", "trusted", "held_out_residual", **fit.record()}``: put it
        in the run's summary as ``early_stop``.
    """
    from dataclasses import replace

    from recon.early_stop import FILE, TRUSTED_RESIDUAL

    from ..atomic import write_json

    if held_out_residual is not None:
        fit = replace(fit, held_out_residual=round(float(held_out_residual), 4))
    path = write_json(Path(store.path) / FILE, fit.to_dict())
    if not fit.trusted:
        log.warning("the PSF explains little of its calibration scenes (held-out residual "
                    "%.2f > %.2f): its recipe is recorded as not trusted and is no "
                    "reconstruction's default (--early-stop %s uses it anyway); check the "
                    "pairs' names and scenes, or capture brighter scenes",
                    fit.held_out_residual, TRUSTED_RESIDUAL, store.path)
    return {"file": FILE, **fit.record(), "sha256": _sha256(path.read_bytes()),
            "held_out_residual": fit.held_out_residual, "trusted": fit.trusted}


def recorded_recipe(run) -> dict | None:
    """The run's record of its recipe (``summary["early_stop"]``); None for a path that
    is no run store, or a run that wrote none."""
    from .run_paths import is_run_store

    if not is_run_store(run):
        return None
    try:
        attrs = json.loads((Path(run) / "zarr.json").read_text())["attributes"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    record = (attrs.get("summary") or {}).get("early_stop")
    return record if isinstance(record, dict) else None


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _problem(run, data: bytes | None, record: dict | None) -> str | None:
    """Why the recipe bytes ``data`` (None: no file) are not the run's own, or None."""
    from recon.early_stop import FILE

    path = Path(run) / FILE
    if record is None:
        return None if data is None else (
            f"{path} was not written by this run (it records no recipe; copied in from "
            "another run?): remove it, or give that run's recipe with --early-stop")
    if data is None:
        return (f"{path} is missing: the run wrote its scene-calibration recipe there; "
                "restore it from a backup copy of the run")
    if "sha256" in record:
        if _sha256(data) == record["sha256"]:
            return None
        return (f"{path} changed since the run wrote it (SHA-256 {_sha256(data)[:12]}..., "
                f"recorded {str(record['sha256'])[:12]}...: edited, or another run's "
                "recipe copied in); restore it from a backup copy of the run")
    try:  # a run written before the file's SHA-256 was recorded: its recorded numbers
        d = json.loads(data)
        changed = [k for k in _RECORDED_FIELDS if d.get(k) != record.get(k)]
    except (ValueError, AttributeError):
        changed = ["the whole file (not JSON)"]
    if not changed:
        return None
    return (f"{path} differs from what the run recorded of it ({', '.join(changed)}: "
            "edited, or another run's recipe copied in); restore it from a backup copy")


def recipe_problems(run) -> list[str]:
    """``runs verify``'s lines about the run's recipe: missing, changed, or one the run
    did not write (empty when intact or when the run has none)."""
    from recon.early_stop import FILE

    path = Path(run) / FILE
    try:
        data = path.read_bytes() if path.is_file() else None
    except OSError as exc:
        return [f"{path} cannot be read ({exc.__class__.__name__}); restore it"]
    problem = _problem(run, data, recorded_recipe(run))
    return [] if problem is None else [problem]


def load_run_recipe(run):
    """The recipe of calibration run ``run``, read once and checked against the run's
    record of it.

    Parameters
    ----------
    run : str or Path
        A ``calibrate psf-from-scenes`` run (or a folder holding ``early_stop.json``
        that is no run store: read as it is).

    Returns
    -------
    recon.early_stop.EarlyStop or None
        None when the run neither holds nor recorded a recipe.

    Raises
    ------
    recon.errors.ReconInputError
        The recipe is missing, changed since the run wrote it or not the run's own
        (one line with the fix: restore it, or ``--early-stop off`` for the automatic
        method), or it is unreadable or out of range
        (:meth:`recon.early_stop.EarlyStop.from_dict`).
    """
    from recon.early_stop import FILE, EarlyStop
    from recon.errors import ReconInputError

    from .run_paths import is_run_store

    path = Path(run) / FILE
    if not is_run_store(run):
        return EarlyStop.load(path) if path.is_file() else None
    try:
        data = path.read_bytes() if path.is_file() else None
    except OSError as exc:
        raise ReconInputError(f"cannot read {path}: {exc.__class__.__name__}") from None
    problem = _problem(run, data, recorded_recipe(run))
    if problem is not None:
        raise ReconInputError(f"{problem}; or pass --early-stop off to reconstruct with "
                              "the automatic method instead of the recipe")
    if data is None:
        return None
    try:
        d = json.loads(data)
    except ValueError:
        raise ReconInputError(f"cannot read the early-stop calibration {path}: not JSON; "
                              "give the JSON file a PSF-from-scenes calibration wrote"
                              ) from None
    try:
        return EarlyStop.from_dict(d)
    except ReconInputError as exc:
        raise ReconInputError(f"{path}: {exc}") from None


def load_recipe(early_stop):
    """The recipe an ``early_stop`` option names, read once: what a product records and
    every one of its frames is solved with (a later edit of the file changes neither).

    Parameters
    ----------
    early_stop : str, Path or recon.early_stop.EarlyStop
        A calibration run, its ``early_stop.json`` (both checked against the run's
        record, :func:`load_run_recipe`), another recipe file, or a recipe read
        already (returned as it is).

    Returns
    -------
    recon.early_stop.EarlyStop

    Raises
    ------
    recon.errors.ReconInputError
        As :func:`load_run_recipe`; a run that holds no recipe.
    """
    from recon.early_stop import FILE, EarlyStop
    from recon.errors import ReconInputError

    if isinstance(early_stop, EarlyStop):
        return early_stop
    path = Path(early_stop)
    run = path if path.is_dir() else path.parent if path.name == FILE else None
    if run is None:
        return EarlyStop.load(path)
    fit = load_run_recipe(run)
    if fit is None:
        raise ReconInputError(f"{run} holds no scene-calibration recipe ({FILE}); give a "
                              "calibrate psf-from-scenes run, or leave --early-stop out")
    return fit

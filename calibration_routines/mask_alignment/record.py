"""The alignment record on disk and the corrected mask it produces.

A record is a directory (``*.align``):

* ``captures.jsonl`` -- one line per spot reading, appended and flushed as it is
  taken (step, round, patch, software shift, stage pose, eta, exposure, times), so
  a crash or an abort loses nothing already measured;
* ``alignment.json`` -- the state after every step and the final report (status,
  camera affine, spot frequency, poses commanded, fitted t / theta / m / z / tilt,
  per-section shifts, eta table, stop reasons, capture count, times); replaced
  atomically (write then rename);
* ``corrected_mask.npy`` -- the model mask with each section's integer shift applied
  (float32 +1/-1, SLM footprint at mask resolution) that later holograms use, and
  ``seam_weight.npy`` (float32 0/1: 0 within the search radius of a boundary between
  sections with different shifts, where the stitched mask is unknown).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from diffuserlab.jsonio import json_line
from instrument.acquisition.plan import PlanError
from instrument.atomic import AppendLog, write_json

__all__ = ["AlignmentRecord", "corrected_mask", "load_alignment", "section_bounds"]


def section_bounds(slm_shape, sections) -> list[tuple[int, int, int, int]]:
    """SLM-pixel bounds ``(row0, row1, col0, col1)`` of a ``rows x cols`` section grid.

    Sections are listed row by row; their sizes differ by at most one pixel.
    """
    rows, cols = (int(v) for v in slm_shape)
    nr, nc = (int(v) for v in sections)
    if not (1 <= nr <= rows and 1 <= nc <= cols):
        raise PlanError(f"section grid {nr}x{nc} does not fit an SLM of {rows}x{cols} pixels")
    re = np.linspace(0, rows, nr + 1).round().astype(int)
    ce = np.linspace(0, cols, nc + 1).round().astype(int)
    return [(int(re[i]), int(re[i + 1]), int(ce[j]), int(ce[j + 1]))
            for i in range(nr) for j in range(nc)]


def corrected_mask(mask_model, shifts, sections, radius: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Stitch the model mask from per-section integer shifts.

    Section ``j`` (SLM pixels ``bounds_j``, i.e. mask pixels ``k * bounds_j``) takes the
    model content shifted by ``s_j``: ``C(x) = M(x - s_j)``, read from the model's bits
    (which extend ``margin`` mask px beyond the footprint).

    Parameters
    ----------
    mask_model : recon.optics.holo_display.MaskModel
        The software's mask model (its ``bits`` are used, never its ground truth).
    shifts : array_like, int (n_sections, 2)
        ``(sx, sy)`` per section, mask px; ``|s| <= margin``.
    sections : (int, int)
        Section grid (rows, cols) over the SLM.
    radius : int
        Seam half-width (mask px) marked unknown between differently shifted sections.

    Returns
    -------
    mask : numpy.ndarray
        float32 (R k, C k), +1 / -1.
    seam_weight : numpy.ndarray
        float32 (R k, C k), 0 on seams, 1 elsewhere.

    Raises
    ------
    instrument.acquisition.plan.PlanError
        Wrong number of shifts, or a shift beyond the modelled margin.
    """
    k, m = mask_model.k, mask_model.margin
    bounds = section_bounds(mask_model.slm_shape, sections)
    s = np.asarray(shifts, dtype=np.int64).reshape(-1, 2)
    if s.shape[0] != len(bounds):
        raise PlanError(f"{s.shape[0]} section shifts for {len(bounds)} sections")
    if np.abs(s).max(initial=0) > m:
        raise PlanError(f"a section shift {np.abs(s).max()} mask px exceeds the model's margin "
                        f"{m}; the mask is too far off for a piecewise fix (realign globally)")
    rows, cols = mask_model.slm_shape
    out = np.empty((rows * k, cols * k), np.float32)
    label = np.empty(out.shape, np.int64)
    model = mask_model.model
    for j, ((r0, r1, c0, c1), (sx, sy)) in enumerate(zip(bounds, s, strict=True)):
        out[r0 * k:r1 * k, c0 * k:c1 * k] = model[r0 * k + m - sy:r1 * k + m - sy,
                                                  c0 * k + m - sx:c1 * k + m - sx]
        label[r0 * k:r1 * k, c0 * k:c1 * k] = j
    shift_of = s[label]
    seam = np.zeros(out.shape, bool)
    for axis in (0, 1):
        diff = np.any(np.diff(shift_of, axis=axis) != 0, axis=-1)
        idx = np.nonzero(diff)
        for off in range(-radius + 1, radius + 1):
            moved = list(idx)
            moved[axis] = np.clip(idx[axis] + off, 0, out.shape[axis] - 1)
            seam[tuple(moved)] = True
    return out, (~seam).astype(np.float32)


class AlignmentRecord:
    """Writer of an alignment record directory (see the module docstring).

    Parameters
    ----------
    path : str or pathlib.Path
        Directory to create (must not exist, or be empty).
    """

    def __init__(self, path):
        self.path = Path(path)
        if self.path.exists() and any(self.path.iterdir()):
            raise PlanError(f"{self.path} already exists and is not empty; choose a new --out")
        self.path.mkdir(parents=True, exist_ok=True)
        self._log = AppendLog(self.path / "captures.jsonl")
        self.state: dict = {"schema": "diffuserlab.mask-alignment/1", "status": "running",
                            "started_host_s": time.time(), "steps": {}}
        self.save()

    def log(self, entry: dict) -> None:
        """Append one capture entry, written through to the file, whole or not at all:
        a write the system refuses midway (a full disk, a file-size limit) is cut back
        to the previous line, and the ``OSError`` propagates."""
        self._log.append(json_line(entry).encode("utf-8"))

    def save(self) -> None:
        """Write ``alignment.json`` atomically (:func:`instrument.atomic.atomic_path`: no
        temporary file is left when the write fails, e.g. on a full disk)."""
        write_json(self.path / "alignment.json", self.state)

    def save_mask(self, mask: np.ndarray, seam_weight: np.ndarray) -> None:
        """Write the corrected mask and its seam weight (float32 ``.npy``), each whole or
        not at all (:func:`instrument.writer.files.save_image`)."""
        from instrument.writer.files import save_image

        for name, array in (("corrected_mask.npy", mask), ("seam_weight.npy", seam_weight)):
            save_image(self.path / name, array.astype(np.float32))

    def close(self, status: str, **extra) -> None:
        """Final status (``completed``, ``aborted``, ``failed``) and save."""
        self.state.update(extra)
        self.state["status"] = status
        self.state["ended_host_s"] = time.time()
        self.save()
        self._log.close()


def load_alignment(path) -> dict:
    """Read an alignment record: the report plus ``corrected_mask`` / ``seam_weight`` arrays.

    Parameters
    ----------
    path : str or pathlib.Path
        The record directory written by ``diffuserlab align mask``.

    Returns
    -------
    dict
        ``alignment.json`` contents, with ``corrected_mask`` and ``seam_weight``
        (float32 (R k, C k)) when the run got that far, and ``captures`` (list of
        dicts).

    Raises
    ------
    FileNotFoundError
        ``path`` is not an alignment record.
    """
    p = Path(path)
    if not (p / "alignment.json").is_file():
        raise FileNotFoundError(f"{p} is not an alignment record (no alignment.json); pass the "
                                "directory written by `diffuserlab align mask --out`")
    rec = json.loads((p / "alignment.json").read_text())
    for name in ("corrected_mask", "seam_weight"):
        f = p / f"{name}.npy"
        if f.is_file():
            rec[name] = np.load(f)
    log = p / "captures.jsonl"
    text = log.read_text(encoding="utf-8") if log.is_file() else ""
    # a last line without its newline is an append cut short (power lost while writing)
    lines = text.split("\n")[:-1]
    rec["captures"] = [json.loads(line) for line in lines if line]
    return rec

"""Reading a run store: frames with their coordinates, checksums verified, the whole
run's integrity check and its summary (the read side of
:class:`instrument.runs.runstore.RunStore`, whose layout the module docstring there
describes)."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from diffuserlab.jsonio import jsonable

from .run_description import description_problems
from .run_integrity import (
    DamagedFrameError,
    RunStoreError,
    damaged_frames,
    frame_crc,
    lock_problem,
)
from .run_layout import FRAME_ARRAYS
from .run_recipe import recipe_problems
from .runstore_records import VIDEO_PLAN, record_problems

__all__ = ["FrameRecord", "RunReadingMixin"]


@dataclass(frozen=True)
class FrameRecord:
    """One stored frame: ``image`` (rows, cols) camera dtype, its plan ``point`` and
    ``tag``, and ``coords`` {name: float}."""

    index: int
    point: int
    tag: str
    image: np.ndarray
    coords: dict[str, float]


class RunReadingMixin:
    """The read side of :class:`instrument.runs.runstore.RunStore`: frames, their integrity
    and the run's summary (uses its ``_group``, ``_point``, ``_coord_names``,
    ``attrs``, ``layout_damage``, ``has_checksums`` and its layout accessors)."""

    def frame(self, index: int) -> FrameRecord:
        """Frame ``index`` with its point, tag and coordinates.

        Raises
        ------
        RunStoreError
            The frame is not written yet.
        """
        if not bool(self._group["done"][index]):  # one chunk
            raise RunStoreError(f"frame {index} of {self.path} is not written yet")
        image, row = self._read(index)
        return FrameRecord(int(index), int(self._point[index]), self.tag_of(index), image,
                           dict(zip(self._coord_names, row.tolist(), strict=True)))

    def _read(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Image and coordinate row of a done frame, checksum verified."""
        index = int(index)
        self.require_layout(*FRAME_ARRAYS)
        try:
            image = np.asarray(self._group["frames"][index])
            row = np.asarray(self._group["coords"][index], np.float64)
        except Exception as exc:  # a corrupt chunk fails to decode
            raise self._damage(index, f"its chunks cannot be read ({exc})") from exc
        try:
            crc = int(self._group["crc32"][index]) if self.has_checksums else None
        except Exception as exc:  # a corrupt checksum chunk: the frame cannot be verified
            chunk = f"crc32/c/{index // (self.shard_frames or 1)}"
            raise self._damage(index, f"its checksum chunk {chunk} cannot be read ({exc}), "
                               f"so the frame cannot be verified (restore {chunk} from a "
                               "backup copy of the run)") from exc
        if crc is not None and crc != frame_crc(image, row):
            chunk = f"frames/c/{index // (self.shard_frames or 1)}/0/0"
            missing = not (self.path / chunk).exists()
            raise self._damage(
                index, f"its chunk file {chunk} is missing (read as zeros)"
                if missing else "its data differ from the checksum recorded when it was "
                "written (a chunk file altered)")
        return image, row

    def _damage(self, index: int, reason: str) -> DamagedFrameError:
        return DamagedFrameError(self.path, index, self.point_of(index), reason,
                                 video=self.is_video)

    @property
    def is_video(self) -> bool:
        """A recorded video (plan ``video``): its frames cannot be captured again."""
        return self.attrs["plan"]["name"] == VIDEO_PLAN

    def intact_frames(self, frames: range | None = None) -> tuple[list[int], list[str]]:
        """The done frames of ``frames`` (default all) whose checksums hold, and one line
        per damaged one: what ``runs verify`` calls intact, for export and recon-run.

        Reads every done frame of the selection once.
        """
        frames = range(self.n_frames) if frames is None else frames
        done = self.done()
        ok, damaged = [], []
        for i in frames:
            if not done[i]:
                continue
            try:
                self._read(i)
            except DamagedFrameError as exc:
                damaged.append(str(exc))
            else:
                ok.append(int(i))
        return ok, damaged

    def point_frames(self, point: int, tag: str | None = None) -> tuple[np.ndarray, list[dict]]:
        """Frames (n, rows, cols) and coordinates of one point (optionally one tag).

        Raises
        ------
        RunStoreError
            The point (or one of its frames) is not written yet, or has no such tag.
        """
        r = self.frame_range(point)
        idx = [i for i in r if tag is None or self.tag_of(i) == tag]
        if not idx:
            raise RunStoreError(f"point {point} has no frames tagged {tag!r}")
        if not self.done(range(idx[0], idx[-1] + 1))[[i - idx[0] for i in idx]].all():
            raise RunStoreError(f"point {point} of {self.path} is not complete")
        read = [self._read(i) for i in idx]
        frames = np.stack([image for image, _ in read])
        coords = [row for _, row in read]
        return frames, [dict(zip(self._coord_names, c.tolist(), strict=True)) for c in coords]

    def coord_info(self) -> dict[str, dict[str, str | None]]:
        """Each coordinate's unit and dimension name as stored with the run.

        Returns
        -------
        dict
            ``{name: {"unit": str or None, "dim": str or None}}`` in
            ``coord_names`` order; None for a run written before units were
            stored (``""``: dimensionless).
        """
        attrs = self._group["coords"].attrs
        units, dims = attrs.get("units") or {}, attrs.get("dims") or {}
        return {n: {"unit": units.get(n), "dim": dims.get(n)} for n in self._coord_names}

    def coords_table(self) -> dict[str, np.ndarray]:
        """Every per-frame coordinate as ``{name: (n_frames,) float64}`` (NaN if unwritten)."""
        c = np.asarray(self._group["coords"][:])
        return {n: c[:, k] for k, n in enumerate(self._coord_names)}

    # ------------------------------------------------------------------ integrity
    def verify(self, on_progress: Callable[[int, int], None] | None = None) -> list[str]:
        """Check every done frame and every product (every written plane of a per-frame
        product) against its checksum, and the store against what the run recorded of
        itself (:func:`instrument.runs.runstore_records.record_problems`: done flags of a
        finished run, frame counts, products written, keys doubled in ``zarr.json``;
        :func:`instrument.runs.run_description.description_problems`: the ``ome`` blocks and
        dimension names other tools read; :func:`instrument.runs.run_recipe.recipe_problems`:
        a scene calibration's ``early_stop.json`` against the SHA-256 it recorded).

        Parameters
        ----------
        on_progress : callable, optional
            ``on_progress(checked, total)`` after each done frame is checked (a viewer
            shows how far a long run's check has come).

        Returns
        -------
        list of str
            One line per problem (frame index and point, or product and plane, with
            the fix); empty when the run is intact. A schema-1 run carries no
            checksums: only unreadable chunks are found (see ``has_checksums``).
        """
        problems = [line for name, line in self.layout_damage.items()
                    if not name.startswith("products/")]
        if not any(name in self.layout_damage for name in FRAME_ARRAYS):
            try:
                problems += [str(exc) for exc in self.damaged_frames(on_progress)]
                problems += record_problems(self)
            except RunStoreError as exc:  # its done flags cannot be read
                problems.append(str(exc))
        return (problems + self.damaged_products() + description_problems(self.path)
                + recipe_problems(self.path))

    def done_or_none(self) -> np.ndarray:
        """:meth:`~instrument.runs.runstore.RunStore.done`, or no frame done where the flags
        cannot be read (what a summary shows of a damaged run; :meth:`verify` names the
        damage)."""
        try:
            return self.done()
        except RunStoreError:
            return np.zeros(self.n_frames, bool)

    def damaged_frames(self, on_progress: Callable[[int, int], None] | None = None,
                       ) -> list[DamagedFrameError]:
        """Every done frame whose chunk is missing, unreadable or differs from its
        checksum, as the error reading it raises (empty when all are intact);
        ``on_progress(checked, total)`` after each frame
        (:func:`instrument.runs.run_integrity.damaged_frames`: read in blocks)."""
        return damaged_frames(self, on_progress)

    def point_of(self, index: int) -> int:
        """The plan point frame ``index`` belongs to."""
        return int(self._point[int(index)])

    # ------------------------------------------------------------------ summary
    def summary(self, *, verify: bool = True) -> dict[str, Any]:
        """A JSON-able overview: plan, status, progress, times, products, warnings, and
        ``problems`` (:meth:`verify`, every stored frame and product checked; None with
        ``verify=False``, which reads no frame: what a viewer shows at once, checking
        the run apart) with ``checksums`` (False for a schema-1 run, which carries
        none), and ``lock`` (who writes the run, or that its lock is stale; None when
        unlocked)."""
        a = self.refresh()
        done = self.done_or_none()
        points_done = np.ones(self.n_points, bool)
        np.logical_and.at(points_done, self._point, done)
        return jsonable({
            "path": str(self.path), "plan": a["plan"]["name"], "status": a["status"],
            "params": a["plan"]["params"], "points_done": int(points_done.sum()),
            "points": self.n_points, "frames_done": int(done.sum()), "frames": self.n_frames,
            "frame_shape": self.frame_shape, "created_utc": a["created_utc"],
            "started_utc": a["started_utc"], "ended_utc": a["ended_utc"],
            "software_version": a["software_version"], "schema_version": a["schema_version"],
            "note": a["note"], "resumes": a["resumes"], "warnings": a["warnings"],
            "error": a["error"], "summary": a.get("summary", {}),
            "products": {n: self.product_info(n) for n in self.products()},
            "coords": self.coord_info(),
            "checksums": self.has_checksums,
            "problems": self.verify() if verify else None,
            "lock": lock_problem(self.path) if self.lock_owner() is not None else None,
        })

    def to_json(self) -> str:
        """:meth:`summary` as indented JSON."""
        return json.dumps(self.summary(), indent=1)

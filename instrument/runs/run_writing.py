"""Writing a run store's frames and attributes: the write side of
:class:`instrument.runs.runstore.RunStore` (whose layout the module docstring there
describes). Each frame goes in the order frame, coordinates, checksum, done flag; a
value the run's dtype cannot hold exactly is refused, never wrapped or rounded.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from diffuserlab.jsonio import jsonable

from .ome import describe_run
from .run_integrity import RunStoreError, frame_crc
from .run_layout import RUN_ARRAYS, record_layout

__all__ = ["RunWritingMixin"]


class RunWritingMixin:
    """Frame and attribute writing of :class:`instrument.runs.runstore.RunStore` (uses its
    ``path``, ``writable``, ``attrs``, ``_group``, ``_coord_names``, ``_point``,
    ``_tag``, ``has_checksums`` and its layout properties)."""

    def _require_writable(self) -> None:
        if not self.writable:
            raise RunStoreError(f"{self.path} is open read-only; open it with mode='r+'")

    def write_frame(self, index: int, image: np.ndarray, coords: Mapping[str, float]) -> None:
        """Store frame ``index``: image, then coordinates, then its done flag.

        Raises
        ------
        RunStoreError
            Read-only store, index out of range, wrong image shape, unknown coordinate,
            or values the run's dtype cannot hold exactly (an integer run refuses
            NaN/inf, non-integer floats and values outside its range instead of
            wrapping or rounding them).
        """
        self._require_writable()
        if not 0 <= index < self.n_frames:
            raise RunStoreError(f"frame {index} is outside the run's 0..{self.n_frames - 1}")
        image = np.asarray(image)
        if image.shape != self.frame_shape:
            raise RunStoreError(f"frame shape {image.shape} differs from the run's "
                                f"{self.frame_shape}; keep the camera ROI/binning fixed")
        unknown = sorted(set(coords) - set(self._coord_names))
        if unknown:
            raise RunStoreError(f"unknown coordinates {unknown}; the run has "
                                f"{self._coord_names}")
        image = self._exact(index, image)
        row = np.array([float(coords.get(n, np.nan)) for n in self._coord_names])
        self._group["frames"][index] = image
        self._group["coords"][index] = row
        if self.has_checksums:
            self._group["crc32"][index] = frame_crc(image, row)
        self._group["done"][index] = 1

    def write_frames(self, start: int, images: np.ndarray, coord_rows: np.ndarray) -> None:
        """Store frames ``start .. start + len(images) - 1`` as one block: images, then
        coordinates, then checksums, then done flags (each a single write).

        Meant for sharded runs, written a whole shard at a time (``start`` a multiple
        of :attr:`~instrument.runs.runstore.RunStore.shard_frames`, ``len(images)`` equal to
        it except at the end of a recording); any block is stored correctly, a partial
        shard just costs a rewrite of that shard.

        Parameters
        ----------
        start : int
        images : ndarray, (m, rows, cols)
            Cast exactly to the run's dtype (as :meth:`write_frame`).
        coord_rows : ndarray, (m, n_coords) float64
            Coordinates in ``coord_names`` order (NaN where unknown).

        Raises
        ------
        RunStoreError
            Read-only store, block outside the run, wrong image or coordinate shape,
            or values the run's dtype cannot hold exactly.
        """
        self._require_writable()
        images = np.asarray(images)
        rows = np.asarray(coord_rows, np.float64)
        m = images.shape[0] if images.ndim == 3 else -1
        if images.ndim != 3 or images.shape[1:] != self.frame_shape:
            raise RunStoreError(f"frame block shape {images.shape} is not (m, "
                                f"{self.frame_shape[0]}, {self.frame_shape[1]}); keep the "
                                "camera ROI/binning fixed")
        if rows.shape != (m, len(self._coord_names)):
            raise RunStoreError(f"coordinate block shape {rows.shape} is not ({m}, "
                                f"{len(self._coord_names)}) for {self._coord_names}")
        if not (0 <= start and start + m <= self.n_frames) or m == 0:
            raise RunStoreError(f"frames {start}..{start + m - 1} are outside the run's "
                                f"0..{self.n_frames - 1}")
        images = np.stack([self._exact(start + j, im) for j, im in enumerate(images)])
        stop = start + m
        self._group["frames"][start:stop] = images
        self._group["coords"][start:stop] = rows
        if self.has_checksums:
            self._group["crc32"][start:stop] = np.array(
                [frame_crc(im, row) for im, row in zip(images, rows, strict=True)], np.uint32)
        self._group["done"][start:stop] = 1

    def _exact(self, index: int, image: np.ndarray) -> np.ndarray:
        """``image`` cast to the run's dtype, or RunStoreError if that would change a value."""
        dtype = self.frame_dtype
        if image.dtype == dtype:
            return image
        kind = image.dtype.kind
        if kind not in "biuf":
            raise RunStoreError(f"frame {index}: {image.dtype} data cannot be stored in the "
                                f"run's {dtype}; pass a real-valued image")
        if dtype.kind == "f" or np.can_cast(image.dtype, dtype, casting="safe"):
            return image.astype(dtype)
        info = np.iinfo(dtype)
        if kind == "f":
            bad = ~np.isfinite(image)
            if bad.any():
                raise RunStoreError(
                    f"frame {index}: {int(bad.sum())} NaN/inf pixels cannot be stored in the "
                    f"run's {dtype}; fix the source or pass a finite image")
            frac = image[image != np.round(image)]
            if frac.size:
                raise RunStoreError(
                    f"frame {index}: non-integer values (e.g. {frac.flat[0]:g}) cannot be "
                    f"stored exactly in the run's {dtype}; round them "
                    "first or pass the camera's integer frame")
        lo, hi = image.min(), image.max()
        if lo < info.min or hi > info.max:
            raise RunStoreError(
                f"frame {index}: values {lo:g}..{hi:g} are outside the run's {dtype} range "
                f"{info.min}..{info.max} (they would wrap); clip or rescale them first")
        return image.astype(dtype)

    def clear_point(self, point: int) -> None:
        """Mark a point's frames not done (before it is captured again)."""
        self._require_writable()
        r = self.frame_range(point)
        self._group["done"][r.start:r.stop] = 0

    def truncate(self, n_frames: int) -> None:
        """Cut a one-point run (a video) to its first ``n_frames`` frame slots, which
        must all be done: a recording that ended early or lost frames keeps no empty
        slots.

        Raises
        ------
        RunStoreError
            Read-only, a run of several points, or a slot below ``n_frames`` not done.
        """
        self._require_writable()
        n = int(n_frames)
        if self.n_points != 1 or not 0 <= n <= self.n_frames:
            raise RunStoreError(f"cannot cut {self.path} to {n_frames} frames: only a "
                                f"one-point run of at least that many frames can be cut")
        if not self.done(range(0, n)).all():
            raise RunStoreError(f"cannot cut {self.path} to {n} frames: not all are stored")
        for name in RUN_ARRAYS:
            arr = self._group[name]
            arr.resize((n, *arr.shape[1:]))
        record_layout(self._group, self.path, RUN_ARRAYS)
        self.attrs = dict(self._group.attrs)
        self._point, self._tag = self._point[:n], self._tag[:n]
        plan = dict(self.attrs["plan"], frames_per_point=[n])
        self.update_attrs(plan=plan)

    def update_attrs(self, **values: Any) -> None:
        """Set run attributes (status, times, summary, ...), all of them in one write of
        ``zarr.json`` (replaced atomically): a reader sees all or none of them.

        (Not ``group.attrs.update``: zarr's ``Attributes`` is a ``MutableMapping`` whose
        ``update`` sets one key at a time, each a write of the whole document, so a reader
        could see ``status="interrupted"`` before the ``closed_by`` set with it.)
        """
        self._require_writable()
        values = jsonable(values)
        self._group.update_attributes(values)
        self.attrs.update(values)
        if {"camera", "device_settings"} & set(values):  # the pitch or frame interval
            describe_run(self._group)
            self.attrs = dict(self._group.attrs)

    def add_warning(self, text: str) -> None:
        """Append a warning to the run's ``warnings`` attribute."""
        self.update_attrs(warnings=[*self.attrs.get("warnings", []), text])

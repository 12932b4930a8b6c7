"""A run compared with what it recorded of itself (part of
:meth:`RunStore.verify <instrument.runs.runstore.RunStore.verify>`).

Checksums (:mod:`instrument.runs.run_integrity`) catch a frame or product whose bytes
changed. They cannot see what vanished together with its own bookkeeping: a deleted
chunk of the ``done`` flags reads as "not written yet" (zarr returns the fill value),
a deleted product folder is simply not listed, and a ``zarr.json`` holding a key twice
is read as its last copy. So :func:`record_problems` compares the store with what the
run recorded when it was written:

* ``zarr.json`` (and ``products/zarr.json``) hold no key twice (a doubled ``plan``: JSON
  readers keep one copy silently);
* the plan's frame count (``frames_per_point``, one entry per point) equals the
  store's frame slots;
* a complete calibration run has every frame flagged done; a video that ended has
  exactly the frames its recording summary recorded flagged done, in order from frame
  0; a video killed while recording keeps a prefix of done frames (shards are written
  in order), so a gap before the last done frame is damage;
* every product the run recorded writing (``products/`` attribute ``written``) exists.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

__all__ = ["VIDEO_PLAN", "duplicate_keys", "index_ranges", "ranges_text", "record_problems",
           "video_cannot_continue"]

#: The plan name of a recorded video (:mod:`instrument.acquisition.video`).
VIDEO_PLAN = "video"


def video_cannot_continue(store) -> str | None:
    """Why ``store`` cannot be continued by a calibration resume, or None.

    A recording (:mod:`instrument.acquisition.video`) is not a plan of bench steps: what it did
    not record happened and is gone, so it is never continued. Its stored frames are
    kept and used as they are (``runs export --frames``, ``recon-run``).

    Parameters
    ----------
    store : RunStore
        An open run.

    Returns
    -------
    str or None
        The message naming the run, its stored frames and what to do instead; None
        for a calibration run.
    """
    if (store.attrs.get("plan") or {}).get("name") != VIDEO_PLAN:
        return None
    kept = int(store.done().sum())
    return (f"{store.path} is a video recording (capture video), not a calibration run: a "
            f"recording cannot be continued, what it did not record is gone. Its {kept} "
            f"stored frames are kept: export them (diffuserlab runs export {store.path} "
            f"--frames --out FRAMES.tif), reconstruct them (diffuserlab recon-run "
            f"{store.path} --psf PSF), or record a new video (diffuserlab capture video)")


def index_ranges(indices: Iterable[int]) -> list[list[int]]:
    """Sorted integer indices as inclusive ranges, e.g. ``[3, 4, 5, 9] -> [[3, 5], [9, 9]]``."""
    out: list[list[int]] = []
    for i in sorted(int(v) for v in indices):
        if out and i <= out[-1][1] + 1:
            out[-1][1] = max(out[-1][1], i)
        else:
            out.append([i, i])
    return out


def ranges_text(indices: Iterable[int]) -> str:
    """``"3-5, 9"`` for the indices ``[3, 4, 5, 9]``."""
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in index_ranges(indices))


def duplicate_keys(path: Path) -> list[str]:
    """Dotted names of the keys a JSON file holds more than once (empty when none, or
    when the file cannot be read: that is reported where it is opened)."""
    found: list[str] = []

    def hook(pairs):
        seen = set()
        for key, _ in pairs:
            if key in seen:
                found.append(key)
            seen.add(key)
        return dict(pairs)

    try:
        json.loads(Path(path).read_text(), object_pairs_hook=hook)
    except (OSError, ValueError):
        return []
    return found


def _chunks(store, indices: np.ndarray) -> str:
    per = store.shard_frames or 1
    return ", ".join(f"done/c/{k}" for k in sorted({int(i) // per for i in indices}))


def record_problems(store) -> list[str]:
    """What ``store`` lacks against its own record (module notes), one line each.

    Parameters
    ----------
    store : instrument.runs.runstore.RunStore

    Returns
    -------
    list of str
        Each line names the damage and what to do; empty when the store matches.
    """
    problems = []
    a = store.attrs
    for name in ("zarr.json", "products/zarr.json"):
        for key in duplicate_keys(store.path / name):
            problems.append(
                f"{store.path}/{name} holds the key {key!r} twice (a JSON reader keeps only "
                "one copy, which may not be the run's): restore the file from a backup copy "
                "of the run")
    plan = a["plan"]
    per_point = list(plan.get("frames_per_point", []))
    if len(per_point) != len(plan.get("points", [])) or sum(per_point) != store.n_frames:
        problems.append(
            f"{store.path}/zarr.json describes {len(plan.get('points', []))} points of "
            f"{sum(per_point)} frames but the store holds {store.n_frames} frame slots: its "
            "plan does not match the frames; restore zarr.json from a backup copy")
    done = store.done()
    video = plan.get("name") == VIDEO_PLAN
    status = a.get("status")
    recorded = ((a.get("summary") or {}).get("recording") or {}).get("recorded")
    if video and isinstance(recorded, int):  # frames 0 .. recorded - 1, in order
        expected, why = np.arange(store.n_frames) < recorded, f"its recording summary " \
            f"recorded {recorded} frames"
    elif video:  # killed while recording: completed shards are a prefix
        last = np.flatnonzero(done)
        expected = np.arange(store.n_frames) <= (last[-1] if last.size else -1)
        why = "later frames are (a recording writes in order)"
    else:
        expected = np.full(store.n_frames, status == "complete")
        why = "the run is complete"
    missing = np.flatnonzero(expected & ~done)
    if missing.size:
        problems.append(
            f"frames {ranges_text(missing)} of {store.path} are not flagged done but {why}: "
            f"their done flags ({_chunks(store, missing)}) were deleted or altered; "
            "restore them from a backup copy of the run")
    extra = np.flatnonzero(~expected & done)
    if video and isinstance(recorded, int) and extra.size:
        problems.append(
            f"frames {ranges_text(extra)} of {store.path} are flagged done but {why}: "
            "restore the run from a backup copy")
    have = set(store.products())
    for name in store.recorded_products():
        if name not in have:
            problems.append(
                f"product {name!r} of {store.path} is missing (the run recorded writing it; "
                f"products/{name} was deleted): "
                + ("compute it again with its command (recon-run) and --overwrite" if video
                   else f"recompute it: diffuserlab calibrate resume {store.path} BENCH.toml"))
    return problems

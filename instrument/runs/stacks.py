"""PSF stacks and frames in and out of run stores: TIFF/.npy import and export.

* :func:`load_psf_stack` reads a PSF stack with its depths from a run store
  (``products/psf_stack``), a TIFF written by :func:`export_tiff` (depths in its
  metadata) or any TIFF/.npy with the depths given;
* :func:`pick_depth` chooses the PSF of one depth for a 2D reconstruction;
* :func:`export_tiff` writes a product or the raw frames as an ImageJ hyperstack or
  an OME-TIFF (axes, pixel size, spacing, units) with their attributes or
  coordinates as JSON metadata, for Fiji and other tools;
* :func:`import_psf_stack` stores a stack from elsewhere as a run, so every tool
  reads PSFs one way.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..atomic import missing_dirs, remove_empty_dirs
from .coords import coord_specs
from .runstore import RunStore, RunStoreError, discard_partial_run
from .tiff_export import read_tiff_metadata

__all__ = ["IMPORTED_PLAN", "MIN_PLANE_PX", "dark_subtracted", "export_tiff", "import_psf_stack",
           "load_psf_stack", "pick_depth"]

#: Fewest pixels along each side of a PSF plane: a smaller array is a wrong file or a
#: wrong axis order, not a measurement (the dark corner psf[5:15, 5:15] alone needs 6).
MIN_PLANE_PX = 8


def _depths(depths_mm, n: int, source: str) -> list[float]:
    if depths_mm is None:
        raise RunStoreError(f"{source} carries no depths; give one depth per plane, in mm")
    try:
        depths = [float(z) for z in np.atleast_1d(np.asarray(depths_mm, float))]
    except (TypeError, ValueError):
        raise RunStoreError(f"{source}: its depths {depths_mm!r} are not numbers of mm; fix "
                            "the depths it records, or give one depth per plane, in mm") from None
    if len(depths) != n:
        raise RunStoreError(f"{source} has {n} planes but {len(depths)} depths were given")
    if not all(np.isfinite(depths)) or min(depths) <= 0:
        raise RunStoreError(f"depths {depths} must be finite and > 0 mm")
    return depths


#: The plan name of a run store made by :func:`import_psf_stack`: its stack is as imported.
IMPORTED_PLAN = "imported-psf-stack"


def dark_subtracted(path: str | Path) -> bool:
    """Whether the PSF (stack) at ``path`` is a calibration run's, dark-subtracted by the
    routine that measured it (``--dark auto`` then needs the frames' level,
    :func:`instrument.processing.reconstruct_files.resolve_dark`); a file, or a run store made by
    :func:`import_psf_stack`, holds the PSF as its maker left it.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
    """
    path = Path(path)
    if not path.is_dir():
        return False
    try:
        plan = RunStore.open(path).attrs.get("plan") or {}
    except RunStoreError:  # not a run: reading it as a PSF reports why
        return False
    return plan.get("name") != IMPORTED_PLAN


def load_psf_stack(path: str | Path, depths_mm: Sequence[float] | None = None,
                   product: str = "psf_stack") -> tuple[np.ndarray, list[float], dict]:
    """A PSF stack, its depths and its attributes.

    Parameters
    ----------
    path : str or Path
        A run store directory (``*.zarr``), a TIFF (3D, or 2D for one plane) or a
        ``.npy`` file.
    depths_mm : sequence of float, optional
        Depth of each plane, mm; needed unless the file records them (a run store,
        or a TIFF from :func:`export_tiff`); if both, they must agree.
    product : str
        Which product of a run store (default ``psf_stack``).

    Returns
    -------
    stack : ndarray, float32, (n_depths, rows, cols)
        Or (n_depths, rows, cols, channels): a colour PSF of a run store, whose
        product records its ``channels`` (``calibrate psf-from-scenes``).
    depths_mm : list of float
    attrs : dict
        The stored attributes (empty for plain files).

    Raises
    ------
    RunStoreError
        Unreadable or unsupported file, a run without the product, missing or
        mismatched depths, values that are not real numbers (complex, bool, text)
        or not finite, planes smaller than :data:`MIN_PLANE_PX` on a side.
    """
    import tifffile

    path = Path(path)
    attrs: dict = {}
    if path.is_dir():
        stack, attrs = RunStore.open(path).product(product)
        recorded = attrs.get("depths_mm")
    elif path.suffix.lower() in (".tif", ".tiff"):
        try:
            with tifffile.TiffFile(path) as tif:
                stack = tif.asarray()
                meta = read_tiff_metadata(tif)
        except (OSError, ValueError) as exc:
            raise RunStoreError(f"cannot read TIFF {path}: {exc}") from exc
        attrs = dict(meta or {})
        recorded = attrs.get("depths_mm")
    elif path.suffix.lower() == ".npy":
        try:
            stack = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as exc:  # EOFError: an empty file
            raise RunStoreError(f"cannot read {path}: {exc}") from exc
        recorded = None
    else:
        raise RunStoreError(f"{path}: use a run store (.zarr directory), a TIFF or a .npy file")
    stack = _real_stack(np.asarray(stack), path)
    if stack.ndim == 2:
        stack = stack[None]
    colour = stack.ndim == 4 and len(attrs.get("channels") or ()) == stack.shape[3]
    if stack.ndim != 3 and not colour:
        raise RunStoreError(f"{path} holds a {stack.ndim}-D array; a PSF stack is "
                            "(depths, rows, cols)")
    if min(stack.shape[1:3]) < MIN_PLANE_PX:
        raise RunStoreError(f"{path} holds planes of {stack.shape[1]}x{stack.shape[2]} pixels; "
                            f"a PSF needs at least {MIN_PLANE_PX}x{MIN_PLANE_PX} (wrong file "
                            "or wrong axis order?)")
    bad = int(np.count_nonzero(~np.isfinite(stack)))
    if bad:
        raise RunStoreError(f"{path} holds {bad} non-finite values (NaN or inf); fix or "
                            "re-measure those pixels")
    if recorded is not None:
        recorded = _depths(recorded, len(stack), str(path))
    if recorded is not None and depths_mm is not None and (
            len(recorded) != len(depths_mm) or not np.allclose(recorded, depths_mm)):
        raise RunStoreError(f"{path} records depths {_fmt(recorded)} mm, not "
                            f"{_fmt(depths_mm)}: leave out --depths (the recorded ones are "
                            "used) or give the recorded ones")
    depths = _depths(recorded if recorded is not None else depths_mm, len(stack), str(path))
    return stack, depths, attrs


def _real_stack(array: np.ndarray, path: Path) -> np.ndarray:
    """``array`` as float32 if it holds real numbers (not complex, bool, text, objects)."""
    if array.dtype == bool or not (np.issubdtype(array.dtype, np.integer)
                                   or np.issubdtype(array.dtype, np.floating)):
        raise RunStoreError(f"{path} holds {array.dtype} values; a PSF stack holds real "
                            "numbers (integer or floating point intensities)")
    return array.astype(np.float32, copy=False)


def pick_depth(stack: np.ndarray, depths_mm: Sequence[float], depth_mm: float | None,
               rel_tol: float = 0.05) -> tuple[np.ndarray, float]:
    """The PSF of the plane nearest ``depth_mm`` (None: the only plane).

    Raises
    ------
    RunStoreError
        No depth given for a multi-plane stack, a depth that is not finite and > 0,
        or the nearest plane is more than ``rel_tol`` (relative) away.
    """
    if depth_mm is not None and not (np.isfinite(depth_mm) and depth_mm > 0):
        raise RunStoreError(f"--depth {depth_mm:g} mm must be finite and > 0")
    if depth_mm is None:
        if len(stack) != 1:
            raise RunStoreError(
                f"the PSF stack has {len(stack)} depths ({_fmt(depths_mm)} mm); choose one "
                "with --depth")
        return stack[0], float(depths_mm[0])
    k = int(np.argmin(np.abs(np.asarray(depths_mm) - depth_mm)))
    if abs(depths_mm[k] - depth_mm) > rel_tol * depth_mm:
        raise RunStoreError(f"no PSF within {rel_tol:.0%} of {depth_mm:g} mm (nearest "
                            f"{depths_mm[k]:g} mm); the stack has {_fmt(depths_mm)} mm")
    return stack[k], float(depths_mm[k])


def _fmt(depths) -> str:
    return ", ".join(f"{z:.4g}" for z in depths)


def export_tiff(run: str | Path, out: str | Path, *, product: str | None = "psf_stack",
                fmt: str = "auto") -> tuple[Path, list[str]]:
    """Write a run's product (or, with ``product=None``, its frames) as a TIFF: an
    ImageJ hyperstack or an OME-TIFF (:func:`instrument.runs.tiff_export.write_tiff`:
    axes, pixel size, z spacing or frame interval and units from the run's OME-Zarr
    description, :mod:`instrument.runs.ome`).

    The product's attributes (depths, exposures, units, ...), or the frames' plan
    points, tags, indices and coordinates, go into the TIFF's JSON metadata, which
    :func:`load_psf_stack` reads back. Frames: the stored frames whose checksums
    hold (:meth:`RunStore.intact_frames`: a recording killed midway exports what it
    stored; a damaged frame is left out), their run indices in the metadata
    (``frame_indices``), one slice label per frame (index, tag, point).

    Parameters
    ----------
    fmt : {"auto", "imagej", "ome"}
        "auto": OME-TIFF for a ``.ome.tif(f)`` name, else an ImageJ hyperstack.

    Returns
    -------
    out : Path
    skipped : list of str
        One line per frame range left out (not stored) or damaged frame.

    Raises
    ------
    RunStoreError
        No such run or product, or no intact frame.
    """

    from ..atomic import atomic_path
    from .ome import frame_axis, frame_pitch_um, product_axes, space_axes
    from .tiff_export import tiff_format, write_tiff

    fmt = tiff_format(out, fmt)
    store = RunStore.open(run)
    out = Path(out)  # its folder is made by atomic_path once the data is read
    labels = delta_t = None
    if product is not None:
        array, attrs = store.product(product)
        meta = {**attrs, "run": str(store.path), "product": product}
        found = product_axes(product, array.shape, store.product_attrs(product),
                             store.attrs)
        axes = None if found is None else found[0]
        if attrs.get("per_frame") or "frame_indices" in attrs:  # a plane per frame
            delta_t = _frame_times_s(store, attrs.get("frame_indices")
                                     or range(array.shape[0]))
    skipped: list[str] = []
    if product is None:
        from .runstore_records import ranges_text

        keep, skipped = store.intact_frames()
        unstored = np.flatnonzero(~store.done())
        if unstored.size:
            skipped.insert(0, f"frames {ranges_text(unstored)} of {store.path} are not "
                           "flagged done (not stored; runs verify says whether that is "
                           "damage)")
        if not keep:
            raise RunStoreError(f"{run}: no stored frame is intact ({'; '.join(skipped)})")
        records = [store.frame(i) for i in keep]
        array = np.stack([r.image for r in records])
        coords = store.coords_table()
        meta = {"run": str(store.path), "frame_indices": keep,
                "points": [r.point for r in records], "tags": [r.tag for r in records],
                "coords": {k: v[keep].tolist() for k, v in coords.items()}}
        axes = [frame_axis(store.attrs), *space_axes(frame_pitch_um(store.attrs))]
        labels = [f"frame {r.index} {r.tag} point {r.point}" for r in records]
        delta_t = _frame_times_s(store, keep)
    with atomic_path(out) as tmp:
        write_tiff(tmp, array, axes, meta, fmt=fmt, frames=product is None, labels=labels,
                   delta_t_s=delta_t)
    return out, skipped


def _frame_times_s(store: RunStore, indices) -> list[float] | None:
    """The recorded times of frames ``indices``, s from the first of them: the
    camera's timestamps (``device_timestamp_s``), else the host's; None when neither
    is recorded for every one of them."""
    coords = store.coords_table()
    indices = [int(i) for i in indices]
    for name in ("device_timestamp_s", "host_timestamp_s"):
        values = coords.get(name)
        if values is None or not indices or max(indices) >= len(values):
            continue
        times = np.asarray(values, np.float64)[indices]
        if np.all(np.isfinite(times)):
            return (times - times[0]).tolist()
    return None


def import_psf_stack(source: str | Path, out: str | Path, *,
                     depths_mm: Sequence[float] | None = None, note: str = "",
                     overwrite: bool = False, pitch_um: float | None = None) -> RunStore:
    """Store a PSF stack from a TIFF or .npy file (with its depths) as a run.

    The run has no frames, only the ``psf_stack`` product with ``depths_mm``
    ascending, and ``source`` in its attributes. With ``pitch_um`` (the sensor's
    pixel pitch, micrometres, of the stack's pixels) the run records it as its
    camera's (``camera.pixel_pitch_um``), so its OME-Zarr description, ``recon`` and
    ``recon3d`` give the stack and what is reconstructed from it a pixel size in
    micrometres; without it, ``y``, ``x`` have no unit.

    Raises
    ------
    diffuserlab.errors.InputError
        ``pitch_um`` is not a finite number > 0
        (:func:`instrument.options.check_pitch_um`), before anything is read.
    RunStoreError
        Unreadable file, missing depths, or ``out`` exists.
    OSError
        The store cannot be written (a full disk: the partial run is removed).
    """
    from ..options import check_pitch_um

    pitch_um = check_pitch_um(pitch_um, "pitch_um")
    stack, depths, attrs = load_psf_stack(source, depths_mm)
    order = np.argsort(depths)
    stack, depths = stack[order], [depths[i] for i in order]
    store, made = None, missing_dirs(out)
    try:  # whole or not at all: a run this call created is removed when it fails
        store = RunStore.create(out, plan_name=IMPORTED_PLAN,
                                plan_params={"source": str(source)},
                                points=[{"z_mm": z} for z in depths],
                                frame_tags=[[] for _ in depths], frame_shape=stack.shape[1:],
                                frame_dtype=np.float32, coord_names=["exposure_s"],
                                coord_specs=coord_specs(["exposure_s"]), note=note,
                                overwrite=overwrite, keep_lock=True)
        if pitch_um is not None:  # before the product: its description reads it
            store.update_attrs(camera={"id": None, "pixel_pitch_um": float(pitch_um)})
        store.write_product("psf_stack", stack, depths_mm=depths, source=str(source),
                            units=attrs.get("units", "as imported"))
        store.update_attrs(status="complete",
                           summary={"depths_mm": depths, "source": str(source)})
        store.unlock()  # locked from its creation until written
    except BaseException:  # never a run another process created at ``out`` meanwhile
        if store is not None:
            discard_partial_run(out, made, token=store.creation_token)
        else:  # refused, or RunStore.create removed its own half-made run
            remove_empty_dirs(made)
        raise
    return store

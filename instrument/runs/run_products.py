"""Products of a run store: arrays derived from its frames (:mod:`instrument.runs.runstore`).

Each image product is its own OME-Zarr image group ``RUN.zarr/products/NAME`` with
its array at ``products/NAME/0``; a table or LUT is an array ``products/NAME``; a run
written before the image groups holds every product as an array ``products/NAME``
(:mod:`instrument.runs.product_nodes` finds a product's array in either layout). Two kinds:

* a *whole* product (a PSF stack, a dark frame, a LUT) is written at once by
  :meth:`ProductsMixin.write_product`; its attribute ``crc32`` holds one CRC-32 per
  plane (3-D) or one for the array;
* a *per-frame* product (a batch reconstruction of a video, ΔF/F) has one plane per
  recorded frame, written one at a time in any order by
  :meth:`ProductsMixin.write_product_frame` and resumable: the hidden arrays
  ``NAME__crc32`` and ``NAME__done`` (one element per plane, one chunk each) hold a
  plane's checksum and done flag, written after the plane, so a crash loses at most
  the plane in flight and :meth:`ProductsMixin.product_frames_done` says what is left.

Reading verifies: a plane whose chunk was deleted (zarr would return zeros) or
altered is an error naming the product and plane, never data.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from diffuserlab.jsonio import jsonable

from ..writer.ome_axes import write_depth_coordinate
from .ome import (
    describe_products,
    product_axes,
    product_dims,
    with_source,
)
from .product_nodes import (
    HIDDEN_SUFFIXES,
    IMAGE_ARRAY,
    MOVING,
    array_key,
    product_array,
    product_arrays,
)
from .run_description import forget_description, record_description
from .run_integrity import RunStoreError, product_crcs
from .run_layout import forget_layout, record_layout

__all__ = ["ProductsMixin"]

#: Suffixes of the hidden arrays of a per-frame product.
_DONE, _CRC = "__done", "__crc32"
#: Attribute of ``products/`` listing every product written (damage if one goes missing).
_WRITTEN = "written"
#: Attribute of a per-frame product: the command that finishes it (names the run's path).
_HINT = "resume_hint"
#: The name of a stack's depth coordinate array in its image group (its first axis).
DEPTH_AXIS = "z"


class ProductsMixin:
    """Product methods of :class:`instrument.runs.runstore.RunStore` (needs ``path``,
    ``_group`` and ``_require_writable``)."""

    # ------------------------------------------------------------------ whole products
    def write_product(self, name: str, array: np.ndarray, **attrs: Any) -> None:
        """Store a derived array as product ``name`` (replacing it) with attributes: an
        image as the group ``products/name`` holding the array ``0`` and its ``ome``
        block, a table or LUT as the array ``products/name``. A stack with one depth
        per plane (``depths_mm``) also gets the coordinate array ``products/name/z``
        (the planes' true depths in mm,
        :func:`instrument.writer.ome_axes.write_depth_coordinate`), recorded with the
        product and checked against ``depths_mm`` when it is read (``product``)."""
        self._require_writable()
        _check_name(name)
        array = np.asarray(array)
        self._delete_product(name)
        chunks = (1, *array.shape[1:]) if array.ndim == 3 else array.shape or (1,)
        key, arr = self._create_product_array(name, array.shape, attrs, chunks=chunks,
                                              dtype=array.dtype)
        arr[...] = array
        arr.update_attributes(jsonable({**attrs, "crc32": product_crcs(array)}))
        keys = [key]
        if key != name and array.ndim == 3 and \
                arr.metadata.dimension_names[0] == DEPTH_AXIS:  # a stack: its true depths
            if write_depth_coordinate(self._group["products"][name], DEPTH_AXIS,
                                      attrs.get("depths_mm"), array.shape[0]):
                keys.append(f"{name}/{DEPTH_AXIS}")
        self._note_product(name, keys)
        describe_products(self._group["products"], self.attrs, [name])  # (attrs re-read)

    def _create_product_array(self, name: str, shape, attrs, **kwargs) -> tuple[str, Any]:
        """Create product ``name``'s array (:mod:`instrument.runs.product_nodes`): in its own
        image group for an image (:func:`instrument.runs.ome.product_axes`), else directly
        in ``products/``; its key there and the array."""
        products = self._group["products"]
        image = product_axes(name, shape, attrs, self.attrs) is not None
        dims = self._product_dims(name, shape, attrs, image)
        if not image:
            return name, products.create_array(name, shape=shape, dimension_names=dims,
                                               **kwargs)
        arr = products.create_group(name).create_array(IMAGE_ARRAY, shape=shape,
                                                       dimension_names=dims, **kwargs)
        return f"{name}/{IMAGE_ARRAY}", arr

    def recorded_products(self) -> list[str]:
        """Names of the products the run recorded writing (the ``written`` attribute of
        ``products/``; empty for runs written before it was kept): a product listed
        here but absent from :meth:`products` was deleted."""
        return list(self._group["products"].attrs.get(_WRITTEN, []))

    def _note_product(self, name: str, arrays: Sequence[str]) -> None:
        """List ``name`` as written and record the layout and dimension names of its
        ``arrays`` (:mod:`instrument.runs.run_layout`, :mod:`instrument.runs.run_description`)."""
        products = self._group["products"]
        record_layout(products, self.path / "products", arrays)
        record_description(products, self.path / "products", arrays)
        written = list(products.attrs.get(_WRITTEN, []))
        if name not in written:
            products.attrs[_WRITTEN] = sorted([*written, name])

    def products(self) -> list[str]:
        """Names of the stored products (the hidden arrays of per-frame ones left out)."""
        return list(product_arrays(self._group["products"]))

    def product_info(self, name: str) -> dict[str, Any]:
        """``{"shape", "dtype"}`` of a product, with ``planes_done`` for a per-frame one
        and ``orientation`` where the product records it (a reconstruction: the model
        grid, :data:`recon.io.DATA_ORIENTATION`)."""
        arr = self._product_array(name, check=False)
        info: dict[str, Any] = {"shape": list(arr.shape), "dtype": str(arr.dtype)}
        if "orientation" in arr.attrs:
            info["orientation"] = arr.attrs["orientation"]
        if self._product_damage(name):
            info["damaged"] = True
        elif arr.attrs.get("per_frame"):
            info["planes_done"] = int(self.product_frames_done(name).sum())
        return info

    def product(self, name: str) -> tuple[np.ndarray, dict]:
        """A product's array and attributes, verified against its checksums.

        Raises
        ------
        RunStoreError
            No such product (the run is incomplete or the plan makes none), a
            per-frame product with planes still missing, or a damaged plane.
        """
        arr = self._product_array(name)
        attrs = dict(arr.attrs)
        if attrs.get("per_frame"):
            done = self.product_frames_done(name)
            if not done.all():
                raise RunStoreError(
                    f"product {name!r} of {self.path} holds {int(done.sum())} of {done.size} "
                    f"planes; finish it ({attrs.get('resume_hint', 'run its command again')})")
            return np.stack([self.product_frame(name, i) for i in range(done.size)]), attrs
        fix = (f"recompute it: diffuserlab calibrate resume {self.path} BENCH.toml (a run "
               "whose points are all stored only recomputes its products)")
        try:
            data = np.asarray(arr[...])
        except Exception as exc:  # a corrupt chunk fails to decode
            raise RunStoreError(f"product {name!r} of {self.path} is damaged: its chunks "
                                f"cannot be read ({exc}); {fix}") from exc
        self._check_depths(name, attrs, fix)
        recorded = attrs.pop("crc32", None)
        if recorded is not None:
            actual = product_crcs(data)
            bad = [k for k, (a, b) in enumerate(zip(recorded, actual, strict=False)) if a != b]
            if bad or len(recorded) != len(actual):
                where = f"plane {bad[0]}" if data.ndim == 3 and bad else "its data"
                raise RunStoreError(f"product {name!r} of {self.path} is damaged: {where} "
                                    "differs from the checksum recorded when it was "
                                    f"written (a chunk file deleted or altered); {fix}")
        return data, attrs

    def _check_depths(self, name: str, attrs: dict, fix: str) -> None:
        """Refuse a stack whose depth coordinate (``products/NAME/z``, where written)
        disagrees with its ``depths_mm``: a reader of the coordinate (xarray) would
        place its planes elsewhere than DiffuserLab does.

        Raises
        ------
        RunStoreError
            The coordinate cannot be read or holds other depths (names both).
        """
        import zarr

        node = self._group["products"].get(name)
        if not isinstance(node, zarr.Group) or DEPTH_AXIS not in node \
                or attrs.get("depths_mm") is None:
            return  # an array of products/ (a table, a run written before), no coordinate
        want = np.asarray(attrs["depths_mm"], np.float64)
        try:
            have = np.asarray(node[DEPTH_AXIS][...], np.float64)
        except Exception as exc:  # a corrupt chunk fails to decode
            raise RunStoreError(f"product {name!r} of {self.path} is damaged: its depth "
                                f"coordinate {DEPTH_AXIS}/ cannot be read ({exc}); "
                                f"{fix}") from exc
        if have.shape != want.shape or not np.array_equal(have, want):
            raise RunStoreError(
                f"product {name!r} of {self.path} is damaged: its depth coordinate "
                f"{DEPTH_AXIS}/ holds {have.tolist()} mm but the product records the "
                f"depths {want.tolist()} mm; {fix}")

    def damaged_products(self) -> list[str]:
        """One line per damaged product or written plane of a per-frame product (the
        error reading it raises); planes not written yet are not damage."""
        problems = []
        for name in self.products():
            try:
                if self._product_array(name).attrs.get("per_frame"):
                    for i in np.flatnonzero(self.product_frames_done(name)):
                        self.product_frame(name, int(i))
                else:
                    self.product(name)
            except RunStoreError as exc:
                problems.append(str(exc))
        return problems

    # ------------------------------------------------------------------ per-frame products
    def create_frame_product(self, name: str, n_planes: int, plane_shape: Sequence[int],
                             dtype=np.float32, *, overwrite: bool = False,
                             **attrs: Any) -> None:
        """Create an empty per-frame product (module notes), or keep an existing one.

        Parameters
        ----------
        name : str
        n_planes : int
            One plane per frame of the run it derives from.
        plane_shape : sequence of int
            Shape of one plane, e.g. (rows, cols) of a reconstruction.
        dtype : numpy dtype
        overwrite : bool
            Replace an existing product of that name. Otherwise an existing
            per-frame product of the same shape, dtype and ``attrs`` is kept (its done
            planes are resumed), and any other one is refused.
        **attrs
            JSON-able attributes (e.g. the parameters that made it; ``resume_hint``:
            the command that finishes it).

        Raises
        ------
        RunStoreError
            Read-only store, bad name, or an existing product that differs.
        """
        self._require_writable()
        _check_name(name)
        shape = (int(n_planes), *(int(v) for v in plane_shape))
        want = jsonable({**attrs, "per_frame": True})
        products = self._group["products"]
        arr = product_array(products, name)
        if arr is not None and not overwrite:
            have = {k: v for k, v in arr.attrs.items()}
            # the hint names the run's path: a run copied or moved elsewhere resumes
            differs = sorted(k for k in (set(have) | set(want)) - {_HINT}
                             if have.get(k) != want.get(k))
            if tuple(arr.shape) == shape and arr.dtype == np.dtype(dtype) and not differs:
                if have.get(_HINT) != want.get(_HINT):
                    arr.attrs[_HINT] = want.get(_HINT)
                return
            raise RunStoreError(
                f"{self.path} already has a product {name!r} made with other settings "
                f"({', '.join(differs) or 'shape/dtype'} differ); use the same settings to "
                "resume it, or replace it (--overwrite, overwrite=True)")
        self._delete_product(name)
        key, arr = self._create_product_array(name, shape, want, chunks=(1, *shape[1:]),
                                              dtype=dtype, fill_value=0)
        dims = arr.metadata.dimension_names
        products.create_array(name + _CRC, shape=shape[:1], chunks=(1,), dtype="uint32",
                              fill_value=0, dimension_names=dims[:1])
        products.create_array(name + _DONE, shape=shape[:1], chunks=(1,), dtype="uint8",
                              fill_value=0, dimension_names=dims[:1])
        arr.update_attributes(want)
        self._note_product(name, [key, name + _CRC, name + _DONE])
        describe_products(self._group["products"], self.attrs, [name])  # (attrs re-read)

    def write_product_frame(self, name: str, index: int, plane: np.ndarray) -> None:
        """Store plane ``index`` of a per-frame product: data, checksum, then done flag.

        Raises
        ------
        RunStoreError
            Read-only store, not a per-frame product, index out of range, or a plane
            of the wrong shape (cast to the product's dtype otherwise).
        """
        self._require_writable()
        arr = self._per_frame(name)
        index = int(index)
        if not 0 <= index < arr.shape[0]:
            raise RunStoreError(f"plane {index} is outside product {name!r} "
                                f"(0..{arr.shape[0] - 1})")
        plane = np.asarray(plane, arr.dtype)
        if plane.shape != tuple(arr.shape[1:]):
            raise RunStoreError(f"plane of shape {plane.shape} does not fit product {name!r} "
                                f"(planes {tuple(arr.shape[1:])})")
        products = self._group["products"]
        arr[index] = plane
        products[name + _CRC][index] = product_crcs(plane)[0]
        products[name + _DONE][index] = 1

    def product_frames_done(self, name: str) -> np.ndarray:
        """Done flags of a per-frame product's planes, (n_planes,) bool."""
        self._per_frame(name)
        return np.asarray(self._group["products"][name + _DONE][:], bool)

    def product_frame(self, name: str, index: int) -> np.ndarray:
        """One done plane of a per-frame product, verified against its checksum.

        Raises
        ------
        RunStoreError
            Not a per-frame product, the plane is not written yet, or it is damaged.
        """
        arr = self._per_frame(name)
        products = self._group["products"]
        index = int(index)
        if not (0 <= index < arr.shape[0] and products[name + _DONE][index]):
            raise RunStoreError(f"plane {index} of product {name!r} of {self.path} is not "
                                f"written yet; {arr.attrs.get('resume_hint', 'finish it')}")
        plane = np.asarray(arr[index])
        if product_crcs(plane)[0] != int(products[name + _CRC][index]):
            raise RunStoreError(
                f"product {name!r} of {self.path} is damaged: plane {index} differs from the "
                "checksum recorded when it was written (a chunk file deleted or altered); "
                f"compute it again: {arr.attrs.get('resume_hint', 'run its command again')} "
                "with overwrite")
        return plane

    # ------------------------------------------------------------------ helpers
    def _product_dims(self, name: str, shape, attrs, image: bool) -> tuple[str, ...]:
        """Dimension names of a new product (:func:`instrument.runs.ome.product_dims`): an
        image's are its OME axes' one-letter names (``t``, ``c``, ``z``, ``y``,
        ``x``), whatever the sizes of the frames' (a reconstruction binned by 2 has
        ``y``, ``x`` of half the frames'), so xarray opens each image group on its
        own (``group="products/NAME"``); a whole-run tree opens where the sizes
        agree."""
        del image  # (the names are the product's own, image or not)
        attrs = with_source(attrs, self._group["products"])
        return product_dims(name, shape, attrs, self.attrs)

    def _product_array(self, name: str, check: bool = True):
        """The product's array, wherever it is (:func:`instrument.runs.product_nodes.
        product_array`); with ``check``, refused when its metadata (or that of its
        hidden arrays) differs from the run's record (:mod:`instrument.runs.run_layout`)."""
        products = self._group["products"]
        key = array_key(products, name)
        if key is None:
            raise RunStoreError(
                f"{self.path} has no product {name!r} (it has {self.products()}); finish "
                "or resume the run first")
        damage = self._product_damage(name, key)
        if check and damage:
            raise RunStoreError(damage[0])
        return products[key]

    def product_attrs(self, name: str) -> dict[str, Any]:
        """A product's stored attributes, with its ``source``'s ``bin_factor`` where it
        records none (:func:`instrument.runs.ome.with_source`); not verified (no data read).

        Raises
        ------
        RunStoreError
            No such product.
        """
        return with_source(self._product_array(name, check=False).attrs,
                           self._group["products"])

    def product_axes(self, name: str):
        """A product's OME axes as stored (:func:`instrument.runs.ome.stored_axes`: named as
        its array's dimensions, with units and scales) and its multiscale metadata;
        None for a table or LUT.

        Raises
        ------
        RunStoreError
            No such product.
        """
        from .ome import stored_axes

        return stored_axes(name, self._product_array(name, check=False),
                           self._group["products"], self.attrs)

    def _product_damage(self, name: str, key: str | None = None) -> list[str]:
        """The layout problems of product ``name``'s array (at ``key`` in ``products/``,
        found when not given) and its hidden arrays."""
        key = key or array_key(self._group["products"], name) or name
        return [self.layout_damage[f"products/{k}"] for k in (key, name + _CRC,
                name + _DONE) if f"products/{k}" in self.layout_damage]

    def _per_frame(self, name: str):
        arr = self._product_array(name)
        if not arr.attrs.get("per_frame"):
            raise RunStoreError(f"product {name!r} of {self.path} is not a per-frame product")
        return arr

    def _delete_product(self, name: str) -> None:
        """Remove product ``name`` (its group or array, its hidden arrays) and its
        layout record."""
        products = self._group["products"]
        for key in (name, name + _CRC, name + _DONE, name + MOVING):
            if key in products:
                del products[key]
        keys = (name, f"{name}/{IMAGE_ARRAY}", f"{name}/{DEPTH_AXIS}", name + _CRC,
                name + _DONE)
        forget_layout(products, keys)
        forget_description(products, keys)
        for key in keys:  # replaced: its old record is gone
            self.layout_damage.pop(f"products/{key}", None)


def _check_name(name: str) -> None:
    if not isinstance(name, str) or not name or "/" in name or name.startswith("__") \
            or name.endswith(HIDDEN_SUFFIXES):
        raise RunStoreError(f"product name {name!r} is invalid; use a plain name such as "
                            "'recon_admm' (no '/', not ending in "
                            f"{', '.join(HIDDEN_SUFFIXES)})")

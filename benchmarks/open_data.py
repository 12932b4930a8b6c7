"""The field's tools on DiffuserLab's outputs: the table of docs/open-data.md, measured.

``python -m benchmarks.open_data [--dir DIR]`` writes fresh outputs with the simulated
bench and the project's own commands (a calibration sweep at the default, uneven
depths, a PSF grid, a recorded video reconstructed binned by 2 with its ΔF/F, a PSF
stack imported with even depths, a ``recon3d`` volume at uneven depths, a ``recon``
still, ``runs export`` OME-TIFFs and ImageJ hyperstacks), opens each with each tool of
the field that reads its format and prints, for every (output, tool) pair, ``right``
or what the tool got wrong, then the count.

"Right" is decided by checks, not by "it opened": the axes (their one-letter names,
in order), the shape, the pixel size in micrometres, the frame interval in seconds
(a video), each plane's depth in micrometres (a stack) and the channels' count (a
PSF grid), each compared with what the bench recorded (:class:`Expect`). A tool
that reads a format not at all is no pair. The tools: ome-zarr-models (validation),
ome-zarr-py, xarray (each group with ``open_dataset``), bioio (its own choice of
reader, else the one the docs name), napari-ome-zarr (its reader), napari with
DiffuserLab's plugin (its reader), tifffile, and ImageJ 1.x (``imagej`` on the
``PATH``, run in batch mode under ``xvfb-run``).

The tests (``tests/instrument/test_open_data_table.py``) run :func:`measure` on the
same outputs and check each verdict of the docs' table against it.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: The tools, in the table's order, and the formats each reads.
ZARR_TOOLS = ("ome-zarr-models", "ome-zarr-py", "xarray", "bioio", "napari-ome-zarr",
              "napari + plugin")
TIFF_TOOLS = ("bioio", "tifffile", "ImageJ 1.x")
TOOLS = ("ome-zarr-models", "ome-zarr-py", "xarray", "bioio", "napari-ome-zarr",
         "napari + plugin", "tifffile", "ImageJ 1.x")

#: The simulated runs' sizes: small, every axis longer than one.
N_DEPTHS, N_FRAMES, IMPORT_DEPTHS_MM = 4, 6, (20.0, 30.0, 40.0)
VOLUME_DEPTHS_MM = (20.0, 25.0, 40.0)


@dataclass
class Expect:
    """What an output holds, from what the bench recorded.

    ``axes``: one letter per axis (``t`` of a sweep is its acquisition order);
    ``yx_um``: the pixel size; ``t_s``: the frame interval (``None``: not a time
    axis); ``z_um``: each plane's depth (``None``: no depths); ``layer``: the name
    napari's plugin gives the output's layer (a word of it).
    """

    row: str
    path: Path
    fmt: str  # "zarr", "ome-tiff" or "imagej"
    axes: str
    shape: tuple
    yx_um: float
    t_s: float | None = None
    z_um: list[float] | None = None
    layer: str = ""


@dataclass
class Reading:
    """What one tool made of one output (``None``: the tool gave nothing for it)."""

    axes: str
    shape: tuple
    yx_um: tuple | None
    t_s: float | None = None
    z_um: list[float] | None = None
    notes: list[str] = field(default_factory=list)


def judge(expect: Expect, seen: Reading) -> list[str]:
    """What ``seen`` gets wrong of ``expect`` (empty: right).

    Parameters
    ----------
    expect : Expect
        The output's truth.
    seen : Reading
        One tool's reading of it.

    Returns
    -------
    list of str
        One short phrase per wrong fact: axes, shape, pixel size, frame interval,
        depths.
    """
    wrong = list(seen.notes)
    if seen.axes != expect.axes:
        wrong.append(f"axes {seen.axes or '?'} (not {expect.axes})")
    if tuple(seen.shape) != tuple(expect.shape):
        wrong.append(f"shape {tuple(seen.shape)}")
    if seen.yx_um is None or not np.allclose(seen.yx_um, expect.yx_um, rtol=1e-6):
        wrong.append(f"pixel size {seen.yx_um} (not {expect.yx_um:g} µm)")
    if expect.t_s is not None and (seen.t_s is None
                                   or not np.isclose(seen.t_s, expect.t_s, rtol=1e-6)):
        wrong.append(f"frame interval {seen.t_s} (not {expect.t_s:g} s)")
    if expect.z_um is not None:
        z = seen.z_um
        if z is None or len(z) != len(expect.z_um):
            wrong.append("no depths")
        elif not np.allclose(z, expect.z_um, rtol=1e-6):
            wrong.append("depths " + ", ".join(f"{v / 1000:g}" for v in z)
                         + " mm (not " + ", ".join(f"{v / 1000:g}" for v in expect.z_um)
                         + ")")
    return wrong


# --- the outputs -------------------------------------------------------------------


def _cli(*args: str) -> None:
    from instrument.cli import main

    with contextlib.redirect_stdout(io.StringIO()):  # the commands' reports
        code = main([str(a) for a in args])
    if code != 0:
        raise RuntimeError(f"diffuserlab {' '.join(map(str, args))} exited {code}")


def make_outputs(where: Path) -> list[Expect]:
    """Write every output of the table into ``where`` with the simulated bench.

    Parameters
    ----------
    where : Path
        An empty folder.

    Returns
    -------
    list of Expect
        One per output (row of the table), with the truth read from the runs'
        records (the camera's pitch and binning, the frame rate, the plan's depths).
    """
    import zarr

    where = Path(where)
    cal, grid, video = where / "cal.zarr", where / "grid.zarr", where / "video.zarr"
    _cli("calibrate", "psf-sweep", "--simulate", "--n-depths", N_DEPTHS, "--frames", 1,
         "--out", cal)
    _cli("calibrate", "psf-grid", "--simulate", "--n", 2, "--frames", 1, "--out", grid)
    _cli("capture", "video", "--simulate", "--scene", "neurons", "--frames", N_FRAMES,
         "--out", video)
    _cli("recon-run", video, "--psf", cal, "--depth", 50, "--method", "wiener",
         "--bin", 2, "--dff", 20, "--workers", 1)
    g_cal = zarr.open_group(cal, mode="r")
    g_video = zarr.open_group(video, mode="r")
    pitch = _pitch_um(g_cal)
    psf = g_cal["products/psf_stack/0"]
    depths_um = [1000.0 * d for d in g_cal["products/psf_stack/0"].attrs["depths_mm"]]
    frames = g_video["frames"]
    interval = 1.0 / float(dict(g_video.attrs)["camera"]["frame_rate_hz"])
    recon = g_video["products/recon_wiener/0"]
    # a PSF stack from elsewhere, at even depths, and a volume at uneven ones
    stack = np.asarray(psf[:3, ::2, ::2], np.float32)
    np.save(where / "stack.npy", stack)
    imported = where / "imported.zarr"
    _cli("runs", "import-psf", where / "stack.npy", "--depths",
         ",".join(f"{d:g}" for d in IMPORT_DEPTHS_MM), "--pitch-um", 2 * pitch,
         "--out", imported)
    raw = np.asarray(frames[0], np.float32)[::2, ::2]
    np.save(where / "raw.npy", raw)
    uneven = where / "uneven.zarr"
    _cli("runs", "import-psf", where / "stack.npy", "--depths",
         ",".join(f"{d:g}" for d in VOLUME_DEPTHS_MM), "--pitch-um", 2 * pitch,
         "--out", uneven)
    volume = where / "volume.zarr"
    _cli("recon3d", "--psf-stack", uneven, "--raw", where / "raw.npy", "--iterations", 5,
         "--bin", 2, "--dark", "none", "--out", volume)
    # the TIFFs: a still, OME-TIFF and ImageJ exports
    np.save(where / "psf2d.npy", stack[1])
    _cli("recon", "--psf", where / "psf2d.npy", "--raw", where / "raw.npy", "--method",
         "wiener", "--bin", 2, "--pitch-um", 2 * pitch, "--dark", "none",
         "--out", where / "still.png")
    _cli("runs", "export", cal, "--out", where / "psf.ome.tif")
    _cli("runs", "export", video, "--product", "recon_wiener", "--out",
         where / "recon.ome.tif")
    _cli("runs", "export", cal, "--out", where / "psf.tif")
    _cli("runs", "export", video, "--frames", "--out", where / "frames.tif")

    v = zarr.open_group(volume, mode="r")["0"]
    even = [1000.0 * d for d in IMPORT_DEPTHS_MM]
    vol = [1000.0 * d for d in VOLUME_DEPTHS_MM]
    n_grid = zarr.open_group(grid, mode="r")["products/psf_grid_registered/0"].shape
    still = Expect("`recon` still `OUT.tif` (OME-TIFF)", where / "still.tif", "ome-tiff",
                   "yx", (raw.shape[0] // 2, raw.shape[1] // 2), 4 * pitch)
    return [
        Expect("calibration run: frames", cal, "zarr", "tyx", frames_shape(g_cal), pitch,
               layer="frames"),
        Expect("calibration run: PSF stack (uneven depths)", cal / "products/psf_stack",
               "zarr", "zyx", psf.shape, pitch, z_um=depths_um, layer="psf_stack"),
        Expect("PSF grid run: registered grid", grid / "products/psf_grid_registered",
               "zarr", "cyx", n_grid, _pitch_um(zarr.open_group(grid, mode="r")),
               layer="psf_grid_registered"),
        Expect("video run: frames", video, "zarr", "tyx", frames.shape, pitch,
               t_s=interval, layer="frames"),
        Expect("video run: reconstruction binned by 2", video / "products/recon_wiener",
               "zarr", "tyx", recon.shape, 2 * pitch, t_s=interval, layer="recon_wiener"),
        Expect("`runs import-psf` run: PSF stack (even depths)",
               imported / "products/psf_stack", "zarr", "zyx", stack.shape, 2 * pitch,
               z_um=even, layer="psf_stack"),
        Expect("`recon3d` volume (uneven depths)", volume, "zarr", "zyx", v.shape,
               4 * pitch, z_um=vol, layer="volume"),
        still,
        Expect("`runs export` OME-TIFF: PSF stack (uneven)", where / "psf.ome.tif",
               "ome-tiff", "zyx", psf.shape, pitch, z_um=depths_um),
        Expect("`runs export` OME-TIFF: per-frame product", where / "recon.ome.tif",
               "ome-tiff", "tyx", recon.shape, 2 * pitch, t_s=interval),
        Expect("`runs export` ImageJ: PSF stack (uneven)", where / "psf.tif", "imagej",
               "zyx", psf.shape, pitch, z_um=depths_um),
        Expect("`runs export` ImageJ: video frames", where / "frames.tif", "imagej", "tyx",
               frames.shape, pitch, t_s=interval),
    ]


def frames_shape(group) -> tuple:
    """The shape of a run's ``frames`` array."""
    return tuple(group["frames"].shape)


def _pitch_um(group) -> float:
    """The frames' pixel size: the camera's pitch times its binning, as recorded."""
    attrs = dict(group.attrs)
    (ms,) = attrs["ome"]["multiscales"]
    return float(ms["datasets"][0]["coordinateTransformations"][0]["scale"][-1])


# --- the tools ----------------------------------------------------------------------


def _um(unit) -> bool:
    return unit in ("micrometer", "µm", "um", "micron")


def _from_ome(axes: list[dict], scale, translation, shape) -> Reading:
    """A reading from OME-Zarr axes, scale and translation (a scale-only reader)."""
    names = "".join(a["name"] for a in axes)
    units = {a["name"]: a.get("unit") for a in axes}
    s = dict(zip(names, scale, strict=True))
    o = dict(zip(names, translation or [0.0] * len(names), strict=True))
    yx = (s["y"], s["x"]) if _um(units.get("y")) and _um(units.get("x")) else None
    t = s["t"] if "t" in s and units.get("t") == "second" else None
    z = None
    if "z" in s and _um(units.get("z")):
        n = shape[names.index("z")]
        z = [o["z"] + k * s["z"] for k in range(n)]
    return Reading(names, tuple(shape), yx, t, z)


def read_ome_zarr_models(e: Expect) -> Reading:
    """ome-zarr-models: validate the group as an OME-Zarr 0.5 image; its metadata."""
    import zarr
    from ome_zarr_models import open_ome_zarr

    image = open_ome_zarr(zarr.open_group(e.path, mode="r"), version="0.5")
    ms = image.ome_attributes.multiscales[0]
    ds = ms.datasets[0]
    ts = {t.type: t for t in ds.coordinateTransformations}
    shape = zarr.open_group(e.path, mode="r")[ds.path].shape
    axes = [{"name": a.name, "unit": a.unit} for a in ms.axes]
    translation = ts["translation"].translation if "translation" in ts else None
    return _from_ome(axes, ts["scale"].scale, translation, shape)


def read_ome_zarr_py(e: Expect) -> Reading:
    """ome-zarr-py's Reader: the image node's axes, transforms and data."""
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Reader

    (node, *_) = list(Reader(parse_url(str(e.path)))())
    ts = {t["type"]: t for t in node.metadata["coordinateTransformations"][0]}
    tr = ts.get("translation", {}).get("translation")
    return _from_ome(node.metadata["axes"], ts["scale"]["scale"], tr, node.data[0].shape)


def read_xarray(e: Expect) -> Reading:
    """xarray: the image's group with ``open_dataset``; units and scales from the
    group's ``ome`` attribute, depths from a ``z`` coordinate where there is one."""
    import xarray as xr

    root, group = _zarr_root(e.path)
    ds = xr.open_dataset(root, engine="zarr", group=group, consolidated=False)
    var = ds["frames"] if "frames" in ds else ds["0"]
    ms = ds.attrs["ome"]["multiscales"][0]
    ts = {t["type"]: t for t in ms["datasets"][0]["coordinateTransformations"]}
    seen = _from_ome(ms["axes"], ts["scale"]["scale"],
                     ts.get("translation", {}).get("translation"), var.shape)
    seen.axes = "".join(var.dims)
    if seen.z_um is not None:  # the scale gives evenly spaced planes; a coordinate, each
        if "z" in var.coords and var.coords["z"].size == var.sizes["z"]:
            seen.z_um = _coordinate_um(var.coords["z"])
    return seen


def _coordinate_um(coord) -> list[float]:
    unit = coord.attrs.get("units", coord.attrs.get("unit", "micrometer"))
    factor = {"millimeter": 1000.0, "mm": 1000.0}.get(unit, 1.0)
    return [factor * float(v) for v in np.asarray(coord.values)]


def _zarr_root(path: Path) -> tuple[str, str | None]:
    """A path inside a store as (the store's root, the group in it)."""
    parts = Path(path).parts
    for k in range(len(parts), 0, -1):
        if parts[k - 1].endswith(".zarr"):
            rest = "/".join(parts[k:])
            return str(Path(*parts[:k])), rest or None
    return str(path), None


def read_bioio(e: Expect) -> Reading:
    """bioio: its own choice of reader, else the one docs/open-data.md names."""
    import bioio

    try:
        image = bioio.BioImage(str(e.path))
    except Exception:  # noqa: BLE001 - refused by its own choice: the docs' reader
        image = bioio.BioImage(str(e.path), reader=_bioio_reader(e.fmt))
    dims = image.dims
    letters = "".join(d.lower() for d in dims.order if getattr(dims, d) > 1)
    shape = tuple(getattr(dims, d.upper()) for d in letters)
    pps = image.physical_pixel_sizes
    yx = (pps.Y, pps.X) if pps.Y is not None and pps.X is not None else None
    z = None
    if "z" in letters:  # its Z coordinates, else its API's: from 0 at the Z size
        coords = image.xarray_dask_data.coords
        if "Z" in coords:
            z = [float(v) for v in coords["Z"].values]
        elif pps.Z is not None:
            z = [k * pps.Z for k in range(dims.Z)]
    t = image.time_interval
    t_s = None if t is None else float(getattr(t, "total_seconds", lambda: t)())
    return Reading(letters, shape, yx, t_s, z)


def _bioio_reader(fmt: str):
    if fmt == "zarr":
        import bioio_ome_zarr

        return bioio_ome_zarr.Reader
    if fmt == "ome-tiff":
        import bioio_ome_tiff

        return bioio_ome_tiff.Reader
    import bioio_tifffile

    return bioio_tifffile.Reader


def read_napari_ome_zarr(e: Expect) -> Reading:
    """napari-ome-zarr's reader (what napari shows: each layer's scale, affine's
    translation, labels and units)."""
    import warnings

    from napari_ome_zarr import napari_get_reader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        layers = napari_get_reader(str(e.path))(str(e.path))
    data, kw, _ = layers[0]
    data = data[0] if isinstance(data, list) else data
    return _napari_reading(data.shape, kw)


def _napari_reading(shape, kw: dict) -> Reading:
    labels = list(kw.get("axis_labels") or [])
    units = list(kw.get("units") or [None] * len(labels))
    scale = list(kw.get("scale") or [1.0] * len(shape))
    affine = kw.get("affine")
    translate = list(kw.get("translate") if kw.get("translate") is not None
                     else (affine.translate if affine is not None else [0.0] * len(shape)))
    channel = kw.get("channel_axis")
    if channel is not None:  # napari splits it into layers; the others keep their axes
        labels.insert(channel, "c")
        units.insert(channel, None)
        scale.insert(channel, 1.0)
        translate.insert(channel, 0.0)
    keep = [k for k, n in enumerate(shape) if n > 1]  # a one-plane axis is napari's own
    labels = ["t" if lab == "frame" else lab for lab in labels]  # a sweep's order
    axes = [{"name": labels[k], "unit": _unit(units[k])} for k in keep]
    return _from_ome(axes, [scale[k] for k in keep], [translate[k] for k in keep],
                     [shape[k] for k in keep])


def _unit(unit) -> str | None:
    unit = None if unit is None else str(unit)
    return {"µm": "micrometer", "um": "micrometer", "s": "second"}.get(unit, unit)


def read_plugin(e: Expect) -> Reading:
    """DiffuserLab's napari plugin's reader: the output's layer (by its name)."""
    from gui.napari_plugin.reader import get_reader

    layers = get_reader(str(e.path))(str(e.path))
    named = [la for la in layers if e.layer in la[1].get("name", "")] or layers
    data, kw, _ = named[0]
    return _napari_reading(data.shape, kw)


def read_tifffile(e: Expect) -> Reading:
    """tifffile: the series' axes and the OME-XML or ImageJ metadata."""
    import tifffile

    with tifffile.TiffFile(e.path) as tif:
        series = tif.series[0]
        axes = series.axes.lower()
        shape = series.shape
        if tif.is_ome:
            pixels = tifffile.xml2dict(tif.ome_metadata)["OME"]["Image"]["Pixels"]
            return _from_ome_xml(pixels, axes, shape)
        ij = tif.imagej_metadata or {}
        page = tif.pages[0]
        return _from_imagej(ij, page, axes, shape)


def _from_ome_xml(pixels: dict, axes: str, shape) -> Reading:
    units_ok = all(pixels.get(f"PhysicalSize{a}Unit", "µm") in ("µm", "um")
                   for a in "XY")
    yx = ((pixels["PhysicalSizeY"], pixels["PhysicalSizeX"])
          if "PhysicalSizeX" in pixels and units_ok else None)
    planes = pixels.get("Plane", [])
    planes = planes if isinstance(planes, list) else [planes]
    t = z = None
    if "t" in axes:
        dts = [p["DeltaT"] for p in planes if "DeltaT" in p]
        t = (float(np.mean(np.diff(dts))) if len(dts) > 1
             else pixels.get("TimeIncrement"))
    if "z" in axes:
        zs = [p.get("PositionZ") for p in planes]
        z = ([float(v) for v in zs] if all(v is not None for v in zs) and zs else None)
    return Reading(axes, tuple(shape), yx, t, z)


def _from_imagej(ij: dict, page, axes: str, shape) -> Reading:
    yx = None
    if "XResolution" in page.tags and ij.get("unit") in ("um", "micron", "µm", "\\u00B5m"):
        xr_ = page.tags["XResolution"].value
        yr_ = page.tags["YResolution"].value
        yx = (yr_[1] / yr_[0], xr_[1] / xr_[0])
    t = ij.get("finterval") if "t" in axes else None
    z = None
    if "z" in axes and "spacing" in ij:
        z0 = -float(ij.get("zorigin", 0.0)) * float(ij["spacing"])
        z = [z0 + k * float(ij["spacing"]) for k in range(shape[axes.index("z")])]
    return Reading(axes, tuple(shape), yx, t, z)


#: ImageJ macro: one line of what ImageJ 1.x made of the file given as its argument.
IJ_MACRO = r"""
open(getArgument());
getVoxelSize(w, h, d, u);
Stack.getDimensions(W, H, C, Z, T);
Stack.getUnits(X, Y, Zu, Time, Value);
x = 0; y = 0; z = 0; toScaled(x, y, z);
print("IJ " + getVersion() + "|" + d2s(w, 9) + "|" + d2s(h, 9) + "|" + d2s(d, 9) + "|" + u
      + "|" + W + "|" + H + "|" + C + "|" + Z + "|" + T + "|" + d2s(Stack.getFrameInterval(), 9)
      + "|" + Time + "|" + d2s(z, 9));
"""


#: ImageJ's length units, in micrometres.
IJ_UNITS_UM = {"µm": 1.0, "micron": 1.0, "um": 1.0, "mm": 1000.0, "cm": 1e4}


def imagej_command() -> list[str] | None:
    """How to run ImageJ 1.x in batch mode here (``None``: not installed)."""
    jar = Path("/usr/share/java/ij.jar")
    if shutil.which("java") is None or not jar.is_file():
        return None
    prefix = [] if os.environ.get("DISPLAY") else ["xvfb-run", "-a"]
    if prefix and shutil.which("xvfb-run") is None:
        return None
    return [*prefix, "java", "-jar", str(jar), "-batch"]


def read_imagej(e: Expect) -> Reading:
    """ImageJ 1.x (Debian's ``imagej``, the ImageJ Fiji is built on, without
    Bio-Formats): what it opens the file as, by a batch macro."""
    command = imagej_command()
    if command is None:
        raise RuntimeError("ImageJ is not installed (apt-get install imagej)")
    with tempfile.TemporaryDirectory() as tmp:
        macro = Path(tmp) / "read.ijm"
        macro.write_text(IJ_MACRO)
        done = subprocess.run([*command, str(macro), str(e.path)], capture_output=True,
                              text=True, timeout=600)
    line = next((ln for ln in done.stdout.splitlines() if ln.startswith("IJ ")), None)
    if line is None:
        raise RuntimeError(f"ImageJ printed nothing: {done.stderr.strip()[-300:]}")
    _, w, h, d, unit, width, height, c, nz, nt, fi, tunit, z0 = line.split("|")
    sizes = {"c": int(c), "z": int(nz), "t": int(nt)}
    axes = "".join(a for a in "ctz" if sizes[a] > 1)
    axes = "".join(sorted(axes, key="tczyx".index)) + "yx"
    shape = tuple(sizes[a] for a in axes[:-2]) + (int(height), int(width))
    to_um = IJ_UNITS_UM.get(unit)  # ImageJ keeps a TIFF's resolution unit (cm)
    yx = None if to_um is None else (to_um * float(h), to_um * float(w))
    t = float(fi) if "t" in axes and float(fi) > 0 and tunit in ("sec", "s") else None
    z = None
    if "z" in axes and to_um is not None:
        z = [to_um * (float(z0) + k * float(d)) for k in range(sizes["z"])]
    return Reading(axes, shape, yx, t, z)


READERS: dict[str, Callable[[Expect], Reading]] = {
    "ome-zarr-models": read_ome_zarr_models, "ome-zarr-py": read_ome_zarr_py,
    "xarray": read_xarray, "bioio": read_bioio, "napari-ome-zarr": read_napari_ome_zarr,
    "napari + plugin": read_plugin, "tifffile": read_tifffile, "ImageJ 1.x": read_imagej}


def pairs(outputs: list[Expect]) -> list[tuple[Expect, str]]:
    """Every (output, tool) pair of the table: each tool with each output of a
    format it reads."""
    return [(e, tool) for e in outputs
            for tool in (ZARR_TOOLS if e.fmt == "zarr" else TIFF_TOOLS)]


def measure(outputs: list[Expect]) -> dict[tuple[str, str], list[str]]:
    """Open every pair; ``{(row, tool): what is wrong}`` (empty list: right).

    A tool that fails to open an output gets ``["refused: <its message>"]``.
    """
    found = {}
    for e, tool in pairs(outputs):
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # ome-zarr-py prints groups
                seen = READERS[tool](e)
            found[e.row, tool] = judge(e, seen)
        except Exception as exc:  # noqa: BLE001 - a refusal is a finding, not a crash
            found[e.row, tool] = [f"refused: {type(exc).__name__}: {str(exc)[:160]}"]
    return found


def main(argv: list[str] | None = None) -> int:
    """Write the outputs, measure every pair, print the verdicts and the count."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.open_data",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--dir", type=Path, default=None,
                   help="folder for the outputs (default: a temporary one, removed)")
    p.add_argument("--json", type=Path, default=None, help="also write the verdicts here")
    args = p.parse_args(argv)
    if args.dir is not None and args.dir.exists() and any(args.dir.iterdir()):
        print(f"--dir {args.dir} is not empty; give a new or empty folder", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        where = args.dir or Path(tmp)
        where.mkdir(parents=True, exist_ok=True)
        outputs = make_outputs(where)
        found = measure(outputs)
    right = sum(not w for w in found.values())
    for (row, tool), wrong in found.items():
        print(f"{row} | {tool} | {'right' if not wrong else '; '.join(wrong)}")
    print(f"{right} of {len(found)} pairs right")
    if args.json:
        args.json.write_text(json.dumps(
            [{"output": r, "tool": t, "wrong": w} for (r, t), w in found.items()], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

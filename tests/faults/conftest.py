"""Inputs of the fault tables: small valid files made once per session, and bad
copies of them (one factory per input class).

Every bad input lives in the same directory as the valid ones, so each case checks
that *nothing* under it changed (:func:`tests.faults.helpers.tree`).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

from instrument.cli import main

REPO = Path(__file__).resolve().parents[2]
SHAPE = (32, 32)


# ----------------------------------------------------------------------------- valid inputs


def _valid(d: Path) -> None:
    """psf.npy, raw.tif, stack.tif (depths 2, 4, 8 mm), stack.npy, run.zarr (imported
    stack), dark.zarr (a completed simulated dark run), bench.toml, file.txt, dir/."""
    rng = np.random.default_rng(0)
    np.save(d / "psf.npy", rng.random(SHAPE).astype(np.float32))
    tifffile.imwrite(d / "raw.tif", (100 * rng.random(SHAPE)).astype(np.float32))
    stack = rng.random((3, *SHAPE)).astype(np.float32)
    tifffile.imwrite(d / "stack.tif", stack, metadata={"depths_mm": [2.0, 4.0, 8.0]},
                     photometric="minisblack")
    np.save(d / "stack.npy", stack)
    assert main(["runs", "import-psf", str(d / "stack.tif"), "--out", str(d / "run.zarr")]) == 0
    assert main(["calibrate", "dark", "--simulate", "--frames", "2",
                 "--out", str(d / "dark.zarr")]) == 0
    shutil.copy(REPO / "examples" / "bench-simulated.toml", d / "bench.toml")
    (d / "file.txt").write_text("a regular file, not a directory\n")
    (d / "dir").mkdir()


# ----------------------------------------------------------------------------- bad inputs


def _empty(d: Path) -> None:
    for name in ("empty.npy", "empty.tif", "empty.toml"):
        (d / name).write_bytes(b"")
    (d / "emptydir").mkdir()


def _truncated(d: Path) -> None:
    for src in ("psf.npy", "raw.tif", "stack.tif", "bench.toml"):
        data = (d / src).read_bytes()
        (d / f"trunc_{src}").write_bytes(data[: len(data) // 2])


def _mislabelled(d: Path) -> None:
    import cv2

    (d / "text.tif").write_text("this is text, not a TIFF\n")
    (d / "text.npy").write_text("this is text, not a NumPy array\n")
    ok, png = cv2.imencode(".png", (255 * np.load(d / "psf.npy")).astype(np.uint8))
    assert ok
    (d / "png.tif").write_bytes(png.tobytes())
    (d / "tif.npy").write_bytes((d / "raw.tif").read_bytes())
    (d / "binary.toml").write_bytes(bytes(range(256)))
    (d / "foreign.toml").write_text('[tool.black]\nline-length = 99\n')


def _shapes(d: Path) -> None:
    rng = np.random.default_rng(1)
    np.save(d / "d1.npy", rng.random(32).astype(np.float32))
    np.save(d / "d3.npy", rng.random((3, *SHAPE)).astype(np.float32))
    np.save(d / "d4.npy", rng.random((2, 3, *SHAPE)).astype(np.float32))
    np.save(d / "tiny.npy", rng.random((2, 2)).astype(np.float32))
    np.save(d / "tiny_stack.npy", rng.random((3, 2, 2)).astype(np.float32))
    tifffile.imwrite(d / "big_raw.tif", rng.random((48, 48)).astype(np.float32))
    np.save(d / "bad_pattern.npy", np.ones((5, 7), np.uint8))


def _dtypes(d: Path) -> None:
    rng = np.random.default_rng(2)
    np.save(d / "complex.npy", (rng.random(SHAPE) + 1j).astype(np.complex64))
    np.save(d / "bool.npy", rng.random(SHAPE) > 0.5)
    np.save(d / "str.npy", np.full(SHAPE, "ab"))
    np.save(d / "object.npy", np.array([[None] * 32] * 32, dtype=object), allow_pickle=True)
    np.save(d / "complex_stack.npy", (rng.random((3, *SHAPE)) + 1j).astype(np.complex64))


def _nonfinite(d: Path) -> None:
    psf = np.load(d / "psf.npy")
    psf[3, 4] = np.nan
    np.save(d / "nan.npy", psf)
    raw = tifffile.imread(d / "raw.tif")
    raw[5, 6] = np.inf
    tifffile.imwrite(d / "inf.tif", raw)
    stack = tifffile.imread(d / "stack.tif")
    stack[1, 7, 7] = np.nan
    tifffile.imwrite(d / "nan_stack.tif", stack, metadata={"depths_mm": [2.0, 4.0, 8.0]},
                     photometric="minisblack")
    np.save(d / "nan_stack.npy", stack)


def _stores(d: Path) -> None:
    """Damaged copies of run.zarr / dark.zarr, one locked by this (live) process and
    one whose lock was left by a process that has exited."""
    def copy(src: str, name: str) -> Path:
        return Path(shutil.copytree(d / src, d / name))

    chunk = Path("products", "psf_stack", "0", "c", "1", "0", "0")
    (copy("run.zarr", "deleted_chunk.zarr") / chunk).unlink()
    altered = copy("run.zarr", "altered_chunk.zarr") / chunk
    data = bytearray(altered.read_bytes())
    data[len(data) // 2] ^= 0xFF
    altered.write_bytes(bytes(data))
    meta = copy("dark.zarr", "trunc_meta.zarr") / "zarr.json"
    meta.write_bytes(meta.read_bytes()[: len(meta.read_bytes()) // 2])
    (copy("dark.zarr", "notjson_meta.zarr") / "zarr.json").write_text("not json at all\n")
    meta = copy("dark.zarr", "nokeys.zarr") / "zarr.json"
    doc = json.loads(meta.read_text())
    doc["attributes"] = {k: v for k, v in doc["attributes"].items()
                         if k in ("schema", "schema_version")}
    meta.write_text(json.dumps(doc))
    lock = {"pid": os.getpid(), "host": socket.gethostname(),
            "started_utc": "2026-01-01T00:00:00+00:00"}
    (copy("dark.zarr", "locked.zarr") / ".lock").write_text(json.dumps(lock))
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    stale = {**lock, "pid": int(gone.stdout)}  # a process that has exited
    (copy("dark.zarr", "stale_lock.zarr") / ".lock").write_text(json.dumps(stale))
    # a bench of another set-up: the simulated bench with the diffuser moved
    text = (d / "bench.toml").read_text()
    assert "diffuser_sensor_distance_mm = 8.9" in text
    (d / "other_bench.toml").write_text(text.replace("diffuser_sensor_distance_mm = 8.9",
                                                     "diffuser_sensor_distance_mm = 12.0"))


def _signal(d: Path) -> None:
    """Raws with nothing to reconstruct after their dark level, beside a 16-bit PSF whose
    dark corner reads 3168 DN (and a 16-bit stack of the same camera)."""
    rng = np.random.default_rng(3)
    psf = np.full(SHAPE, 3168, np.uint16)
    psf[16:30, 16:30] += (20000 * rng.random((14, 14))).astype(np.uint16)
    tifffile.imwrite(d / "psf16.tif", psf)
    stack = np.stack([psf, np.roll(psf, 2, 1), np.roll(psf, 4, 1)])
    tifffile.imwrite(d / "stack16.tif", stack, metadata={"depths_mm": [2.0, 4.0, 8.0]},
                     photometric="minisblack")
    tifffile.imwrite(d / "raw16.tif", (3168 + 9000 * rng.random(SHAPE)).astype(np.uint16))
    # an 8-bit export of a frame beside the 16-bit PSF: every level below 3168
    tifffile.imwrite(d / "raw8.tif", (255 * rng.random(SHAPE)).astype(np.uint8))
    # a background-subtracted frame (levels around 0) and a dark frame (noise only)
    tifffile.imwrite(d / "bgsub.tif", (200 * rng.random(SHAPE) - 100).astype(np.float32))
    tifffile.imwrite(d / "noise.tif", rng.normal(0, 5, SHAPE).astype(np.float32))
    tifffile.imwrite(d / "const.tif", np.full(SHAPE, 5000, np.uint16))
    sat = np.full(SHAPE, 65535, np.uint16)
    sat[:3] = 9000  # 90 % saturated, not constant
    tifffile.imwrite(d / "sat.tif", sat)
    lone = (100 * rng.random(SHAPE) + 50).astype(np.float32)
    lone[7, 9] = 1e38
    tifffile.imwrite(d / "lone.tif", lone)


def _colour(d: Path) -> None:
    """Frames that are not colour: three grey pages (three frames, not R, G, B), 32 pages
    of 32 x 3, an array of 2 values per pixel."""
    rng = np.random.default_rng(4)
    frames = (100 * rng.random((3, *SHAPE)) + 10).astype(np.float32)
    tifffile.imwrite(d / "pages3.tif", frames, photometric="minisblack")
    tifffile.imwrite(d / "pages_hw3.tif", frames.transpose(1, 2, 0), photometric="minisblack")
    np.save(d / "two.npy", frames[:2].transpose(1, 2, 0))
    tifffile.imwrite(d / "abc_depths.tif", frames, metadata={"depths_mm": ["abc", 4.0, 8.0]},
                     photometric="minisblack")
    sat = (2000 + 3000 * rng.random(SHAPE)).astype(np.uint16)
    sat[:4] = 65535  # 12.5 % saturated: warned once, reconstructed
    tifffile.imwrite(d / "sat12.tif", sat)


def _frame_psf(d: Path) -> None:
    """frame_psf.npy: a PSF at the simulated camera's frame shape (dark.zarr's frames);
    rgb_dark.npy: a colour dark image of that region (not the monochrome frames')."""
    from instrument.runs.runstore import RunStore

    rows, cols = RunStore.open(d / "dark.zarr").frame_shape
    rng = np.random.default_rng(5)
    np.save(d / "frame_psf.npy", (100 + 1000 * rng.random((rows, cols))).astype(np.float32))
    np.save(d / "rgb_dark.npy", np.full((rows, cols, 3), 64.0, np.float32))


def _bench_fields(d: Path) -> None:
    """Bench files whose values have the right types but cannot describe the bench: the
    geometry contradicting the camera, a length in metres, an unknown driver parameter
    (which a simulated twin would drop), a negative speed, two axes on one controller,
    counts_per_unit = 0."""
    sim = (d / "bench.toml").read_text()
    lab = (REPO / "examples" / "bench-lab.toml").read_text()
    emulated = (REPO / "examples" / "bench-emulated.toml").read_text()
    edits = {
        "b_geom.toml": (sim, "sensor_shape_px = [256, 320]", "sensor_shape_px = [512, 640]"),
        "b_metres.toml": (sim, "diffuser_sensor_distance_mm = 8.9",
                          "diffuser_sensor_distance_mm = 0.0089"),
        "b_gain.toml": (sim, "adc_bits = 12", "adc_bits = 12\ngain_db = 6"),
        "l_speed.toml": (lab, "speed_mm_s = 2.0", "speed_mm_s = -2.0"),
        "l_serial.toml": (lab, 'y = "27500102"', 'y = "27500101"'),
        "e_counts.toml": (emulated, "counts_per_unit = 34554.96", "counts_per_unit = 0"),
    }
    for name, (text, old, new) in edits.items():
        assert text.count(old) == 1, (name, old)
        (d / name).write_text(text.replace(old, new))


FACTORIES = (_valid, _empty, _truncated, _mislabelled, _shapes, _dtypes, _nonfinite, _stores,
             _signal, _colour, _bench_fields, _frame_psf)


@pytest.fixture(scope="session")
def fault_dir(tmp_path_factory) -> Path:
    """A directory with the valid inputs and one bad input per class (see the factories
    above); the fault cases must leave every file in it as it was."""
    d = tmp_path_factory.mktemp("faults")
    for make in FACTORIES:
        make(d)
    return d


@pytest.fixture
def d(fault_dir, monkeypatch) -> Path:
    """:func:`fault_dir`, also the working directory (default outputs land there).

    Whatever a case adds (a failing case's outputs) is removed afterwards, so that one
    failure does not turn the next cases' outputs into clashes.
    """
    before = set(fault_dir.rglob("*"))
    monkeypatch.chdir(fault_dir)
    yield fault_dir
    for path in sorted(set(fault_dir.rglob("*")) - before, key=lambda p: len(p.parts)):
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)

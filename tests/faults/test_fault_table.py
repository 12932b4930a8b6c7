"""The fault table: every ``diffuserlab`` command on a matrix of bad inputs.

Each case is a command line (run in the fault directory of ``conftest.py``, whose
files are the valid inputs and one bad input per class) and the words its error
must name. Every case must exit 2 with exactly one line
``diffuserlab: error: ...`` on stderr, no traceback, and leave every file of the
directory as it was (sha256 before and after, nothing added). Output clashes of
recon, recon3d, demo, analyze, runs, holo and benchmark are in
``tests/instrument/cli/test_output_safety.py``; this table covers the other
commands' outputs and every other input class.

Not here, by design: ``runs verify`` of a store with deleted or altered chunks exits 1
and lists the damage (``runs show`` marks it DAMAGED), see docs/data-safety.md.
"""

from __future__ import annotations

import shlex
from collections import Counter

import pytest

from .helpers import assert_refused

#: input classes (the second part of a case id)
CLASSES = ("missing", "empty", "truncated", "mislabelled", "shape", "dtype", "nonfinite",
           "number", "unwritable", "clash", "corrupt-store", "locked-store", "foreign-bench",
           "no-signal", "colour", "bench-field", "resource", "ignored-option", "out-name",
           "messages")


def case(command: str, cls: str, what: str, words: str):
    """One row: ``command`` (split like a shell), its input class, a short name and the
    words (``|``-separated) the error line must hold."""
    assert cls in CLASSES, cls
    return pytest.param(shlex.split(command), [w for w in words.split("|") if w],
                        id=f"{_command(command)}:{cls}:{what}")


def _command(command: str) -> str:
    """The (sub)command of a command line: its words before the first option or path."""
    words = []
    for word in command.split():
        if word.startswith("-") or "." in word or "/" in word:
            break
        words.append(word)
    return " ".join(words[:2])


R = "recon --iterations 2 --out o/r"
R2 = f"{R} --psf psf.npy --raw raw.tif"
V = "recon3d --iterations 2 --out o/v.tif"
V2 = f"{V} --psf-stack stack.tif --raw raw.tif"
A = "analyze resolution --pitch-um 13 --d-mm 8.9 --out o/a"
A2 = f"{A} --psf-stack stack.tif"

RECON = [
    case(f"{R} --psf nope.npy --raw raw.tif", "missing", "psf", "nope.npy"),
    case(f"{R} --psf psf.npy --raw nope.tif", "missing", "raw", "nope.tif"),
    case(f"{R} --psf dir --raw raw.tif", "missing", "psf is a directory", "dir"),
    case(f"{R} --psf empty.npy --raw raw.tif", "empty", "psf", "empty.npy"),
    case(f"{R} --psf psf.npy --raw empty.tif", "empty", "raw", "empty.tif"),
    case(f"{R} --psf trunc_psf.npy --raw raw.tif", "truncated", "psf", "trunc_psf.npy"),
    case(f"{R} --psf psf.npy --raw trunc_raw.tif", "truncated", "raw", "trunc_raw.tif"),
    case(f"{R} --psf psf.npy --raw text.tif", "mislabelled", "text tif", "text.tif"),
    case(f"{R} --psf png.tif --raw raw.tif", "mislabelled", "png as tif", "png.tif"),
    case(f"{R} --psf text.npy --raw raw.tif", "mislabelled", "text npy", "text.npy"),
    case(f"{R} --psf psf.npy --raw tif.npy", "mislabelled", "tif as npy", "tif.npy"),
    case(f"{R} --psf psf.npy --raw psf.toml", "mislabelled", "unknown suffix", "psf.toml"),
    case(f"{R} --psf d1.npy --raw raw.tif", "shape", "1-D psf", "d1.npy"),
    case(f"{R} --psf d3.npy --raw raw.tif", "shape", "3-D psf without depth", "d3.npy"),
    case(f"{R} --psf d4.npy --raw raw.tif", "shape", "4-D psf", "d4.npy"),
    case(f"{R} --psf tiny.npy --raw tiny.npy", "shape", "2x2",
         "2x2 pixels|dark corner|--dark"),
    case(f"{R} --psf psf.npy --raw big_raw.tif", "shape", "size mismatch", "shape"),
    case(f"{R} --psf complex.npy --raw raw.tif", "dtype", "complex psf", "complex"),
    case(f"{R} --psf bool.npy --raw raw.tif", "dtype", "bool psf", "bool"),
    case(f"{R} --psf str.npy --raw raw.tif", "dtype", "str psf", "str.npy"),
    case(f"{R} --psf object.npy --raw raw.tif", "dtype", "object psf", "object.npy"),
    case(f"{R} --psf nan.npy --raw raw.tif", "nonfinite", "nan psf", "nan"),
    case(f"{R} --psf psf.npy --raw inf.tif", "nonfinite", "inf raw", "inf"),
    case(f"{R2} --iterations 0", "number", "iterations 0", "iterations"),
    case(f"{R2} --iterations -5", "number", "iterations -5", "iterations"),
    case(f"{R2} --iterations abc", "number", "iterations abc", "--iterations"),
    case(f"{R2} --tv -1", "number", "tv -1", "tv"),
    case(f"{R2} --tv nan", "number", "tv nan", "tv"),
    case(f"{R2} --tv inf", "number", "tv inf", "tv"),
    case(f"{R2} --bin 0", "number", "bin 0", "bin"),
    case(f"{R2} --bin -2", "number", "bin -2", "bin"),
    case(f"{R2} --bin 64", "number", "bin larger than image", "bin"),
    case(f"{R2} --erase 1.5", "number", "erase 1.5", "erase"),
    case(f"{R2} --erase nan", "number", "erase nan", "erase"),
    case(f"{R2} --erase 0.5 --seed -1", "number", "seed -1", "seed"),
    case(f"{R2} --full-scale 0", "number", "full-scale 0", "full"),
    case(f"{R2} --full-scale nan", "number", "full-scale nan", "full"),
    case(f"{R} --psf stack.tif --depth 50 --raw raw.tif", "number", "depth not in stack", "50"),
    case(f"{R} --psf stack.tif --depth nan --raw raw.tif", "number", "depth nan", "depth"),
    case(f"{R} --psf stack.tif --depth -4 --raw raw.tif", "number", "depth -4", "depth"),
    case(f"{R} --psf run.zarr --depth 4 --psf-product nope --raw raw.tif", "missing",
         "product", "nope"),
    case(f"{R} --psf deleted_chunk.zarr --depth 4 --raw raw.tif", "corrupt-store",
         "deleted chunk", "deleted_chunk.zarr"),
    case(f"{R} --psf altered_chunk.zarr --depth 4 --raw raw.tif", "corrupt-store",
         "altered chunk", "altered_chunk.zarr"),
    case(f"{R} --psf notjson_meta.zarr --depth 4 --raw raw.tif", "corrupt-store",
         "zarr.json not json", "notjson_meta.zarr"),
    case(f"{R2} --out file.txt/r", "unwritable", "out under a file", "file.txt"),
    case(f"{R2} --metrics-json /proc/x/m.json", "unwritable", "metrics in /proc", "/proc/x"),
]

RS = "recon --iterations 2 --out o/r --psf psf16.tif"
#: the raw checked after its dark level, in every method (recon.preprocess.signal)
NO_SIGNAL = [
    case(f"{RS} --raw raw8.tif", "no-signal", "8-bit raw beside 16-bit psf",
         "raw8.tif|uint8|uint16|--allow-mixed-ranges"),
    *[case(f"{RS} --raw raw8.tif --allow-mixed-ranges --method {m}", "no-signal",
           f"8-bit raw below the psf's dark level, {m}",
           "raw8.tif|3168|dark corner|floor|--dark") for m in ("auto", "wiener", "gd",
                                                                "fista", "admm")],
    case(f"{RS} --raw bgsub.tif", "no-signal", "background-subtracted raw",
         "bgsub.tif|below|3168|--dark none"),
    case(f"{RS} --raw bgsub.tif --dark 3000", "no-signal", "dark value given",
         "bgsub.tif|below|dark value given"),
    case(f"{RS} --raw noise.tif --dark none --method admm --tv 1e-3", "no-signal",
         "dark frame, fixed method", "noise.tif|no signal|dark level 0"),
    case(f"{RS} --raw const.tif", "no-signal", "constant raw", "const.tif|constant|5000"),
    case(f"{RS} --raw sat.tif --method wiener", "no-signal", "90 % saturated raw",
         "sat.tif|90.6% of the raw is at full scale"),
    case(f"{R} --psf psf.npy --raw lone.tif --method fista", "no-signal", "lone 1e38 pixel",
         "lone.tif|(7, 9)|1e+38"),
    case(f"{RS} --raw lone.tif", "no-signal", "1e38 above the psf camera's full scale",
         "lone.tif|full scale 65535"),
    case(f"{RS} --raw raw16.tif --erase 0.9999", "number", "99.99 % erasure",
         "--erase 0.9999|0 to 0.99"),
    case(f"{V} --psf-stack stack16.tif --raw raw8.tif", "no-signal",
         "recon3d raw below the stack's dark level", "raw8.tif|3168|dark corners|--dark"),
    case(f"{V} --psf-stack stack16.tif --raw bgsub.tif --method fista --tv 0", "no-signal",
         "recon3d background-subtracted raw, fista", "bgsub.tif|below"),
    case(f"{V} --psf-stack stack.tif --raw const.tif", "no-signal", "recon3d constant raw",
         "const.tif|constant"),
    case(f"{V} --psf-stack stack.tif --raw noise.tif --dark none", "no-signal",
         "recon3d dark frame", "noise.tif|no signal"),
    case(f"{V} --psf-stack stack.tif --raw lone.tif", "no-signal", "recon3d lone 1e38 pixel",
         "lone.tif|1e+38"),
]

#: colour only from a photometric tag / samples per pixel or a last axis of 3 or 4
COLOUR = [
    case(f"{R} --psf psf.npy --raw pages3.tif", "colour", "3 grey pages as raw",
         "pages3.tif|stack of 3 images|photometric"),
    case(f"{R} --psf pages3.tif --raw raw.tif", "colour", "3 grey pages as psf",
         "pages3.tif|stack of 3 images|--depth"),
    case(f"{R} --psf psf.npy --raw pages_hw3.tif", "colour", "32 pages of 32x3",
         "pages_hw3.tif|stack of 32 images"),
    case(f"{R} --psf psf.npy --raw two.npy", "colour", "2 values per pixel",
         "two.npy|2 values per pixel"),
    case(f"{V2} --raw pages3.tif", "colour", "recon3d 3 grey pages as raw",
         "pages3.tif|stack of 3 images"),
    # not "PSF has 3 channels": a stack without --depth is a stack
    case(f"{R} --psf stack.tif --raw raw.tif", "colour", "psf stack without depth",
         "stack.tif|stack of 3 images|--depth"),
]

#: messages a user can act on: the file named, the option to use
MESSAGES = [
    case(f"{R} --psf abc_depths.tif --depth 4 --raw raw.tif", "messages",
         "stack depths not numbers", "abc_depths.tif|'abc'|one depth per plane"),
    case(f"{V} --psf-stack abc_depths.tif --raw raw.tif", "messages",
         "recon3d stack depths not numbers", "abc_depths.tif|not numbers"),
]

RECON3D = [
    case(f"{V} --psf-stack nope.tif --raw raw.tif", "missing", "stack", "nope.tif"),
    case(f"{V} --psf-stack stack.tif --raw nope.tif", "missing", "raw", "nope.tif"),
    case(f"{V} --psf-stack emptydir --raw raw.tif", "empty", "empty dir as store", "emptydir"),
    case(f"{V} --psf-stack empty.tif --depths 1 --raw raw.tif", "empty", "stack", "empty.tif"),
    case(f"{V} --psf-stack trunc_stack.tif --raw raw.tif", "truncated", "stack",
         "trunc_stack.tif"),
    case(f"{V} --psf-stack text.tif --depths 1 --raw raw.tif", "mislabelled", "text tif",
         "text.tif"),
    case(f"{V} --psf-stack text.npy --depths 1 --raw raw.tif", "mislabelled", "text npy",
         "text.npy"),
    case(f"{V} --psf-stack stack.tif --raw text.tif", "mislabelled", "raw text tif",
         "text.tif"),
    case(f"{V} --psf-stack stack.npy --raw raw.tif", "missing", "npy without depths",
         "depths"),
    case(f"{V} --psf-stack stack.npy --depths 2,4 --raw raw.tif", "shape", "depths count",
         "depths"),
    case(f"{V} --psf-stack d1.npy --depths 2 --raw raw.tif", "shape", "1-D stack", "d1.npy"),
    case(f"{V} --psf-stack d4.npy --depths 2,4 --raw raw.tif", "shape", "4-D stack",
         "d4.npy"),
    case(f"{V} --psf-stack tiny_stack.npy --depths 2,4,8 --raw tiny.npy", "shape", "2x2",
         "2"),
    case(f"{V2} --raw big_raw.tif", "shape", "size mismatch", "size"),
    case(f"{V} --psf-stack complex_stack.npy --depths 2,4,8 --raw raw.tif", "dtype",
         "complex stack", "complex"),
    case(f"{V} --psf-stack stack.tif --raw bool.npy", "dtype", "bool raw", "bool"),
    case(f"{V} --psf-stack nan_stack.tif --raw raw.tif", "nonfinite", "nan stack", "nan"),
    case(f"{V2} --raw inf.tif", "nonfinite", "inf raw", "inf"),
    case(f"{V} --psf-stack stack.npy --depths 2,nan,8 --raw raw.tif", "nonfinite",
         "nan depth", "depths"),
    case(f"{V} --psf-stack stack.npy --depths 2,2,8 --raw raw.tif", "number",
         "repeated depths", "depth"),
    case(f"{V} --psf-stack stack.npy --depths=-2,4,8 --raw raw.tif", "number",
         "negative depth", "depths"),
    case(f"{V2} --iterations 0", "number", "iterations 0", "iterations"),
    case(f"{V2} --tv -1", "number", "tv -1", "tv"),
    case(f"{V2} --tv nan", "number", "tv nan", "tv"),
    case(f"{V2} --l1 inf", "number", "l1 inf", "l1"),
    case(f"{V2} --bin 0", "number", "bin 0", "bin"),
    case(f"{V2} --dark nan", "number", "dark nan", "dark"),
    case(f"{V2} --dark bright", "number", "dark word", "dark"),
    case(f"{V2} --method newton", "number", "method", "newton"),
    # dask reads '' as 1 byte and a unit alone as one of it
    case(f"{V2} --memory-limit ''", "number", "memory limit empty", "--memory-limit ''"),
    case(f"{V2} --memory-limit GB", "number", "memory limit without a number",
         "--memory-limit 'GB'"),
    case(f"{V2} --method fista --prior wavelet --tv 1e-3", "ignored-option",
         "recon3d prior with fista", "--prior wavelet|--method fista|--method admm"),
    case(f"{V} --psf-stack deleted_chunk.zarr --raw raw.tif", "corrupt-store",
         "deleted chunk", "deleted_chunk.zarr"),
    case(f"{V} --psf-stack altered_chunk.zarr --raw raw.tif", "corrupt-store",
         "altered chunk", "altered_chunk.zarr"),
    case(f"{V} --psf-stack trunc_meta.zarr --raw raw.tif", "corrupt-store",
         "truncated zarr.json", "trunc_meta.zarr"),
    case(f"{V} --psf-stack dark.zarr --raw raw.tif", "missing", "run without psf stack",
         "psf_stack"),
    case(f"{V2} --out file.txt/v.tif", "unwritable", "out under a file", "file.txt"),
    case(f"{V2} --out /proc/x/v.zarr", "unwritable", "out in /proc", "/proc/x"),
]

ANALYZE = [
    case(f"{A} --psf-stack nope.tif", "missing", "stack", "nope.tif"),
    case(f"{A} --psf-stack empty.tif --depths 1", "empty", "stack", "empty.tif"),
    case(f"{A} --psf-stack trunc_stack.tif", "truncated", "stack", "trunc_stack.tif"),
    case(f"{A} --psf-stack text.npy --depths 1", "mislabelled", "text npy", "text.npy"),
    case(f"{A} --psf-stack d1.npy --depths 1", "shape", "1-D", "d1.npy"),
    case(f"{A} --psf-stack tiny_stack.npy --depths 2,4,8", "shape", "2x2", "2"),
    case(f"{A} --psf-stack complex_stack.npy --depths 2,4,8", "dtype", "complex", "complex"),
    case(f"{A} --psf-stack nan_stack.tif", "nonfinite", "nan stack", "nan"),
    case(f"{A} --psf-stack stack.npy --depths 2,inf,8", "nonfinite", "inf depth", "depths"),
    case(f"{A} --psf-stack deleted_chunk.zarr", "corrupt-store", "deleted chunk",
         "deleted_chunk.zarr"),
    case(f"{A} --psf-stack nokeys.zarr", "corrupt-store", "attrs lack keys", "nokeys.zarr"),
    case("analyze resolution --psf-stack stack.tif --out o/a", "missing", "no pitch",
         "--pitch-um"),
    case(f"{A2} --pitch-um -13", "number", "pitch negative", "--pitch-um"),
    case(f"{A2} --d-mm nan", "number", "d nan", "--d-mm"),
    case(f"{A2} --bin 0", "number", "bin 0", "--bin"),
    case(f"{A2} --bin 64", "number", "bin too large", "bin"),
    case(f"{A2} --remove-background -1", "number", "remove-background -1", "background"),
    case(f"{A2} --threshold 2", "number", "threshold 2", "threshold"),
    case(f"{A2} --threshold nan", "number", "threshold nan", "threshold"),
    case(f"{A2} --level 0", "number", "level 0", "level"),
    case("analyze similarity --psf-stack stack.tif --out o/a --index 99", "number",
         "index 99", "index"),
    case("analyze similarity --psf-stack stack.tif --out o/a --index -9", "number",
         "index -9", "index"),
    case("analyze condition --psf-stack stack.tif --out o/a --k-max 1", "number", "k-max 1",
         "--k-max"),
    case("analyze condition --psf-stack stack.tif --out o/a --separations-px 0,-1", "number",
         "separations <= 0", "separation"),
    case("analyze condition --psf-stack stack.tif --out o/a --separations-px a", "number",
         "separations a", "separations"),
    case("analyze condition --psf-stack stack.tif --out o/a --depth 50", "number",
         "depth not in stack", "50"),
    case("analyze condition --psf-stack stack.tif --out o/a --axial --separations-planes 0",
         "number", "planes 0", "separations-planes"),
    case("analyze condition --psf-stack stack.tif --out o/a --axial --xz-px -1", "number",
         "xz -1", "xz"),
    case("analyze distinguish --psf-stack stack.tif --out o/a --iterations 0", "number",
         "iterations 0", "iterations"),
    case(f"{A2.replace('resolution', 'grid')} --scene-range 50,10", "number",
         "scene range reversed", "scene-range"),
    case(f"{A2.replace('resolution', 'grid')} --scene-range 10", "number",
         "scene range one value", "scene-range"),
    case(f"{A2.replace('resolution', 'fov')} --alpha-c-deg nan", "number", "alpha nan",
         "alpha"),
    case(f"{A2.replace('resolution', 'fov')} --alpha-c-deg 30 --support-energy 1.5",
         "number", "support energy 1.5", "support"),
    case(f"{A2.replace('resolution', 'fov')} --alpha-c-deg 30 --beta-deg -5", "number",
         "beta -5", "beta"),
    case(f"{A2} --out file.txt/a", "unwritable", "out under a file", "file.txt"),
    case(f"{A2} --out /proc/x/a", "unwritable", "out in /proc", "/proc/x"),
    case("analyze design --focal-mm 5 --out o/a", "number", "design focal beyond d",
         "--focal-mm 5|--distance-mm"),
    case("analyze design --z-mm 2,-1 --out o/a", "number", "design negative depth", "--z-mm"),
    case("analyze design --out file.txt/a", "unwritable", "design out under a file",
         "file.txt"),
]

BENCH = [
    case("validate nope.toml", "missing", "bench file", "nope.toml"),
    case("validate", "missing", "no file no simulate", "--simulate"),
    case("validate empty.toml", "empty", "bench file", "empty.toml"),
    case("validate trunc_bench.toml", "truncated", "bench file", "trunc_bench.toml"),
    case("validate binary.toml", "mislabelled", "binary", "binary.toml"),
    case("validate foreign.toml", "foreign-bench", "not a bench", "foreign.toml"),
    case("validate psf.npy", "mislabelled", "npy as bench", "psf.npy"),
    case("devices nope.toml", "missing", "bench file", "nope.toml"),
    case("devices foreign.toml", "foreign-bench", "not a bench", "foreign.toml"),
    case("devices --timeout 0", "number", "timeout 0", "--timeout"),
    case("devices --timeout nan", "number", "timeout nan", "--timeout"),
    case("devices --timeout -1", "number", "timeout -1", "--timeout"),
    case("devices --timeout inf", "number", "timeout inf", "--timeout|finite"),
]

#: values of the right type that cannot describe the bench: refused at their line
BENCH_FIELDS = [
    case("validate b_geom.toml", "bench-field", "camera shape against the geometry",
         "b_geom.toml:53|sensor_shape [256, 320]|geometry.sensor_shape_px [512, 640]"),
    case("validate b_metres.toml", "bench-field", "distance in metres",
         "b_metres.toml:25|0.0089 mm|diffuser_sensor_distance_mm = 8.9"),
    case("validate b_gain.toml --simulate", "bench-field", "unknown parameter, simulated",
         "b_gain.toml:56|gain_db|max_gain_db"),
    case("validate l_speed.toml --simulate", "bench-field", "negative speed",
         "l_speed.toml:65|speed_mm_s = -2|> 0"),
    case("validate l_serial.toml --simulate", "bench-field", "two axes on one serial number",
         "l_serial.toml:63|axes x, y share serial number '27500101'"),
    case("validate e_counts.toml --simulate", "bench-field", "counts_per_unit 0",
         "e_counts.toml:58|counts_per_unit = 0|> 0"),
    case("devices b_metres.toml", "bench-field", "devices: distance in metres",
         "b_metres.toml:25|metres"),
    case("calibrate dark b_gain.toml --simulate --frames 2 --out o/c.zarr", "bench-field",
         "calibrate: unknown parameter", "b_gain.toml:56|gain_db"),
]

RUNS = [
    case("runs show nope.zarr", "missing", "show", "nope.zarr"),
    case("runs show emptydir", "empty", "show empty dir", "emptydir"),
    case("runs show file.txt", "mislabelled", "show a file", "file.txt"),
    case("runs show trunc_meta.zarr", "corrupt-store", "show truncated zarr.json",
         "trunc_meta.zarr"),
    case("runs show notjson_meta.zarr", "corrupt-store", "show zarr.json not json",
         "notjson_meta.zarr"),
    case("runs show nokeys.zarr", "corrupt-store", "show attrs lack keys", "nokeys.zarr"),
    case("runs verify nope.zarr", "missing", "verify", "nope.zarr"),
    case("runs verify notjson_meta.zarr", "corrupt-store", "verify zarr.json not json",
         "notjson_meta.zarr"),
    case("runs verify nokeys.zarr", "corrupt-store", "verify attrs lack keys", "nokeys.zarr"),
    case("runs export nope.zarr --out o/e.tif", "missing", "export", "nope.zarr"),
    case("runs export run.zarr --product nope --out o/e.tif", "missing", "export product",
         "nope"),
    case("runs export deleted_chunk.zarr --out o/e.tif", "corrupt-store",
         "export deleted chunk", "deleted_chunk.zarr"),
    case("runs export altered_chunk.zarr --out o/e.tif", "corrupt-store",
         "export altered chunk", "altered_chunk.zarr"),
    case("runs export trunc_meta.zarr --out o/e.tif", "corrupt-store",
         "export truncated zarr.json", "trunc_meta.zarr"),
    case("runs export run.zarr --out file.txt/e.tif", "unwritable", "export out under a file",
         "file.txt"),
    case("runs export run.zarr --out /proc/x/e.tif", "unwritable", "export out in /proc",
         "/proc/x"),
    case("runs import-psf nope.tif --out o/i.zarr", "missing", "import", "nope.tif"),
    case("runs import-psf empty.npy --out o/i.zarr", "empty", "import", "empty.npy"),
    case("runs import-psf trunc_stack.tif --out o/i.zarr", "truncated", "import",
         "trunc_stack.tif"),
    case("runs import-psf text.tif --depths 1 --out o/i.zarr", "mislabelled", "import text",
         "text.tif"),
    case("runs import-psf d1.npy --depths 1 --out o/i.zarr", "shape", "import 1-D", "d1.npy"),
    case("runs import-psf d4.npy --depths 1,2 --out o/i.zarr", "shape", "import 4-D",
         "d4.npy"),
    case("runs import-psf stack.npy --depths 2,4 --out o/i.zarr", "shape",
         "import depths count", "depths"),
    case("runs import-psf complex_stack.npy --depths 2,4,8 --out o/i.zarr", "dtype",
         "import complex", "complex"),
    case("runs import-psf str.npy --depths 2 --out o/i.zarr", "dtype", "import str",
         "str.npy"),
    case("runs import-psf nan_stack.npy --depths 2,4,8 --out o/i.zarr", "nonfinite",
         "import nan", "nan"),
    case("runs import-psf stack.npy --depths 2,a,8 --out o/i.zarr", "number",
         "import depths a", "--depths"),
    case("runs import-psf stack.npy --depths 2,nan,8 --out o/i.zarr", "number",
         "import depths nan", "depths"),
    case("runs import-psf stack.npy --depths 8,4,-2 --out o/i.zarr", "number",
         "import depths negative", "depths"),
    case("runs import-psf stack.tif --out file.txt/i.zarr", "unwritable",
         "import out under a file", "file.txt"),
    case("runs import-psf stack.tif --out dir", "clash", "import out is a plain dir", "dir"),
    case("runs import-psf stack.tif --out dir --overwrite", "clash",
         "import overwrite a plain dir", "dir"),
    case("runs import-psf stack.tif --out file.txt --overwrite", "clash",
         "import overwrite a file", "file.txt"),
    case("runs import-psf stack.tif --out run.zarr", "clash", "import out exists",
         "run.zarr"),
    case("runs import-psf stack.tif --out locked.zarr --overwrite", "locked-store",
         "import overwrite a locked run", "locked.zarr"),
]

BENCHMARK = [
    case("benchmark recon --quick --out file.txt/b", "unwritable", "out under a file",
         "file.txt"),
    case("benchmark recon --quick --out /proc/x/b", "unwritable", "out in /proc", "/proc/x"),
    case("benchmark recon --quick --only nonsense --out o/b", "number", "only nonsense",
         "nonsense"),
    case("benchmark live --seconds 0", "number", "seconds 0", "--seconds 0"),
    case("benchmark live --fps nan", "number", "fps nan", "--fps nan"),
    case("benchmark live --iterations 0", "number", "iterations 0", "--iterations 0"),
    case("benchmark live --threads 0", "number", "threads 0", "threads=0"),
    case("benchmark live --json file.txt", "clash", "json exists", "file.txt|exists"),
    case("benchmark live --json file.txt/b.json", "unwritable", "json under a file",
         "file.txt"),
]

#: resources a command cannot have (memory, cores, frames, a scheduler), refused before
#: any work
RESOURCE = [
    case("holo benchmark --slm 100000 100000", "resource", "hologram beyond memory",
         "--slm 100000 100000|GiB of memory"),
    case("holo evaluate --size 1000000 --out o/h", "resource", "evaluation beyond memory",
         "--size 1000000|GiB of memory"),
    case("capture video --simulate --seconds 1e308 --out o/v.zarr", "resource",
         "recording of 1e308 s", "--seconds 1e+308|at most"),
    case("capture video --simulate --frames 99999999 --out o/v.zarr", "resource",
         "recording of 1e8 frames", "99999999|at most"),
    case("recon-run dark.zarr --psf frame_psf.npy --workers 1000000 --frames 0:2", "resource",
         "workers beyond the cores", "--workers 1000000|cores"),
    case("recon-run dark.zarr --psf frame_psf.npy --scheduler notaurl", "resource",
         "scheduler not an address", "--scheduler 'notaurl'|tcp://HOST:PORT"),
    case("recon-run dark.zarr --psf frame_psf.npy --scheduler tcp://127.0.0.1:9", "resource",
         "scheduler port closed", "--scheduler tcp://127.0.0.1:9|nothing answers"),
]

#: options a command would otherwise ignore
IGNORED = [
    # before: Wiener ran without the prior, silently
    case(f"{R2} --method wiener --prior dncnn", "ignored-option", "prior with wiener",
         "--prior dncnn|--method wiener|--method admm"),
    case("emulators start --duration-s nan", "ignored-option", "duration nan",
         "--duration-s|nan"),
    case("emulators start --duration-s -1", "ignored-option", "duration negative",
         "--duration-s|-1"),
    case("holo evaluate --quick --size 1000000 --out o/h", "ignored-option",
         "evaluate --quick with --size", "--quick sets --size 48|drop --size"),
    case("holo benchmark --quick --slm 100 100", "ignored-option",
         "benchmark --quick with --slm", "--quick sets --slm 36 64|drop --slm"),
]

#: only known extensions are extensions
OUT_NAMES = [
    case("runs export run.zarr --out o/e.png", "out-name", "export under a png name",
         "o/e.png|.tif"),
    case("runs export run.zarr --out o/e", "out-name", "export without an extension",
         "o/e|.tif"),
]

HE = "holo evaluate --out o/h"
HB = "holo benchmark --quick"
HOLO = [
    case(f"{HE} --size 0", "number", "size 0", "--size"),
    case(f"{HE} --size -48", "number", "size -48", "--size"),
    case(f"{HE} --iterations 0", "number", "iterations 0", "--iterations"),
    case(f"{HE} --factors a", "number", "factors a", "--factors"),
    case(f"{HE} --factors 0", "number", "factors 0", "factor 0"),
    case(f"{HE} --factors 5", "number", "factors not square", "factor 5"),
    case(f"{HE} --seeds -1", "number", "seeds -1", "--seeds"),
    case(f"{HE} --seeds ,", "number", "seeds empty", "--seeds"),
    case(f"{HE} --methods bogus", "number", "methods bogus", "bogus"),
    case(f"{HE} --methods ,", "number", "methods empty", "--methods"),
    case(f"{HE} --images nope", "missing", "images", "nope"),
    case(f"{HE} --images emptydir", "empty", "images", "emptydir"),
    case(f"{HE} --images file.txt", "mislabelled", "images is a file", "file.txt"),
    case("holo evaluate --quick --out file.txt/h", "unwritable", "out under a file",
         "file.txt"),
    case("holo evaluate --quick --out /proc/x/h", "unwritable", "out in /proc", "/proc/x"),
    case("holo benchmark --factor 5", "number", "factor 5", "--factor"),
    case("holo benchmark --slm 0 10", "number", "slm 0", "--slm"),
    case("holo benchmark --iterations 0", "number", "iterations 0", "--iterations"),
    case("holo benchmark --fft-repeats -1", "number", "fft repeats -1", "--fft-repeats"),
    case(f"{HB} --json file.txt/h.json", "unwritable", "json under a file", "file.txt"),
    case(f"{HB} --json /proc/x/h.json", "unwritable", "json in /proc", "/proc/x"),
    case(f"{HB} --json dir", "clash", "json is a directory", "dir"),
    case(f"{HB} --json raw.tif", "clash", "json exists", "exists"),
]

C = "calibrate {} --simulate --out o/c.zarr"
CD = C.format("dark") + " --frames 2"
CS, CG = C.format("psf-sweep") + " --frames 1", C.format("psf-grid") + " --frames 1"
CA, CL = C.format("angular-response") + " --frames 1", C.format("slm-lut") + " --frames 1"
CALIBRATE = [
    case("calibrate dark nope.toml --out o/c.zarr", "missing", "bench file", "nope.toml"),
    case("calibrate dark --out o/c.zarr", "missing", "no bench no simulate", "--simulate"),
    case("calibrate dark empty.toml --simulate --out o/c.zarr", "empty", "bench", "empty.toml"),
    case("calibrate dark trunc_bench.toml --simulate --out o/c.zarr", "truncated", "bench",
         "trunc_bench.toml"),
    case("calibrate dark foreign.toml --simulate --out o/c.zarr", "foreign-bench",
         "not a bench", "foreign.toml"),
    case("calibrate dark binary.toml --simulate --out o/c.zarr", "mislabelled",
         "binary bench", "binary.toml"),
    case(f"{CD} --frames 0", "number", "frames 0", "frames"),
    case(f"{CD} --frames -3", "number", "frames -3", "frames"),
    case(f"{CD} --exposure-s -1", "number", "exposure -1", "exposure"),
    case(f"{CD} --exposure-s nan", "number", "exposure nan", "exposure"),
    case(f"{CD} --reconnect-timeout -1", "number", "reconnect timeout -1", "reconnect"),
    case(f"{CD} --reconnect-timeout inf", "number", "reconnect timeout inf",
         "--reconnect-timeout inf|finite"),
    case(f"{CD} --seed -1", "number", "seed -1", "seed"),
    case("calibrate dark --simulate --out file.txt/c.zarr", "unwritable", "out under a file",
         "file.txt"),
    case("calibrate dark --simulate --out /proc/x/c.zarr", "unwritable", "out in /proc",
         "/proc/x"),
    case("calibrate dark --simulate --out run.zarr", "clash", "out is an existing run",
         "run.zarr"),
    case("calibrate dark --simulate --out raw.tif", "clash", "out is a file", "raw.tif"),
    case("calibrate dark --simulate --out dir --overwrite", "clash",
         "overwrite a plain dir", "dir"),
    case("calibrate dark --simulate --out locked.zarr --overwrite", "locked-store",
         "overwrite a locked run", "locked.zarr"),
    case(f"{CS} --z-min 100 --z-max 20", "number", "z range reversed", "z"),
    case(f"{CS} --z-min -10 --z-max 20", "number", "z-min negative", "z"),
    case(f"{CS} --z-min nan", "number", "z-min nan", "z"),
    case(f"{CS} --n-depths 0", "number", "n-depths 0", "depths"),
    case(f"{CS} --c-per-mm -1", "number", "c-per-mm -1", "--c-per-mm|must be > 0"),
    case(f"{CG} --n 0", "number", "n 0", "n"),
    case(f"{CG} --n -3", "number", "n -3", "n"),
    case(f"{CG} --n 2 --led-step 0", "number", "led-step 0", "led"),
    case(f"{CG} --n 2 --mode stage --spacing-mm -1", "number", "spacing -1", "spacing"),
    case(f"{CG} --mode stage --z-mm 0", "number", "z 0", "z"),
    case(f"{CG} --n 2 --falloff-sigma-deg nan", "number", "falloff nan", "falloff"),
    case(f"{CG} --falloff-run nope.zarr", "missing", "falloff run", "nope.zarr"),
    case(f"{CG} --falloff-run dark.zarr", "foreign-bench", "falloff run of another routine",
         "dark.zarr"),
    case(f"{CA} --n-angles 0", "number", "n-angles 0", "angles"),
    case(f"{CA} --max-angle-deg -5", "number", "max angle -5", "angle"),
    case(f"{CA} --max-angle-deg 100", "number", "max angle 100", "angle"),
    case(f"{CA} --n-angles 3 --z-mm 0", "number", "source at z 0", "z"),
    case(f"{CL} --levels 3", "number", "levels 3", "levels"),
    case(f"{CL} --levels 1000", "number", "levels 1000", "levels"),
    case(f"{CL} --period-px 7", "number", "period odd", "period"),
    case(f"{CL} --period-px 0", "number", "period 0", "period"),
    case("calibrate resume nope.zarr --simulate", "missing", "run", "nope.zarr"),
    case("calibrate resume dir --simulate", "mislabelled", "plain dir", "dir"),
    case("calibrate resume notjson_meta.zarr --simulate", "corrupt-store", "zarr.json",
         "notjson_meta.zarr"),
    case("calibrate resume nokeys.zarr --simulate", "corrupt-store", "attrs lack keys",
         "nokeys.zarr"),
    case("calibrate resume locked.zarr --simulate", "locked-store", "locked run",
         "locked.zarr|is writing it"),
    case("calibrate resume stale_lock.zarr --simulate", "locked-store", "stale lock",
         "stale lock|stale_lock.zarr/.lock"),
    case("calibrate resume dark.zarr --simulate --redo a", "number", "redo a", "--redo"),
    case("calibrate resume dark.zarr --simulate --redo 999", "number", "redo 999", "999"),
    case("calibrate resume dark.zarr foreign.toml --simulate", "foreign-bench",
         "not a bench", "foreign.toml"),
    case("calibrate resume dark.zarr other_bench.toml --simulate", "foreign-bench",
         "bench of another setup", "another set-up|diffuser_sensor_distance_mm"),
]

AM = "align mask --simulate --out o/al.align"
ALIGN = [
    case(f"{AM} --mask-pattern nope.npy", "missing", "pattern", "nope.npy"),
    case(f"{AM} --mask-pattern empty.npy", "empty", "pattern", "empty.npy"),
    case(f"{AM} --mask-pattern trunc_psf.npy", "truncated", "pattern", "trunc_psf.npy"),
    case(f"{AM} --mask-pattern text.npy", "mislabelled", "pattern", "text.npy"),
    case(f"{AM} --mask-pattern bad_pattern.npy", "shape", "pattern", "bad_pattern.npy"),
    case(f"{AM} --mask-pattern complex.npy", "dtype", "pattern", "complex.npy"),
    case(f"{AM} --mask-pattern object.npy", "dtype", "object pattern", "object.npy"),
    case(f"{AM} --mask-pattern nan.npy", "nonfinite", "pattern", "nan.npy"),
    case(f"{AM} --k 0", "number", "k 0", "k"),
    case(f"{AM} --frames 0", "number", "frames 0", "frames"),
    case(f"{AM} --coarse-range-px -1", "number", "coarse range -1", "coarse"),
    case(f"{AM} --relay-na nan", "number", "relay na nan", "na"),
    case(f"{AM} --relay-na -0.1", "number", "relay na -0.1", "na"),
    case(f"{AM} --focus-range-mm 0", "number", "focus range 0", "focus"),
    case(f"{AM} --mask-margin -1", "number", "margin -1", "margin"),
    case(f"{AM} --lut nope.zarr", "missing", "lut", "nope.zarr"),
    case(f"{AM} --lut dark.zarr", "foreign-bench", "lut is a dark run", "dark.zarr"),
    case(f"{AM} --lut text.npy", "mislabelled", "lut text", "text.npy"),
    case("align mask --simulate --out file.txt/al.align", "unwritable", "out under a file",
         "file.txt"),
    case("align mask --simulate --out /proc/x/al.align", "unwritable", "out in /proc",
         "/proc/x"),
    case("align mask --simulate --out raw.tif", "clash", "out is a file", "raw.tif"),
    case("align mask foreign.toml --simulate --out o/al.align", "foreign-bench",
         "not a bench", "foreign.toml"),
    case("align mask --out o/al.align", "missing", "real bench without pattern", "pattern"),
]

DEMO = [
    case("demo --out o/demo --iterations 0", "number", "iterations 0", "--iterations"),
    case("demo --out o/demo --method newton", "number", "method", "newton"),
    case("demo --out o/demo --seed x", "number", "seed x", "--seed"),
    case("demo --out o/demo --seed -1", "number", "seed -1", "--seed"),
    case("demo --out file.txt", "clash", "out is a file", "file.txt|not a directory"),
    case("demo --real-sample --out o/demo --iterations -1", "number", "real sample it -1",
         "--iterations"),
    case("demo --out /proc/x/demo", "unwritable", "out in /proc", "/proc/x"),
    case("demo --out file.txt/demo", "unwritable", "out under a file", "file.txt"),
]

CL = "capture live --simulate --seconds 1"
CAPTURE = [
    case(f"{CL} --psf nope.npy", "missing", "psf", "nope.npy"),
    case(f"{CL} --psf empty.npy", "empty", "psf", "empty.npy"),
    case(f"{CL} --psf psf.npy", "shape", "psf of another shape", "32x32|256x320"),
    case(f"{CL} --psf psf.npy --method bogus", "number", "method", "--method 'bogus'"),
    case(f"{CL} --psf psf.npy --seconds 0", "number", "seconds 0", "--seconds 0"),
    case(f"{CL} --psf psf.npy --preview-png raw.tif", "clash", "preview exists",
         "raw.tif|exists"),
    case(f"{CL} --psf psf.npy --preview-png file.txt/p.png", "unwritable",
         "preview under a file", "file.txt"),
    case("capture live foreign.toml --simulate --psf psf.npy", "foreign-bench",
         "not a bench", "foreign.toml"),
]

CV = "capture video --simulate --frames 2"
RR = "recon-run dark.zarr --iterations 2"
VIDEO = [
    case(f"{CV} --out o/v.zarr --frames 0", "number", "frames 0", "--frames 0"),
    case(f"{CV} --out o/v.zarr --compressor gzip", "number", "compressor", "gzip"),
    case(f"{CV} --out o/v.zarr --shard-frames 0", "number", "shard frames", "--shard-frames 0"),
    case(f"{CV} --out raw.tif", "clash", "out exists", "raw.tif|exists"),
    case(f"{CV} --out file.txt/v.zarr", "unwritable", "out under a file", "file.txt"),
    case(f"{CV} --out o/v.zarr --live-recon wiener --psf nope.npy", "missing", "live psf",
         "nope.npy"),
    case("capture video foreign.toml --simulate --frames 2 --out o/v.zarr", "foreign-bench",
         "not a bench", "foreign.toml"),
    case("recon-run nope.zarr --psf psf.npy", "missing", "run", "nope.zarr"),
    case(f"{RR} --psf nope.npy", "missing", "psf", "nope.npy"),
    case(f"{RR} --psf psf.npy", "shape", "psf of another shape", "32|frames are"),
    case(f"{RR} --psf psf.npy --frames x", "number", "frames x", "--frames 'x'"),
    case(f"{RR} --psf psf.npy --dff 120", "number", "dff 120", "--dff 120"),
    # before: each frame failed in its worker (exit 1) and the product was made
    case(f"{RR} --psf frame_psf.npy --dark rgb_dark.npy", "shape", "colour dark frame",
         "dark frame is|x3 but the frames of --psf frame_psf.npy are"),
    case(f"{RR} --psf frame_psf.npy --dark 1e6", "no-signal", "dark level above the psf",
         "PSF has no signal above the dark level|1000000"),
    case(f"{RR} --psf frame_psf.npy --dark 500", "no-signal", "dark level above the frames",
         "frame 0 of dark.zarr|below the dark level 500"),
    case(f"{RR} --psf frame_psf.npy --method wiener --prior dncnn", "ignored-option",
         "prior with wiener", "--prior dncnn|--method wiener|--method admm"),
    # a calibration run's dark-subtracted PSF without a dark level: test_calibrate's
    # test_recon_takes_one_depth_of_a_run and test_recon_flags' test_dark_has_one_meaning
    # (a TIFF stack is a PSF as measured: its dark corner, as in every command)
    case("recon-run trunc_meta.zarr --psf psf.npy", "corrupt-store", "truncated zarr.json",
         "trunc_meta.zarr"),
    case("recon-run locked.zarr --psf psf.npy", "locked-store", "locked run", "locked.zarr"),
    case("gui nope.toml", "missing", "bench file", "nope.toml"),
    case("bench serve nope.toml", "missing", "bench file", "nope.toml"),
    case("gui foreign.toml --simulate", "foreign-bench", "not a bench", "foreign.toml"),
    case("emulators start --time-scale 0 --duration-s 0.1", "number", "time scale 0",
         "--time-scale"),
    case("emulators start --bench-out raw.tif --duration-s 0.1", "clash", "bench-out exists",
         "raw.tif|exists"),
]

TABLE = {"recon": RECON, "no-signal": NO_SIGNAL, "colour": COLOUR, "messages": MESSAGES,
         "demo": DEMO, "recon3d": RECON3D,
         "analyze": ANALYZE, "validate/devices": BENCH, "bench-field": BENCH_FIELDS,
         "runs": RUNS, "out-name": OUT_NAMES, "benchmark": BENCHMARK, "holo": HOLO,
         "resource": RESOURCE, "ignored-option": IGNORED,
         "calibrate": CALIBRATE, "align": ALIGN, "capture": CAPTURE, "video": VIDEO}
ALL = [c for rows in TABLE.values() for c in rows]


@pytest.mark.parametrize("argv, words", ALL)
def test_bad_input_is_one_error_line_and_changes_nothing(d, capsys, argv, words):
    assert_refused(argv, words, d, capsys)


def test_the_table_covers_every_class_and_command():
    classes = Counter(p.id.split(":")[1] for p in ALL)
    assert set(classes) == set(CLASSES), set(CLASSES) - set(classes)
    from instrument.cli import build_parser

    commands = set(build_parser()._subparsers._group_actions[0].choices)
    covered = {p.values[0][0] for p in ALL}
    assert commands <= covered, commands - covered
    assert len({p.id for p in ALL}) == len(ALL), "case ids must be unique"

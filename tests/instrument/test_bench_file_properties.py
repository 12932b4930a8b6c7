"""Property-based tests of the bench-file parser
(:func:`instrument.devices.bench_setup.parse_bench`,
:func:`instrument.devices.bench_setup.load_bench`, the writer :func:`instrument.config.to_toml`).

* whatever the input (any bytes, any text, the example files with any line mangled),
  the parser returns a bench or raises :class:`BenchConfigError`, never anything else;
* every valid bench (the examples with their numbers moved within their ranges, any
  name and description) survives ``to_toml`` -> ``parse_bench`` unchanged;
* every number out of its range (negative, zero where the range is open, too large,
  NaN, infinite) is reported at its location and TOML line;
* independent problems anywhere in a file are all reported in one pass, each once.

Derandomized and without an example database, so a CI run is deterministic. No
generated file has a large sensor, LED or SLM shape: the simulated drivers allocate
arrays of that size when constructed.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from instrument.config import (
    BenchConfig,
    BenchConfigError,
    CalibrationDefaults,
    GeometryConfig,
    default_bench,
    to_toml,
)
from instrument.config.base import Ordered, Range
from instrument.config.rules import MIN_LENGTH_MM
from instrument.devices.bench_setup import load_bench, parse_bench

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
SIM_TEXT = (EXAMPLES / "bench-simulated.toml").read_text()
LAB_TEXT = (EXAMPLES / "bench-lab.toml").read_text()
DEFAULT_TEXT = to_toml(default_bench())

PROPERTY = settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)


def _problems(text: str, **options: Any) -> list:
    with pytest.raises(BenchConfigError) as info:
        parse_bench(text, source="bench.toml", **options)
    return info.value.problems


def _line_of(text: str, prefix: str) -> int:
    """1-based number of the first line starting with ``prefix``."""
    return next(n for n, line in enumerate(text.splitlines(), 1) if line.startswith(prefix))


def _set_value(text: str, key: str, value: str, nth: int = 0) -> str:
    """``text`` with the value of the nth ``key = ...`` line replaced by ``value``."""
    lines = text.splitlines()
    hits = [i for i, line in enumerate(lines) if line.startswith(f"{key} = ")]
    lines[hits[nth]] = f"{key} = {value}"
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------ (a) any input at all

# Values that stress the parser: non-finite, huge, wrong types, nesting. No pair of
# large numbers: a simulated driver allocates arrays of a shape it is given.
EVIL_VALUES = [
    "nan", "+nan", "-nan", "inf", "-inf", "1e400", "-1e400", "0", "-0.0", "-1", "1e-400",
    "9" * 30, "-" + "9" * 30, "9" * 5000, "0x7fffffffffffffff", "true", "false",
    '"5 cm"', '"x"', '""', "''' '''", "[]", "{}", "[0, 0]", "[1, 2, 3]", "[-1, 5]",
    "[nan, 1]", '["a", 1]', "[[1, 2], [3]]", "{a = 1}", "{x = {y = [nan]}}",
    "1979-05-27", "07:32:00", "[" * 40 + "]" * 40, "{a = " * 40 + "1" + "}" * 40,
    "[" * 2000 + "]" * 2000, '"\\u0000"', "[true, 2.5]",
]
ASSIGNMENT_LINES = [
    n for n, line in enumerate(SIM_TEXT.splitlines()) if " = " in line and not line.startswith("#")
]


@st.composite
def mangled_examples(draw) -> str:
    """An example file with a few lines' values replaced, lines dropped, duplicated or
    inserted."""
    lines = draw(st.sampled_from([SIM_TEXT, LAB_TEXT])).splitlines()
    for _ in range(draw(st.integers(1, 4))):
        action = draw(st.sampled_from(["value", "value", "drop", "copy", "insert"]))
        n = draw(st.integers(0, len(lines) - 1))
        if action == "value" and " = " in lines[n]:
            key = lines[n].split(" = ", 1)[0]
            lines[n] = f"{key} = {draw(st.sampled_from(EVIL_VALUES))}"
        elif action == "drop":
            del lines[n]
        elif action == "copy":
            lines.insert(n, lines[n])
        elif action == "insert":
            lines.insert(n, draw(st.text(max_size=30).map(lambda t: t.replace("\n", " "))))
    return "\n".join(lines) + "\n"


@PROPERTY
@given(text=st.text(max_size=400), simulate=st.booleans())
def test_any_text_is_a_bench_or_a_bench_config_error(text, simulate):
    try:
        parse_bench(text, construct=True, simulate=simulate)
    except BenchConfigError as exc:
        assert exc.problems and all(p.fix for p in exc.problems)


@PROPERTY
@given(data=st.binary(max_size=400))
def test_any_bytes_in_a_file_are_a_bench_or_a_bench_config_error(data):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.toml"
        path.write_bytes(data)
        try:
            load_bench(path, construct=True)
        except BenchConfigError as exc:
            assert exc.problems and str(path) in exc.lines()[0]


def _check_one_line_per_problem(text: str, simulate: bool) -> None:
    try:
        parse_bench(text, source="bench.toml", construct=True, simulate=simulate)
    except BenchConfigError as exc:
        lines = exc.lines()
        assert lines and all(line.startswith("bench.toml") for line in lines)
        assert all("\n" not in line and "; fix: " in line for line in lines)
        assert all(len(line) < 1500 for line in lines)  # huge values are cut
        assert len(set(lines)) == len(lines)  # nothing said twice


@PROPERTY
@given(text=mangled_examples(), simulate=st.booleans())
def test_mangled_example_files_give_one_located_line_per_problem(text, simulate):
    _check_one_line_per_problem(text, simulate)


@pytest.mark.parametrize("value", EVIL_VALUES, ids=lambda v: v[:20])
@settings(PROPERTY, max_examples=8)
@given(line=st.sampled_from(ASSIGNMENT_LINES), simulate=st.booleans())
def test_each_hostile_value_on_any_line_gives_one_located_line_per_problem(value, line, simulate):
    lines = SIM_TEXT.splitlines()
    lines[line] = f"{lines[line].split(' = ', 1)[0]} = {value}"
    _check_one_line_per_problem("\n".join(lines) + "\n", simulate)


# ------------------------------------------------------------------ (b) round trip


def _ranged_fields(model: type) -> list[tuple[str, Range, bool, Ordered | None]]:
    """(name, range, is a pair, order) of every field of ``model`` with a Range."""
    out = []
    for name, field in model.model_fields.items():
        rng = next((m for m in field.metadata if isinstance(m, Range)), None)
        if rng is not None:
            order = next((m for m in field.metadata if isinstance(m, Ordered)), None)
            out.append((name, rng, "tuple" in str(field.annotation), order))
    return out


RANGED = {
    "geometry": _ranged_fields(GeometryConfig),
    "calibration": _ranged_fields(CalibrationDefaults),
}


def _in_range(rng: Range) -> st.SearchStrategy:
    if rng.integer:
        low = int(rng.lo) + 1 if rng.lo_open else int(rng.lo)
        return st.integers(low, int(min(rng.hi, 4096)))  # small: no huge sensor arrays
    return st.floats(rng.lo, rng.hi, exclude_min=rng.lo_open, allow_nan=False)


@st.composite
def valid_sections(draw, section: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, rng, pair, order in RANGED[section]:
        if not pair:
            out[name] = draw(_in_range(rng))
            continue
        a, b = draw(_in_range(rng)), draw(_in_range(rng))
        if order is not None:
            a, b = min(a, b), max(a, b)
            assume(not order.strict or a < b)
        out[name] = (a, b)
    return out


def _finite(x: Any) -> st.SearchStrategy:
    """A new number of the same type as ``x``, positive like the examples' parameters."""
    if isinstance(x, int):
        return st.integers(1, 64)
    return st.floats(1e-6, 1e6, allow_nan=False)


@st.composite
def valid_benches(draw) -> tuple[BenchConfig, str]:
    """The default bench or the lab example, every number moved within its range; and
    which of the two it is."""
    base = draw(st.sampled_from(["default", "lab"]))
    config = default_bench() if base == "default" else parse_bench(LAB_TEXT, check_drivers=False)
    data = config.model_dump()
    data["name"] = draw(st.text(min_size=1, max_size=20).filter(str.strip))
    data["description"] = draw(st.text(max_size=40))
    for section in ("geometry", "calibration"):
        data[section].update(draw(valid_sections(section)))
    for dev in data["devices"]:
        params = dev["params"]
        for key, value in params.items():
            if isinstance(value, int | float) and not isinstance(value, bool):
                params[key] = draw(_finite(value))
        axes = params.get("axes")
        if isinstance(axes, dict):
            for axis in axes:
                lo, hi = sorted(draw(st.lists(st.floats(-1e4, 1e4), min_size=2, max_size=2,
                                              unique=True)))
                axes[axis] = [lo, hi]
        _physical(dev, data["geometry"])
    geometry = data["geometry"]
    geometry["diffuser_sensor_distance_mm"] = max(geometry["diffuser_sensor_distance_mm"],
                                                  MIN_LENGTH_MM)
    geometry["aperture_mm"] = tuple(max(v, MIN_LENGTH_MM) for v in geometry["aperture_mm"])
    return BenchConfig.model_validate(data), base


def _physical(dev: dict, geometry: dict) -> None:
    """The rules of instrument.config.rules on a drawn device: the camera's sensor is the
    geometry's, an LED array's lengths are millimetres (not metres)."""
    params = dev["params"]
    if dev["kind"] == "camera":
        if "pixel_pitch_um" in params:
            params["pixel_pitch_um"] = geometry["sensor_pixel_pitch_um"]
        for key in ("sensor_shape", "sensor_shape_px", "shape_px", "size_px"):
            if key in params:
                params[key] = list(geometry["sensor_shape_px"])
    if dev["kind"] == "led_array":
        for key in ("pitch_mm", "distance_mm"):
            if key in params:
                params[key] = max(params[key], MIN_LENGTH_MM)


@PROPERTY
@given(generated=valid_benches())
def test_every_valid_bench_round_trips_through_toml(generated):
    config, base = generated
    text = to_toml(config)
    again = parse_bench(text, check_drivers=base == "default")
    assert again == config
    assert to_toml(again) == text


# ------------------------------------------------- (c) numbers out of their range


def _out_of_range(rng: Range) -> st.SearchStrategy:
    above = st.floats(rng.hi, 1e300, exclude_min=True, allow_nan=False)
    below = st.floats(-1e300, rng.lo, exclude_max=not rng.lo_open, allow_nan=False)
    literals = st.sampled_from([math.nan, math.inf, -math.inf])
    if rng.integer:  # integers outside, written as integers
        return st.one_of(
            st.integers(int(rng.hi) + 1, 10**30),
            st.integers(-(10**30), math.ceil(rng.lo) - (0 if rng.lo_open else 1)),
        )
    return st.one_of(above, below, literals)


def _toml_number(x: float | int) -> str:
    if isinstance(x, float) and math.isnan(x):
        return "nan"
    if isinstance(x, float) and math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return repr(x)


FIELDS = [(section, f) for section, fields in RANGED.items() for f in fields]


@PROPERTY
@given(data=st.data())
def test_every_number_out_of_range_is_reported_at_its_line(data):
    section, (name, rng, pair, _) = data.draw(st.sampled_from(FIELDS))
    bad = data.draw(_out_of_range(rng))
    good = getattr(getattr(default_bench(), section), name)
    if pair:
        slot = data.draw(st.integers(0, 1))
        values = [_toml_number(v) for v in good]
        values[slot] = _toml_number(bad)
        literal = f"[{', '.join(values)}]"
    else:
        literal = _toml_number(bad)
    text = _set_value(DEFAULT_TEXT, name, literal)
    found = _problems(text)
    assert [(p.location, p.line) for p in found] == [(f"{section}.{name}", _line_of(text, name))]
    assert "out of range" in found[0].message
    assert name in found[0].fix


# Parameters of the default bench's devices the simulated drivers check, with the
# values they refuse (each device is constructed by validate, as with `construct`).
DRIVER_LIMITS = {
    # key (nth occurrence): (device index, refused values)
    ("pixel_pitch_um", 0): (0, st.floats(-1e300, 0.0) | st.sampled_from([math.nan, math.inf])),
    ("adc_bits", 0): (0, st.integers(-(10**6), 7) | st.integers(17, 10**6)),
    ("pitch_mm", 0): (2, st.floats(-1e300, 0.0) | st.sampled_from([math.nan, -math.inf])),
    ("distance_mm", 0): (2, st.floats(-1e300, 0.0) | st.just(math.inf)),
    ("pixel_pitch_um", 1): (3, st.floats(-1e300, 0.0) | st.just(math.nan)),
    ("wavelength_nm", 1): (3, st.floats(-1e300, 0.0) | st.just(math.inf)),
}


@PROPERTY
@given(data=st.data(), simulate=st.booleans())
def test_every_driver_parameter_out_of_range_is_reported_at_its_line(data, simulate):
    (key, nth), (index, values) = data.draw(st.sampled_from(list(DRIVER_LIMITS.items())))
    text = _set_value(DEFAULT_TEXT, key, _toml_number(data.draw(values)), nth)
    found = _problems(text, construct=True, simulate=simulate)
    line = [n for n, t in enumerate(text.splitlines(), 1) if t.startswith(f"{key} = ")][nth]
    assert [(p.location, p.line) for p in found] == [(f"devices[{index}].params.{key}", line)]
    assert "refused" in found[0].message and key in found[0].fix


# ----------------------------------------- (d) independent problems, all at once

# (text to replace, replacement, location reported). Each changes a different key, and
# none makes another one moot, so any subset gives exactly its own problems.
INJECTIONS = [
    ('name = "simulated"', 'name = " "', "name"),
    ("sensor_pixel_pitch_um = 13.0", "sensor_pixel_pitch_um = -13.0",
     "geometry.sensor_pixel_pitch_um"),
    ('diffuser_kind = "smooth"', 'diffuser_kind = "rough"', "geometry.diffuser_kind"),
    ("z_range_mm = [20.0, 200.0]", "z_range_mm = [200.0, 20.0]", "calibration.z_range_mm"),
    ("exposure_bounds_s = [1e-05, 1.0]", "exposure_bounds_s = [1.0, 1e-05]",
     "calibration.exposure_bounds_s"),
    ("n_depths = 32", "n_depths = 0", "calibration.n_depths"),
    ("dark_frames = 32", "dark_frmes = 32", "calibration.dark_frmes"),
    ('id = "camera"', 'id = "Camera X"', "devices[0].id"),
    ("adc_bits = 12", "adc_bits = 3", "devices[0].params.adc_bits"),
    ("\npixel_pitch_um = 13.0", "\npixel_pitch_um = -1.0", "devices[0].params.pixel_pitch_um"),
    ("x = [-25.0, 25.0], y", "x = [25.0, -25.0], y", "devices[1].params.axes.x"),
    ('driver = "simulated-led-array"', 'driver = "acme-leds"', "devices[2].driver"),
    ("pitch_mm = 4.0", 'pitch_mm = "4 cm"', "devices[2].params.pitch_mm"),
    ("resolution = [96, 120]", "resolution = [0, 120]", "devices[3].params.resolution"),
    ("wavelength_nm = 532.0\n\n[[devices]]", "wavelength_nm = 532.0\nfoo = 1\n\n[[devices]]",
     "devices[3].params.foo"),
    ('id = "mask_stage"', 'id = "slm"', "devices[4].id"),
    ('kind = "stage"\ndriver = "simulated-stage"\n\n[devices.params]\naxes = {x = [-5.0',
     'kind = "stage"\ndriver = "simulated-slm"\n\n[devices.params]\naxes = {x = [-5.0',
     "devices[4].driver"),
]


@PROPERTY
@given(chosen=st.sets(st.sampled_from(range(len(INJECTIONS))), min_size=1))
def test_independent_problems_are_all_reported_in_one_pass(chosen):
    text = DEFAULT_TEXT
    for i in sorted(chosen):
        old, new, _ = INJECTIONS[i]
        assert text.count(old) >= 1, old
        text = text.replace(old, new, 1)
    found = _problems(text, construct=True)
    assert sorted(p.location for p in found) == sorted(INJECTIONS[i][2] for i in chosen)
    assert all(p.line is not None for p in found)
    lines = text.splitlines()
    for p in found:  # each on the line of its own key
        assert p.location.rsplit(".", 1)[-1] in lines[p.line - 1], (str(p), lines[p.line - 1])

"""The bench subcommands of ``diffuserlab``: ``validate``, ``devices`` and ``bench serve``
(:mod:`instrument.cli.bench_serve`).

``diffuserlab validate [BENCH.toml] [--simulate]``
    Check a bench file (with ``--simulate`` and no file: the built-in simulated
    bench), constructing (not opening) every device so that parameter
    values a driver refuses are reported too. Prints ``ok: N devices ...`` (exit 0),
    or every problem on its own line,
    ``diffuserlab: error: FILE:LINE: LOCATION: MESSAGE; fix: FIX`` (exit 2). With
    ``--simulate`` the drivers are not looked up as written: every device is checked
    with its simulated twin, so a lab file validates on a machine without the
    hardware drivers; the swaps are listed.

``diffuserlab devices [BENCH.toml] [--simulate] [--timeout S] [--settings] [--json]``
    Open every device of the bench (without a file: the built-in simulated bench),
    print one line per device (id, kind, driver, status) and close them again.
    ``--settings`` adds each device's settings under it: value, unit and limits, read
    from the open device (:meth:`drivers.base.Device.setting_specs` with its
    ``info``). ``--json`` prints one JSON document instead, for other programs: per
    device its status, its settings' values, their declarations with the device's
    limits, and a JSON schema of the writable settings
    (:func:`drivers.settings.settings_model`) that a settings table for the device
    must satisfy. Exit 2 on a bad bench file or driver, 1 if a device fails to open
    (the ones opened before it are closed again).
"""

from __future__ import annotations

import argparse
import json
import math
from collections import Counter
from typing import TYPE_CHECKING, Any

from ..devices.bench_file import bench_config, bench_label
from .common import error

if TYPE_CHECKING:  # pragma: no cover  (the bench models load pydantic: not for --help)
    from ..config import BenchConfig, BenchConfigError

__all__ = ["add_subcommands", "run_devices", "run_validate"]

_PLURAL = {"camera": "cameras", "stage": "stages", "led_array": "led_arrays", "slm": "slms"}


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``validate``, ``devices`` and ``bench serve``
    (:mod:`instrument.cli.bench_serve`) to the ``diffuserlab`` subparsers."""
    from .bench_serve import add_serve

    vp = sub.add_parser(
        "validate",
        help="check a bench TOML file (every problem with its location and fix)",
        description="Check a bench TOML file; exit 2 listing every problem.",
    )
    vp.add_argument("bench", nargs="?", default=None,
                    help="bench TOML file (see examples/bench-*.toml; with --simulate "
                    "default: the built-in simulated bench)")
    vp.add_argument(
        "--simulate",
        action="store_true",
        help="check with every device swapped for its simulated twin "
        "(a lab file on a machine without the hardware drivers)",
    )
    vp.set_defaults(handler=run_validate)
    dp = sub.add_parser(
        "devices",
        help="open every device of a bench and print its kind, driver and status",
        description="Open every device, print its status, close them again. Without a "
        "file: the built-in simulated bench.",
    )
    dp.add_argument("bench", nargs="?", default=None, help="bench TOML file (default: built-in)")
    dp.add_argument(
        "--simulate", action="store_true", help="use the simulated twin of every device"
    )
    dp.add_argument(
        "--timeout",
        type=float,
        default=10.0,
        dest="timeout_s",
        help="seconds each device may take to open (default 10)",
    )
    dp.add_argument("--settings", action="store_true",
                    help="list each device's settings: value, unit and limits")
    dp.add_argument("--json", action="store_true",
                    help="print one JSON document (status, settings, their declarations "
                    "and a JSON schema per device) instead of text")
    dp.set_defaults(handler=run_devices)
    add_serve(sub)


def run_validate(args: argparse.Namespace) -> int:
    """Run ``validate``; returns the exit status (module docstring)."""
    return _validate(args.bench, simulate=args.simulate)


def run_devices(args: argparse.Namespace) -> int:
    """Run ``devices``; returns the exit status (module docstring)."""
    return _devices(args.bench, simulate=args.simulate, timeout_s=args.timeout_s,
                    settings=args.settings, as_json=args.json)


def _report(exc: BenchConfigError) -> int:
    for line in exc.lines():
        error(line)
    return 2


def _summary(config: BenchConfig) -> str:
    counts = Counter(d.kind for d in config.devices)
    parts = ", ".join(
        f"{n} {kind if n == 1 else _PLURAL[kind]}" for kind, n in sorted(counts.items())
    )
    n = len(config.devices)
    return (
        f"{n} device{'s' if n != 1 else ''} ({parts}), bench {config.name!r} "
        f"({', '.join(config.branches)})"
    )


def _load(path: str | None, simulate: bool,
          command: str) -> tuple[BenchConfig, BenchConfig]:
    """(as written, as it will be driven); raises BenchConfigError or MissingBenchFile."""
    from ..devices.bench_setup import load_bench

    driven = bench_config(path, simulate=simulate, command=command, construct=True)
    written = load_bench(path, check_drivers=False) if simulate and path else driven
    return written, driven


def _validate(path: str | None, *, simulate: bool) -> int:
    from ..config import BenchConfigError
    from ..devices.bench_setup import simulated_twin

    try:
        config, driven = _load(path, simulate, "validate")
    except BenchConfigError as exc:
        return _report(exc)
    print(f"ok: {_summary(config)} in {bench_label(path)}")
    if simulate:
        for orig in config.devices:
            twin, dropped = simulated_twin(orig, config.geometry)
            note = f" (params dropped: {', '.join(sorted(dropped))})" if dropped else ""
            print(f"  {orig.id}: {orig.driver} -> {twin.driver}{note}")
    return 0


def _value(v: Any, limit: int = 60) -> str:
    text = v if isinstance(v, str) else json.dumps(v, separators=(",", ":"), default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _status_text(status: dict[str, Any]) -> str:
    state = (
        "disconnected"
        if status.get("disconnected")
        else ("open" if status.get("is_open") else "closed")
    )
    skip = {"device_id", "kind", "driver", "is_open", "disconnected"}
    rest = " ".join(f"{k}={_value(v)}" for k, v in status.items() if k not in skip)
    return f"{state} {rest}".rstrip()


def _devices(path: str | None, *, simulate: bool, timeout_s: float, settings: bool = False,
             as_json: bool = False) -> int:
    from ..config import BenchConfigError
    from ..devices.bench_setup import BenchOpenError, open_bench
    from ..devices.registry import RegistryError

    if not (0 < timeout_s < math.inf):  # NaN fails too; every wait on a device ends
        error(f"--timeout must be a finite number of seconds > 0, got {timeout_s}")
        return 2
    try:  # without a file: the built-in simulated bench, --simulate or not
        config, driven = _load(path, simulate or path is None, "devices")
    except BenchConfigError as exc:
        return _report(exc)
    source = bench_label(path)
    try:
        bench = open_bench(driven, timeout_s=timeout_s)
    except RegistryError as exc:
        error(str(exc))
        return 2
    except BenchOpenError as exc:
        error(str(exc))
        return 1
    failed = 0
    with bench:
        if as_json:
            records = []
            for dev in driven.devices:
                record = _device_record(bench[dev.id], dev)
                failed += "error" in record
                records.append(record)
            from diffuserlab.jsonio import json_text

            print(json_text({"bench": config.name, "source": source, "simulated": simulate,
                             "devices": records}, default=str))
            return 1 if failed else 0
        print(f"{_summary(config)} from {source}{' (simulated twins)' if simulate else ''}:")
        w_id = max(len(d.id) for d in driven.devices)
        w_drv = max(len(d.driver) for d in driven.devices)
        for dev in driven.devices:
            try:
                status = _status_text(bench[dev.id].status())
            except Exception as exc:  # report it, keep listing the others
                status = f"status failed: {type(exc).__name__}: {exc}"
                failed += 1
            print(f"  {dev.id:<{w_id}}  {dev.kind:<9}  {dev.driver:<{w_drv}}  {status}")
            if settings:
                failed += _print_settings(bench[dev.id])
    return 1 if failed else 0


def _declared(device: Any) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """(declarations with the open device's limits, current values)."""
    return device.setting_specs(device.info), device.settings()


def _print_settings(device: Any) -> int:
    """Print ``device``'s settings under its line; 1 if they could not be read."""
    try:
        specs, values = _declared(device)
    except Exception as exc:  # report it, keep listing the others
        print(f"      settings failed: {type(exc).__name__}: {exc}")
        return 1
    width = max((len(s["name"]) for s in specs), default=0)
    for spec in specs:
        value = _value(values.get(spec["name"]), 40)
        unit = f" {spec['unit']}" if spec["unit"] else ""
        notes = [spec["limits"]] if spec["limits"] else []
        notes += ["read-only"] if spec["read_only"] else []
        note = f"  ({'; '.join(notes)})" if notes else ""
        print(f"      {spec['name']:<{width}} = {value}{unit}{note}")
    return 0


def _device_record(device: Any, entry: Any) -> dict[str, Any]:
    """One device of ``devices --json`` (the open ``device``, its bench file ``entry``):
    its status, settings, declarations and the JSON schema of its writable settings;
    ``error`` where they could not be read."""
    from drivers.settings import settings_model

    record: dict[str, Any] = {"id": entry.id, "kind": entry.kind, "driver": entry.driver}
    try:
        record["status"] = device.status()
        specs, values = _declared(device)
        record.update(settings=values, declarations=specs,
                      schema=settings_model(type(device)).model_json_schema())
    except Exception as exc:  # report it, keep listing the others
        record["error"] = f"{type(exc).__name__}: {exc}"
    return record

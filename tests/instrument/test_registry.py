"""Driver registry (entry points, in-process registration) and open_bench's lifecycle.

The fake drivers here are small ``drivers.base.Device`` subclasses that record every
open and close in ``EVENTS``; the other bench tests import them.
"""

from __future__ import annotations

import importlib.util
import threading
import time
from importlib.metadata import EntryPoint
from typing import Any

import pytest

from drivers.base import Device
from drivers.errors import DeviceValueError
from instrument.config import DeviceConfig, default_bench
from instrument.devices import registry
from instrument.devices.bench_setup import BenchOpenError, open_bench
from instrument.devices.registry import (
    ENTRY_POINT_GROUP,
    DriverKindError,
    DriverLoadError,
    UnknownDriverError,
    resolve,
)

EVENTS: list[tuple[str, str]] = []
OPENED: dict[str, Device] = {}
BUILTINS = {
    "simulated-camera": ("drivers.simulated:SimulatedCamera", "camera"),
    "simulated-stage": ("drivers.simulated:SimulatedStage", "stage"),
    "simulated-led-array": ("drivers.simulated:SimulatedLedArray", "led_array"),
    "simulated-slm": ("drivers.simulated:SimulatedSlm", "slm"),
}


class _Fake(Device):
    """Records lifecycle events; ``fail_open=True`` makes open raise."""

    def __init__(self, device_id: str, **params: Any) -> None:
        super().__init__(device_id, **params)
        if params.get("fail_init"):
            raise RuntimeError("constructor refused")
        OPENED[device_id] = self

    def _do_open(self, timeout_s: float) -> None:
        EVENTS.append(("open", self.device_id))
        self.timeout_s = timeout_s
        if self.params.get("fail_open"):
            raise TimeoutError(f"no answer within {timeout_s} s")
        if self.params.get("interrupt_open"):
            raise KeyboardInterrupt

    def _do_close(self) -> None:
        EVENTS.append(("close", self.device_id))
        if self.params.get("fail_close"):
            raise RuntimeError("close failed")

    def _do_get_info(self) -> dict[str, Any]:
        return {}

    def _do_get_settings(self) -> dict[str, Any]:
        return {}

    def _do_apply(self, name: str, value: Any) -> Any:
        return None

    def _do_status(self) -> dict[str, Any]:
        return {"frames": 0, "params": sorted(self.params)}


class FakeCamera(_Fake):
    kind = "camera"


class FakeStage(_Fake):
    kind = "stage"


class FakeLedArray(_Fake):
    kind = "led_array"


class FakeSlm(_Fake):
    kind = "slm"


FAKES = {
    "simulated-camera": FakeCamera,
    "simulated-stage": FakeStage,
    "simulated-led-array": FakeLedArray,
    "simulated-slm": FakeSlm,
}


def use_fakes(monkeypatch: pytest.MonkeyPatch, simulated: bool = True) -> None:
    """Fresh in-process registry holding fake-camera/... (and the simulated-* names)."""
    monkeypatch.setattr(registry, "_local", {})
    EVENTS.clear()
    OPENED.clear()
    for name, cls in FAKES.items():
        registry.register(name.replace("simulated-", "fake-"), cls)
        if simulated:
            registry.register(name, cls)


@pytest.fixture
def fakes(monkeypatch):
    use_fakes(monkeypatch)
    return FAKES


def _bench(*devices: DeviceConfig):
    return default_bench().model_copy(update={"devices": list(devices)})


def _dev(dev_id: str, kind: str = "camera", driver: str = "fake-camera", **params):
    if kind == "stage":
        params.setdefault("axes", ["x"])
    return DeviceConfig(id=dev_id, kind=kind, driver=driver, params=params)


# ------------------------------------------------------------------ entry points


def test_builtin_drivers_are_declared_as_entry_points():
    eps = registry._entry_points()
    for name, (target, _) in BUILTINS.items():
        assert [e.value for e in eps[name]] == [target]
    assert set(BUILTINS) <= set(registry.names())


def _simulated_drivers_written() -> bool:
    spec = importlib.util.find_spec("drivers.simulated")
    return spec is not None and spec.origin is not None  # a package with its __init__


@pytest.mark.skipif(
    not _simulated_drivers_written(),
    reason="drivers.simulated not written yet (runs as soon as it exists)",
)
def test_builtin_simulated_drivers_resolve_through_entry_points(monkeypatch):
    import drivers.simulated as sim

    monkeypatch.setattr(registry, "_local", {})  # nothing registered in-process
    for name, (target, kind) in BUILTINS.items():
        cls = resolve(name, kind)
        assert cls is getattr(sim, target.split(":")[1])
        assert issubclass(cls, Device) and cls.kind == kind
    assert {n: registry.available()[n] for n in BUILTINS} == {
        n: k for n, (_, k) in BUILTINS.items()
    }
    with open_bench(default_bench(), timeout_s=5.0) as bench:
        assert list(bench) == [d.id for d in default_bench().devices]
        assert all(dev.is_open for dev in bench.values())
        devices = list(bench.values())
    assert not any(dev.is_open for dev in devices)


def test_resolve_loads_a_plugin_entry_point(monkeypatch):
    monkeypatch.setattr(registry, "_local", {})
    ep = EntryPoint("plugin-cam", f"{__name__}:FakeCamera", ENTRY_POINT_GROUP)
    twin = EntryPoint("plugin-cam", f"{__name__}:FakeCamera", ENTRY_POINT_GROUP)
    monkeypatch.setattr(registry, "entry_points", lambda group: [ep, twin])
    assert resolve("plugin-cam") is FakeCamera  # same target twice: not ambiguous
    assert resolve("plugin-cam", "camera") is FakeCamera
    assert registry.available() == {"plugin-cam": "camera"}


def test_entry_point_problems_are_reported(monkeypatch):
    monkeypatch.setattr(registry, "_local", {})
    eps = [
        EntryPoint("broken", "no_such_module_xyz:Driver", ENTRY_POINT_GROUP),
        EntryPoint("two", f"{__name__}:FakeCamera", ENTRY_POINT_GROUP),
        EntryPoint("two", f"{__name__}:FakeStage", ENTRY_POINT_GROUP),
        EntryPoint("kindless", f"{__name__}:_Fake", ENTRY_POINT_GROUP),
    ]
    monkeypatch.setattr(registry, "entry_points", lambda group: eps)
    with pytest.raises(DriverLoadError, match="no_such_module_xyz.*ModuleNotFoundError"):
        resolve("broken")
    with pytest.raises(DriverLoadError, match="more than one package"):
        resolve("two")
    with pytest.raises(DriverLoadError, match="declares kind 'device'.*camera, stage"):
        resolve("kindless")
    assert registry.available() == {"broken": None, "kindless": None, "two": None}


def test_unknown_driver_lists_the_available_ones(fakes):
    with pytest.raises(UnknownDriverError) as info:
        resolve("acme-camera")
    msg = str(info.value)
    assert "unknown driver 'acme-camera'" in msg
    assert "fake-camera" in msg and "simulated-stage" in msg
    assert isinstance(info.value, LookupError)


def test_driver_of_another_kind_is_refused(fakes):
    with pytest.raises(DriverKindError, match="'fake-stage' drives a stage, not a camera"):
        resolve("fake-stage", "camera")


def test_register_takes_precedence_and_unregister_removes(fakes):
    assert resolve("fake-slm") is FakeSlm
    registry.register("fake-slm", FakeCamera)
    assert resolve("fake-slm") is FakeCamera
    registry.unregister("fake-slm")
    with pytest.raises(UnknownDriverError):
        resolve("fake-slm")
    with pytest.raises(DriverLoadError, match="not a device class"):
        registry.register("x", object())
    assert registry.available()["fake-led-array"] == "led_array"


class _Picky(FakeCamera):
    """Refuses gain > 10 and offset < 0 (checked in that order), and an offset above
    ``2 * gain`` (a cross-parameter rule); ``mode`` must be "a" (refused without naming
    it); ``port`` is required."""

    def __init__(self, device_id, *, port, gain=1, offset=0, mode="a", **params):
        super().__init__(device_id, **params)
        if gain > 10:
            raise DeviceValueError(device_id, f"gain={gain} is too high", "use <= 10")
        if offset < 0:
            raise DeviceValueError(device_id, f"offset={offset} is negative", "use >= 0")
        if offset > 2 * gain:
            raise DeviceValueError(device_id, f"offset={offset} above twice the gain",
                                   "lower offset")
        if mode != "a":
            raise RuntimeError("unsupported")


def test_construction_problems_without_opening(fakes):
    registry.register("picky", _Picky)
    bench = _bench(
        _dev("a", driver="picky", port=1, gain=20, offset=-1),  # two refusals, both named
        _dev("b", fail_init=True),  # refusal naming no parameter: the one whose removal passes
        _dev("c"),
        _dev("d", driver="picky", port=1, gain=2, offset=9),  # cross-parameter: first named
        _dev("e", driver="picky", port=1, mode="b"),
    )
    found = registry.construction_problems(bench)
    assert [(p.location, p.message, p.fix) for p in found] == [
        (
            "devices[0].params.gain",
            "driver 'picky' refused the parameters of device 'a': gain=20 is too high",
            "use <= 10",
        ),
        (
            "devices[0].params.offset",
            "driver 'picky' refused the parameters of device 'a': offset=-1 is negative",
            "use >= 0",
        ),
        (
            "devices[1].params.fail_init",
            "driver 'fake-camera' refused the parameters of device 'b': RuntimeError: "
            "constructor refused",
            "check the parameters 'fake-camera' takes",
        ),
        (
            "devices[3].params.offset",
            "driver 'picky' refused the parameters of device 'd': offset=9 above twice the gain",
            "lower offset",
        ),
        (
            "devices[4].params.mode",
            "driver 'picky' refused the parameters of device 'e': RuntimeError: unsupported",
            "check the parameters 'picky' takes",
        ),
    ]
    assert EVENTS == []  # nothing opened
    assert registry.construction_problems(_bench(_dev("a"), _dev("c"))) == []


@pytest.mark.parametrize(
    ("refusal", "location"),
    [("no such device", "devices[3].params"), ("no such port", "devices[3].params.port")],
)
def test_construction_never_leaves_out_a_required_parameter(fakes, refusal, location):
    class NeedsPort(FakeCamera):
        def __init__(self, device_id, *, port, **params):
            super().__init__(device_id, **params)
            raise RuntimeError(refusal)

    registry.register("needs-port", NeedsPort)
    found = registry.device_construction_problems(3, _dev("a", driver="needs-port", port="x"))
    # one problem: constructing again without the required port would only add a
    # "missing argument" follow-on
    assert [(p.location, p.message) for p in found] == [
        (location, f"driver 'needs-port' refused the parameters of device 'a': RuntimeError: "
                   f"{refusal}")
    ]
    assert registry.required_params(NeedsPort) == {"port"}
    assert registry.required_params(_Picky) == {"port"}


def test_one_view_reads_the_entry_points_once(monkeypatch):
    reads = []
    real = registry.entry_points

    def counting(group):
        reads.append(group)
        return real(group=group)

    monkeypatch.setattr(registry, "entry_points", counting)
    with registry.one_view():
        with registry.one_view():  # nested: the same view
            assert resolve("simulated-camera").kind == "camera"
        assert resolve("simulated-slm").kind == "slm"
        assert "simulated-stage" in registry.names()
    assert len(reads) == 1
    resolve("simulated-camera")  # outside: read afresh
    assert len(reads) == 2


# -------------------------------------------------------------------- open_bench


def test_open_bench_opens_all_and_closes_in_reverse(fakes):
    bench = _bench(_dev("a"), _dev("b", "stage", "fake-stage"), _dev("c", "slm", "fake-slm"))
    with open_bench(bench, timeout_s=2.5) as devices:
        assert isinstance(devices, dict) and list(devices) == ["a", "b", "c"]
        assert all(d.is_open for d in devices.values())
        assert {d.timeout_s for d in devices.values()} == {2.5}
        assert type(devices["b"]) is FakeStage and devices["b"].params == {"axes": ["x"]}
    # independent devices open concurrently (any order); closing is last first
    assert sorted(EVENTS[:3]) == [("open", "a"), ("open", "b"), ("open", "c")]
    assert EVENTS[3:] == [("close", "c"), ("close", "b"), ("close", "a")]
    assert not any(d.is_open for d in OPENED.values())
    assert devices == {}


def test_open_bench_closes_opened_devices_when_a_later_one_fails(fakes):
    """Devices on one connection (a port) open one after another, in bench order."""
    bench = _bench(
        _dev("a", port="/dev/ttyUSB0"),
        _dev("b", "stage", "fake-stage", port="/dev/ttyUSB0"),
        _dev("c", "slm", "fake-slm", fail_open=True, port="/dev/ttyUSB0"),
        _dev("d", "led_array", "fake-led-array", port="/dev/ttyUSB0"),
    )
    with pytest.raises(BenchOpenError) as info:
        open_bench(bench, timeout_s=1.0)
    err = info.value
    assert err.device_id == "c" and err.closed == ["a", "b"]
    assert "opening device 'c' (driver 'fake-slm') failed: TimeoutError" in str(err)
    assert "closed again: a, b" in str(err)
    assert isinstance(err.__cause__, TimeoutError)
    assert EVENTS == [("open", "a"), ("open", "b"), ("open", "c"), ("close", "b"), ("close", "a")]
    assert not OPENED["d"].is_open and ("open", "d") not in EVENTS  # never opened
    assert not any(d.is_open for d in OPENED.values())


def test_open_bench_failing_constructor_and_failing_close(fakes):
    bench = _bench(
        _dev("a", fail_close=True, serial_number="1"),
        _dev("b", "stage", "fake-stage", serial_numbers={"x": "1"}),
        _dev("c", "slm", "fake-slm", fail_open=True, serial_number="1"),
    )
    with pytest.raises(BenchOpenError) as info:
        open_bench(bench)
    err = info.value
    assert err.device_id == "c" and err.closed == ["b"]
    assert list(err.close_errors) == ["a"] and "close failed for: a" in str(err)
    assert EVENTS[-2:] == [("close", "b"), ("close", "a")]
    EVENTS.clear()
    bench = _bench(_dev("a"), _dev("c", "slm", "fake-slm", fail_init=True),
                   _dev("d", "slm", "fake-slm", fail_init=True))
    with pytest.raises(BenchOpenError, match="RuntimeError: constructor refused") as info:
        open_bench(bench)
    assert list(info.value.failures) == ["c", "d"] and EVENTS == []  # nothing opened


def test_open_bench_interrupted_closes_and_reraises(fakes):
    bench = _bench(_dev("a"), _dev("b", "stage", "fake-stage", interrupt_open=True))
    with pytest.raises(KeyboardInterrupt):
        open_bench(bench)
    assert sorted(EVENTS[:2]) == [("open", "a"), ("open", "b")]
    assert EVENTS[2:] == [("close", "a")]
    assert not OPENED["a"].is_open


class _Slow(FakeStage):
    """Opens in ``open_s`` seconds of waiting on the open's bounds, as a stage homing
    at open does (``Stage._wait_homing_at_open``: its cancel event checked, the
    caller's deadline kept)."""

    def _do_open(self, timeout_s: float) -> None:
        super()._do_open(timeout_s)
        deadline, cancel = self._open_bounds
        end = time.monotonic() + self.params.get("open_s", 30.0)
        while time.monotonic() < end:
            self._check_cancel("while homing")
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError("homing at open did not finish within the open's timeout")
            time.sleep(0.01)


def test_open_bench_reports_every_failure_and_stops_the_slow_ones(fakes):
    """Independent devices open concurrently: a failing device is reported and a
    device still homing is stopped (not waited for 30 s) and closed; every opened
    device is closed again."""
    registry.register("slow-stage", _Slow)
    bench = _bench(
        _dev("a"),
        _dev("slow", "stage", "slow-stage", open_s=30.0),
        _dev("c", "slm", "fake-slm", fail_open=True),
    )
    with pytest.raises(BenchOpenError) as info:
        open_bench(bench)
    err = info.value
    assert err.device_id == "c" and list(err.failures) == ["c"]
    assert "opening device 'c' (driver 'fake-slm') failed: TimeoutError" in str(err)
    assert "slow" not in err.failures and "slow" in err.stopped
    assert not any(d.is_open for d in OPENED.values())
    assert ("close", "a") in EVENTS or "a" in err.stopped


def test_open_bench_cancel_and_timeout_bound_the_opens(fakes):
    """The caller's cancel event (the GUI's cancel) stops a bench whose stages home at
    open, and the caller's timeout bounds it; the quick devices are closed again."""
    registry.register("slow-stage", _Slow)
    bench = _bench(_dev("a"), _dev("slow", "stage", "slow-stage", open_s=30.0))
    cancel = threading.Event()
    threading.Timer(0.2, cancel.set).start()
    with pytest.raises(BenchOpenError, match="open cancelled while homing") as info:
        open_bench(bench, cancel=cancel)
    assert info.value.device_id == "slow" and not OPENED["a"].is_open
    assert ("close", "a") in EVENTS
    EVENTS.clear()
    with pytest.raises(BenchOpenError, match="within the open's timeout") as info:
        open_bench(bench, timeout_s=0.3)
    assert not OPENED["a"].is_open
    with open_bench(_bench(_dev("s", "stage", "slow-stage", open_s=0.05))) as devices:
        assert devices["s"].is_open  # no timeout given: the device's own bounds


class _Overlap(FakeCamera):
    """Counts how many opens run at once; with a ``barrier``, each open waits there for
    the others (which only concurrent opens reach)."""

    active = 0
    most = 0
    barrier: threading.Barrier | None = None
    lock = threading.Lock()

    def _do_open(self, timeout_s: float) -> None:
        with _Overlap.lock:
            _Overlap.active += 1
            _Overlap.most = max(_Overlap.most, _Overlap.active)
        if _Overlap.barrier is not None:
            _Overlap.barrier.wait()
        else:
            time.sleep(0.02)
        with _Overlap.lock:
            _Overlap.active -= 1
        super()._do_open(timeout_s)


def test_open_bench_opens_devices_on_one_clock_one_after_another(fakes):
    """Independent devices open at once; simulated devices advancing one clock (a
    virtual bench's construct hook gives them one) open one after another."""
    registry.register("overlap", _Overlap)
    bench = _bench(*(_dev(c, driver="overlap") for c in "abc"))
    _Overlap.most, _Overlap.barrier = 0, threading.Barrier(3, timeout=30)
    try:
        with open_bench(bench):  # each open waits for the other two: all three at once
            assert _Overlap.most == 3
    finally:
        _Overlap.barrier = None
    shared = object()

    def on_one_clock(dev_cfg, cls):
        device = cls(dev_cfg.id, **dev_cfg.params)
        device.clock = shared
        return device

    _Overlap.most = 0
    with open_bench(bench, construct=on_one_clock) as devices:
        assert list(devices) == ["a", "b", "c"]
    assert _Overlap.most == 1
    assert EVENTS[-6:-3] == [("open", "a"), ("open", "b"), ("open", "c")]


def test_independent_groups_share_connections():
    from instrument.devices.bench_setup import independent_groups

    devices = [_dev("a", port="/dev/ttyUSB0"), _dev("b"), _dev("c", serial_numbers={"x": "7"}),
               _dev("d", port="/dev/ttyUSB0"), _dev("e", serial_number="7"), _dev("f")]
    assert independent_groups(devices) == [[0, 3], [1], [2, 4], [5]]


def test_open_bench_checks_every_driver_before_opening(fakes):
    bench = _bench(_dev("a"), _dev("b", "stage", "fake-camera"))
    with pytest.raises(DriverKindError):
        open_bench(bench)
    bench = _bench(_dev("a"), _dev("b", "stage", "no-such-driver"))
    with pytest.raises(UnknownDriverError):
        open_bench(bench)
    assert EVENTS == [] and OPENED == {}
    with pytest.raises(ValueError, match="timeout_s"):
        open_bench(_bench(_dev("a")), timeout_s=0)


def test_open_bench_simulate_swaps_to_the_twins(fakes):
    bench = _bench(
        _dev("cam", "camera", "aravis", port="x", exposure_s=0.01),
        _dev("st", "stage", "thorlabs-apt", serial_numbers={"x": "1"}),
    )
    with open_bench(bench, simulate=True) as devices:
        assert type(devices["cam"]) is FakeCamera and type(devices["st"]) is FakeStage
        # fakes take **params, so nothing is dropped; the camera gets the geometry
        assert devices["cam"].params == {
            "sensor_shape": [256, 320],
            "pixel_pitch_um": 13.0,
            "port": "x",
            "exposure_s": 0.01,
        }
        assert devices["st"].params == {"axes": {"x": [-25.0, 25.0]}, "serial_numbers": {"x": "1"}}


def test_accepted_params_reads_the_constructor():
    class Explicit(FakeCamera):
        def __init__(self, device_id, *, port="", exposure_s=0.1, clock=None):
            super().__init__(device_id)

    assert registry.accepted_params(Explicit) == {"port", "exposure_s", "clock"}
    assert registry.accepted_params(FakeCamera) is None

"""The simulated drivers: conformance suites, fault injection, timing, sensor model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.camera import FrameRing
from drivers.errors import (
    CameraTimeoutError,
    DeviceDisconnectedError,
    DeviceStateError,
    DeviceValueError,
    LedArrayTimeoutError,
    SlmTimeoutError,
    StageTimeoutError,
)
from drivers.simulated import (
    SimClock,
    SimulatedCamera,
    SimulatedDmd,
    SimulatedLedArray,
    SimulatedSlm,
    SimulatedStage,
)
from drivers.simulated.clock import REALTIME_STEP_S
from tests.drivers.conformance import (
    CameraConformance,
    DmdConformance,
    LedArrayConformance,
    SlmConformance,
    StageConformance,
)

SHAPE = (48, 64)


def camera(**kw) -> SimulatedCamera:
    kw.setdefault("sensor_shape", SHAPE)
    cam = SimulatedCamera("cam0", **kw)
    cam.open()
    return cam


class _Sim:
    def provoke_timeout(self, device):
        device.faults.timeout_next()

    def advance_time(self, device, seconds):
        device.clock.advance(seconds)


class TestSimulatedCamera(_Sim, CameraConformance):
    @pytest.fixture
    def device(self):
        cam = camera(irradiance=lambda c: np.full(SHAPE, 2e4))
        yield cam
        cam.close()


class TestSimulatedStage(_Sim, StageConformance):
    @pytest.fixture
    def device(self):
        with SimulatedStage("stage0", velocity={"x": 5.0, "y": 5.0, "z": 2.0}) as stage:
            yield stage


class TestSimulatedRotationStage(_Sim, StageConformance):
    @pytest.fixture
    def device(self):
        with SimulatedStage("mask0", axes=["rotation", "tip", "tilt"], velocity=20.0) as stage:
            yield stage


class TestSimulatedLedArray(_Sim, LedArrayConformance):
    @pytest.fixture
    def device(self):
        with SimulatedLedArray("led0") as leds:
            yield leds

    def leds_emitting(self, device):
        return len(device.emitting)


class TestSimulatedSlm(_Sim, SlmConformance):
    @pytest.fixture
    def device(self):
        with SimulatedSlm("slm0") as slm:
            yield slm


class TestSimulatedDmd(_Sim, DmdConformance):
    @pytest.fixture
    def device(self):
        with SimulatedDmd("dmd0") as dmd:
            yield dmd


def test_simulated_dmd_plays_the_sequence_in_time():
    dmd = SimulatedDmd("dmd0")
    with dmd:
        dmd.apply_settings({"period_s": 0.1, "exposure_s": 0.05})
        dmd.load_sequence([{"image": 0, "bit": b} for b in range(3)], repeat=False)
        dmd.start()
        seen = []
        for _ in range(4):
            seen.append(dmd.pattern_index)
            dmd.clock.advance(0.1)
        assert seen == [0, 1, 2, None] and not dmd.running


# --------------------------------------------------------------------------- faults
@pytest.mark.parametrize(
    ("make", "call", "error"),
    [
        (lambda: camera(), lambda d: d.snap(timeout_s=0.7), CameraTimeoutError),
        (lambda: SimulatedStage("s"), lambda d: d.move_to({"x": 1.0}, timeout_s=0.7),
         StageTimeoutError),
        (lambda: SimulatedLedArray("l"), lambda d: d.all_off(timeout_s=0.7), LedArrayTimeoutError),
        (lambda: SimulatedSlm("m"), lambda d: d.show_image(np.zeros((96, 120), np.uint8),
                                                          timeout_s=0.7), SlmTimeoutError),
    ],
)
def test_timeout_next_spends_the_timeout_then_recovers(make, call, error):
    dev = make()
    dev.open()
    dev.faults.timeout_next(n=2)
    for _ in range(2):
        t0 = dev.clock.now_s
        with pytest.raises(error, match=r"within 0\.7 s"):
            call(dev)
        assert dev.clock.now_s - t0 == pytest.approx(0.7)
    call(dev)  # third call works
    assert dev.is_open and not dev.status()["disconnected"]


def test_camera_disconnect_detected_and_reconnect_reapplies_settings():
    cam = camera()
    cam.apply_settings({"exposure_s": 0.02, "gain": 6.0, "roi": [4, 4, 32, 16], "binning": 2,
                        "pixel_format": "mono16"})
    before = cam.settings()
    cam.faults.disconnect()
    with pytest.raises(DeviceDisconnectedError, match="cam0"):
        cam.snap()
    with pytest.raises(ConnectionError):
        cam.settings()  # every call fails, not only I/O
    with pytest.raises(DeviceDisconnectedError):
        cam.exposure_s = 0.1
    assert cam.status()["disconnected"] is True
    with pytest.raises(DeviceDisconnectedError):
        cam.reconnect()  # still unplugged
    with pytest.raises(DeviceDisconnectedError):
        cam.snap()  # and still failing after a failed reconnect
    cam.faults.allow_reconnect(after_attempts=2)
    for _ in range(2):
        with pytest.raises(DeviceDisconnectedError):
            cam.reconnect()
    cam.reconnect()
    assert cam.is_open and cam.settings() == before
    assert cam._hw["exposure_s"] == 0.02 and cam._hw["roi"] == (4, 4, 32, 16)  # in the "hardware"
    frame = cam.snap()
    assert frame.image.shape == (8, 16) and frame.exposure_s == 0.02 and frame.gain == 6.0
    assert frame.index == 0  # a fresh session after the reconnect


def test_stage_reconnect_reapplies_settings_keeps_position():
    with SimulatedStage("s") as stage:
        stage.apply_settings({"velocity": {"x": 1.0}, "limits": {"y": (-5, 5)},
                              "backlash": {"z": 0.1}})
        stage.move_to({"x": 3.0})
        stage.faults.disconnect()
        with pytest.raises(DeviceDisconnectedError):
            stage.positions()
        stage.faults.allow_reconnect()
        stage.reconnect()
        assert stage.velocity["x"] == 1.0 and stage.limits["y"] == (-5.0, 5.0)
        assert stage._hw["backlash"]["z"] == 0.1
        assert stage.position("x") == 3.0  # mechanical position kept, nothing replayed
        t0 = stage.clock.now_s
        stage.move_to({"x": 4.0})
        assert stage.clock.now_s - t0 == pytest.approx(1.0)  # the re-applied velocity


def test_led_and_slm_reconnect_restore_display():
    with SimulatedLedArray("l") as leds, SimulatedSlm("m") as slm:
        leds.brightness = 0.3
        idx = leds.set_pattern("darkfield", colour="red")
        img = np.random.default_rng(0).integers(0, 256, (96, 120), dtype=np.uint8)
        pid = slm.show_image(img)
        for dev in (leds, slm):
            dev.faults.disconnect()
            dev.faults.allow_reconnect()
            dev.reconnect()
        assert set(leds.emitting) == set(idx.tolist())  # lit again on the device
        assert set(leds.emitting.values()) == {("red", 0.3)}
        np.testing.assert_array_equal(slm.panel, img)
        assert slm.pattern_id == pid


def test_dropped_frames_are_counted_in_stream():
    cam = camera()
    ring = FrameRing(16)
    cam.start_stream(ring)
    cam.faults.drop_frames(n=2)
    frames = [ring.get(timeout_s=1.0) for _ in range(4)]
    cam.stop_stream()
    assert [f.index for f in frames] == [2, 3, 4, 5]  # the gap shows the loss
    assert ring.dropped == 2 and ring.skipped == 2 and cam.dropped_frames == 2
    c = ring.counters()
    assert c["acquired"] == c["read"] + c["skipped"] + c["buffered"]
    assert cam.status()["dropped_frames"] == 2


def test_drop_probability_is_seeded_and_counted():
    def run(seed):
        cam = camera(seed=seed)
        cam.faults.drop_frames(probability=0.3)
        ring = FrameRing(1000)
        cam.start_stream(ring)
        cam.clock.advance(200 * cam.frame_period_s + 1e-9)
        cam.stop_stream()
        return ring.counters()

    a, b = run(1), run(1)
    assert a == b and a["acquired"] == 200
    assert 30 < a["dropped"] < 90 and a["skipped"] == a["dropped"]
    assert a["acquired"] == a["buffered"] + a["skipped"]
    assert run(2) != a


def test_dropped_frame_in_snap_is_counted_and_skipped():
    cam = camera()
    cam.faults.drop_frames(n=1)
    frame = cam.snap()
    assert frame.index == 1 and cam.dropped_frames == 1
    cam.faults.drop_frames(probability=1.0)
    with pytest.raises(CameraTimeoutError):
        cam.snap(timeout_s=0.5)
    cam.faults.clear()
    assert cam.snap().index > 1


def test_drop_frames_validates():
    cam = camera()
    for kw in ({}, {"n": 1, "probability": 0.5}, {"probability": 2.0}, {"n": -1}):
        with pytest.raises(DeviceValueError):
            cam.faults.drop_frames(**kw)


def test_stuck_axis_times_out_and_stops():
    with SimulatedStage("s") as stage:
        stage.faults.stick_axis("x")
        t0 = stage.clock.now_s
        with pytest.raises(StageTimeoutError, match="stopped") as info:
            stage.move_to({"x": 5.0, "y": 2.0}, timeout_s=3.0)
        assert isinstance(info.value, TimeoutError)
        assert stage.clock.now_s - t0 == pytest.approx(3.0)
        assert stage.position("x") == 0.0 and not stage.is_moving()
        stage.move_to({"x": 5.0}, wait=False)
        assert stage.is_moving()
        with pytest.raises(StageTimeoutError):
            stage.wait_until_idle(timeout_s=1.0)
        with pytest.raises(StageTimeoutError):
            stage.home(["x"], timeout_s=1.0)
        assert not stage.status()["homed"]["x"]
        stage.move_to({"y": -2.0})  # the other axes still work
        assert stage.position("y") == -2.0
        stage.faults.unstick_axis("x")
        stage.move_to({"x": 5.0})
        assert stage.position("x") == 5.0


# --------------------------------------------------------------------------- timing
def test_stage_motion_follows_velocity_on_the_clock():
    with SimulatedStage("s", velocity=2.0) as stage:
        stage.move_to({"x": 10.0, "y": -4.0}, wait=False)
        stage.clock.advance(1.0)
        assert stage.positions()["x"] == pytest.approx(2.0)
        assert stage.positions()["y"] == pytest.approx(-2.0)
        assert stage.is_moving()
        with pytest.raises(StageTimeoutError):
            stage.wait_until_idle(timeout_s=3.0)  # 4 s remain on x
        assert stage.clock.now_s == pytest.approx(4.0)
        stage.move_to({"x": 10.0}, wait=False)  # restart from where it stopped (8 mm)
        stage.wait_until_idle(timeout_s=1.01)
        assert stage.position("x") == 10.0 and stage.clock.now_s == pytest.approx(5.0)
        stage.home()
        assert stage.positions() == {"x": 0.0, "y": 0.0, "z": 0.0}
        assert all(stage.status()["homed"].values())


def test_stage_repeatability_sigma():
    with SimulatedStage("s", repeatability_sigma=0.01, seed=3) as stage:
        errors = []
        for k in range(200):
            target = 1.0 + (k % 2)
            stage.move_to({"x": target})
            errors.append(stage.position("x") - target)
    assert np.std(errors) == pytest.approx(0.01, rel=0.2)
    assert abs(np.mean(errors)) < 0.003


def test_camera_frame_timing_follows_exposure_and_frame_rate():
    cam = camera(max_frame_rate_hz=50.0)
    cam.exposure_s = 0.005  # readout-limited: 20 ms per frame
    ring = FrameRing(10)
    cam.start_stream(ring)
    cam.clock.advance(0.1 + 1e-9)
    assert ring.acquired == 5
    cam.exposure_s = 0.05  # exposure-limited
    cam.clock.advance(0.2 + 1e-9)
    cam.stop_stream()
    stamps = np.diff([ring.get(0).device_timestamp_s for _ in range(len(ring))])
    assert stamps[:4] == pytest.approx([0.02] * 4)
    assert stamps[-2:] == pytest.approx([0.05] * 2)
    t0 = cam.clock.now_s
    cam.snap()
    assert cam.clock.now_s - t0 == pytest.approx(0.05)


def test_hardware_trigger_mode():
    cam = camera()
    cam.trigger_mode = "hardware"
    t0 = cam.clock.now_s
    with pytest.raises(CameraTimeoutError, match="hardware trigger"):
        cam.snap(timeout_s=0.3)
    assert cam.clock.now_s - t0 == pytest.approx(0.3)
    cam.fire_hardware_trigger()
    assert cam.snap().device_timestamp_s == pytest.approx(cam.clock.now_s - cam.frame_period_s)
    ring = FrameRing(4)
    cam.start_stream(ring)
    cam.fire_hardware_trigger()
    assert ring.get(timeout_s=1.0).index == 1
    cam.stop_stream()


def test_streaming_camera_sees_the_stage_during_a_move():
    clock = SimClock()
    stage = SimulatedStage("s", velocity=10.0, clock=clock)
    cam = SimulatedCamera("c", sensor_shape=(16, 16), read_noise_e=0.0, dark_current_e_per_s=0,
                          hot_pixel_fraction=0.0, clock=clock,
                          irradiance=lambda c: np.full((16, 16), 1e4 * (1 + stage.position("x"))))
    with stage, cam:
        cam.exposure_s = 0.05
        ring = FrameRing(64)
        cam.start_stream(ring)
        stage.move_to({"x": 10.0})  # 1 s of motion: the camera streams meanwhile
        cam.stop_stream()
        means = [ring.get(0).image.mean() for _ in range(len(ring))]
    assert len(means) in (19, 20)  # 1 s / 50 ms (the last one may end a hair after 1 s)
    assert np.all(np.diff(means) > 0)


def test_slm_and_led_use_simulated_time():
    clock = SimClock()
    with SimulatedSlm("m", clock=clock, settle_s=0.05, refresh_hz=50.0) as slm, \
            SimulatedLedArray("l", clock=clock, command_latency_s=0.002) as leds:
        t0 = clock.now_s
        slm.show_phase(np.zeros(slm.resolution))
        assert clock.now_s - t0 == pytest.approx(0.02 + 0.05)
        t0 = clock.now_s
        leds.set_pattern("brightfield")
        assert clock.now_s - t0 == pytest.approx(0.002)


def test_sim_clock(monkeypatch):
    clock = SimClock(1.0)
    with pytest.raises(ValueError):
        clock.advance(-1.0)
    with pytest.raises(ValueError):
        clock.advance(math.nan)
    with pytest.raises(ValueError):
        clock.advance_to(0.5)
    fired = []
    events = [3.0, 2.0]
    token = clock.subscribe(lambda: min(events) if events else None,
                            lambda t: (fired.append(t), events.remove(min(events))))
    clock.advance(5.0)
    assert fired == [2.0, 3.0] and clock.now_s == 6.0
    clock.unsubscribe(token)
    clock.subscribe(lambda: 7.0, lambda t: clock.advance(1.0))
    with pytest.raises(RuntimeError, match="must only read"):
        clock.advance(2.0)

    slept = []
    monkeypatch.setattr("drivers.simulated.clock.time.sleep", slept.append)
    rt = SimClock(realtime=True)
    rt.advance(0.25)
    # until the wall-clock deadline, in steps of REALTIME_STEP_S (a timer subscribed
    # meanwhile by another thread fires in time)
    assert slept[-1] == pytest.approx(0.25, abs=0.01) and max(slept) <= 0.26
    assert len(slept) == pytest.approx(0.25 / REALTIME_STEP_S, abs=1)
    n = len(slept)
    SimClock().advance(0.25)
    assert len(slept) == n  # the default never sleeps


# --------------------------------------------------------------------------- sensor model
def flat(value: float, shape=SHAPE):
    return lambda cam: np.full(shape, value)


@pytest.mark.parametrize("gain_db", [0.0, 12.0])
def test_flat_field_mean_and_variance(gain_db):
    shape = (200, 200)
    cam = camera(sensor_shape=shape, irradiance=flat(5e4, shape), dark_current_e_per_s=0.0,
                 hot_pixel_fraction=0.0, read_noise_e=3.0, seed=4)
    cam.apply_settings({"exposure_s": 0.02, "gain": gain_db})
    k = cam.conversion_gain_dn_per_e
    mu_e = 5e4 * 0.02
    img = cam.snap().image.astype(float)
    assert img.mean() == pytest.approx(64.0 + k * mu_e, rel=0.005)
    assert img.var() == pytest.approx(k**2 * (mu_e + 3.0**2) + 1 / 12, rel=0.03)


def test_saturation_is_counted():
    irr = np.zeros(SHAPE)
    irr[10:20, 5:15] = 1e8  # 100 pixels far beyond full well
    cam = camera(irradiance=lambda c: irr)
    frame = cam.snap()
    assert frame.saturated_pixels == 100
    assert np.all(frame.image[10:20, 5:15] == 4095) and frame.image.max() == 4095
    cam.roi = (0, 0, 10, 15)  # only 25 of them inside the ROI
    assert cam.snap().saturated_pixels == 25
    cam.roi = None
    cam.gain = 24.0  # moderate light, ADC full scale reached before full well
    irr[:] = 0.0
    irr[0, 0] = 3e5
    assert cam.snap().saturated_pixels == 1


def test_hot_pixels_fixed_by_seed():
    def dark(seed):
        return camera(seed=seed, hot_pixel_fraction=0.01, hot_pixel_e_per_s=1e4,
                      read_noise_e=1.0)

    cam = dark(5)
    cam.exposure_s = 0.1
    mask = cam.hot_pixel_mask
    assert mask.sum() > 5
    a, b = cam.snap().image, cam.snap().image
    assert np.array_equal(a > 200, mask) and np.array_equal(b > 200, mask)
    assert not np.array_equal(a, b)  # the noise differs, the hot pixels do not
    assert np.array_equal(dark(5).hot_pixel_mask, mask)
    assert not np.array_equal(dark(6).hot_pixel_mask, mask)


def test_dark_frame_mean_is_offset_plus_dark_current():
    cam = camera(sensor_shape=(200, 200), dark_current_e_per_s=200.0, hot_pixel_fraction=0.0,
                 dark_offset_dn=100.0, read_noise_e=2.0)
    cam.exposure_s = 0.5
    k = cam.conversion_gain_dn_per_e
    img = cam.snap().image.astype(float)
    # standard error of the mean ~0.02 DN
    assert img.mean() == pytest.approx(100.0 + k * 200.0 * 0.5, abs=0.1)
    cam.exposure_s = 0.001
    assert cam.snap().image.mean() == pytest.approx(100.0 + k * 0.2, abs=0.02)


def test_binning_averages_and_pixel_formats_scale():
    shape = (120, 120)
    cam = camera(sensor_shape=shape, irradiance=flat(1e5, shape), hot_pixel_fraction=0.0)
    cam.exposure_s = 0.02
    ref = cam.snap().image.astype(float)
    cam.binning = 2
    binned = cam.snap().image.astype(float)
    assert binned.shape == (60, 60)
    assert binned.mean() == pytest.approx(ref.mean(), rel=0.002)
    assert binned.var() == pytest.approx(ref.var() / 4, rel=0.15)
    cam.binning = 1
    cam.pixel_format = "mono8"
    assert cam.snap().image.mean() == pytest.approx(ref.mean() / 16, abs=0.6)
    cam.pixel_format = "mono16"
    img16 = cam.snap().image
    assert img16.mean() == pytest.approx(ref.mean() * 16, rel=0.002)
    assert np.all(img16 % 16 == 0)


def test_roi_crops_the_irradiance():
    irr = np.zeros(SHAPE)
    irr[30, 40] = 1e7
    cam = camera(irradiance=lambda c: irr, read_noise_e=0.0, dark_current_e_per_s=0.0,
                 hot_pixel_fraction=0.0)
    cam.roi = (35, 25, 10, 10)
    img = cam.snap().image
    assert np.unravel_index(img.argmax(), img.shape) == (5, 5)
    assert img.max() > 1000 and np.all(np.delete(img.ravel(), img.argmax()) == 64)


def test_bad_irradiance_and_constructor_arguments():
    cam = camera(irradiance=lambda c: np.zeros((3, 3)))
    with pytest.raises(DeviceValueError, match="irradiance"):
        cam.snap()
    for kw in ({"adc_bits": 20}, {"full_well_e": 0}, {"sensor_shape": (0, 5)},
               {"irradiance": 5.0}, {"quantum_efficiency": 1.5}):
        with pytest.raises(DeviceValueError, match="cam0"):
            SimulatedCamera("cam0", **kw)
    with pytest.raises(DeviceValueError):
        SimulatedStage("s", axes={"q": (0, 1)})
    with pytest.raises(DeviceValueError):
        SimulatedStage("s", axes={"x": (1, 0)})
    with pytest.raises(DeviceValueError):
        SimulatedSlm("m", lut_rad=np.zeros(256))
    with pytest.raises(DeviceValueError):
        SimulatedLedArray("l", pitch_mm=0)
    with pytest.raises(TypeError):
        SimulatedSlm("m", clock="now")


def test_simulated_devices_share_nothing_by_default():
    a, b = SimulatedCamera("a"), SimulatedCamera("b")
    assert a.clock is not b.clock
    with pytest.raises(DeviceStateError):
        a.snap()


@pytest.mark.parametrize("cls, name, value, message", [
    (SimulatedCamera, "sensor_shape", (32768, 32768), "sensor_shape rows=32768 is not an integer"),
    (SimulatedCamera, "sensor_shape", (480,), r"sensor_shape=\(480,\) is not \(rows, cols\)"),
    (SimulatedSlm, "resolution", [96], r"resolution=\[96\] is not \(rows, cols\)"),
    (SimulatedSlm, "resolution", "96x120", "resolution='96x120' is not"),
    (SimulatedSlm, "resolution", (96, 100000), "resolution cols=100000"),
    (SimulatedLedArray, "shape", (4096, 4096), "shape rows=4096"),
])
def test_simulated_shapes_are_checked_before_any_allocation(cls, name, value, message):
    with pytest.raises(DeviceValueError, match=message):
        cls("dev", **{name: value})


# --------------------------------------------------------------------------- frame rate, video
def test_streamed_rate_on_the_sim_clock_equals_the_frame_rate_setting():
    cam = camera(max_frame_rate_hz=100.0)
    cam.exposure_s = 0.004
    cam.frame_rate_hz = 12.5
    assert cam.frame_rate_hz == 12.5 and cam.resulting_frame_rate_hz == pytest.approx(12.5)
    ring = FrameRing(64)
    cam.start_stream(ring)
    cam.clock.advance(2.0 + 1e-9)
    cam.stop_stream()
    assert ring.acquired == 25
    stamps = [ring.get(0).device_timestamp_s for _ in range(len(ring))]
    assert np.diff(stamps) == pytest.approx([0.08] * 24)


def test_exposure_longer_than_the_frame_period_limits_the_rate():
    cam = camera(max_frame_rate_hz=100.0)
    cam.frame_rate_hz = 20.0
    cam.exposure_s = 0.1  # twice the 50 ms period
    assert cam.frame_rate_hz == 20.0  # the setting stays, the rate drops
    assert cam.resulting_frame_rate_hz == pytest.approx(10.0)
    assert cam.frame_period_s == pytest.approx(0.1)
    ring = FrameRing(64)
    cam.start_stream(ring)
    cam.clock.advance(1.0 + 1e-9)
    cam.stop_stream()
    assert ring.acquired == 10
    with pytest.raises(DeviceValueError, match="frame_rate_hz"):
        cam.frame_rate_hz = 150.0  # above max_frame_rate_hz


def test_frames_of_a_moving_scene_sample_it_mid_exposure():
    seen = []

    def irradiance(cam):
        seen.append(cam.frame_time_s)
        return np.full(SHAPE, 2e4 * (1.0 + cam.frame_time_s))

    cam = camera(irradiance=irradiance, read_noise_e=0.0)
    cam.exposure_s = 0.01
    cam.frame_rate_hz = 10.0
    ring = FrameRing(8)
    cam.start_stream(ring)
    frames = [ring.get(timeout_s=1.0) for _ in range(5)]
    cam.stop_stream()
    assert seen == pytest.approx([f.device_timestamp_s + 0.005 for f in frames])
    means = [f.image.mean() for f in frames]
    assert np.all(np.diff(means) > 0)  # the scene brightens with time, so do the frames
    assert cam.frame_time_s == cam.clock.now_s  # outside a frame: the clock's time


def test_realtime_clock_streams_on_the_wall_clock_from_a_grab_thread():
    import time

    cam = camera(clock=SimClock(realtime=True), max_frame_rate_hz=200.0,
                 irradiance=lambda c: np.full(SHAPE, 1e4))
    cam.exposure_s = 0.002
    cam.frame_rate_hz = 50.0
    ring = FrameRing(4)
    t0 = time.monotonic()
    cam.start_stream(ring)
    hang_guard = t0 + 60.0
    while ring.acquired < 10 and time.monotonic() < hang_guard:  # nobody reads: the
        time.sleep(0.01)  # ring overflows and counts it (as many frames as the host lets)
    reached = time.monotonic() - t0
    c = ring.counters()
    frame = ring.get_latest(timeout_s=1.0)
    cam.stop_stream()
    elapsed = time.monotonic() - t0
    assert c["acquired"] >= 10
    assert reached >= 0.8 * 9 / 50  # 10 frames at 50 Hz take 9 periods of the wall clock
    assert c["acquired"] <= 1.2 * 50 * elapsed + 1  # never faster than the wall clock
    assert c["skipped"] == c["acquired"] - c["buffered"] and c["buffered"] == 4
    assert frame.index >= c["acquired"] - 1
    after = ring.acquired
    time.sleep(0.05)
    assert ring.acquired == after  # stopped: the grab thread is gone
    cam.close()


def test_gaussian_shot_noise_above_threshold_and_poisson_below():
    means = (0.3, 20.0, 2e4)  # electrons in 10 ms: inverse transform, numpy Poisson, Gaussian
    irr = np.repeat(np.array(means) / 0.01, [16, 16, 32])[None, :] * np.ones((SHAPE[0], 1))
    irr.flags.writeable = False  # cached maps: fresh noise per frame all the same
    cam = camera(irradiance=lambda c: irr, read_noise_e=0.0, dark_current_e_per_s=0.0,
                 hot_pixel_fraction=0.0, adc_bits=16, full_well_e=65535.0, dark_offset_dn=0,
                 gaussian_shot_noise_above_e=100.0)
    frames = np.array([cam.snap().image.astype(float) for _ in range(40)])
    tiny, low, bright = frames[:, :, :16], frames[:, :, 16:32], frames[:, :, 32:]
    for part, mu in ((tiny, 0.3), (low, 20.0)):  # Poisson: integers, var = mean
        assert np.all(part == np.round(part)) and part.mean() == pytest.approx(mu, rel=0.03)
        assert part.var() == pytest.approx(mu, rel=0.05)
    assert np.mean(tiny == 0) == pytest.approx(math.exp(-0.3), abs=0.01)
    assert np.mean(tiny == 2) == pytest.approx(math.exp(-0.3) * 0.3**2 / 2, abs=0.005)
    assert bright.mean() == pytest.approx(2e4, rel=0.01)
    assert bright.var() == pytest.approx(2e4 + 1 / 12, rel=0.05)
    assert not np.array_equal(frames[0], frames[1])
    fast = camera(irradiance=flat(3e5), read_noise_e=5.0, gaussian_shot_noise_above_e=100.0)
    exact = camera(irradiance=flat(3e5), read_noise_e=5.0)  # the default: exact Poisson
    a = np.array([fast.snap().image for _ in range(20)], float)
    b = np.array([exact.snap().image for _ in range(20)], float)
    assert a.mean() == pytest.approx(b.mean(), rel=2e-3)
    assert a.var() == pytest.approx(b.var(), rel=0.05)  # shot and read noise alike
    with pytest.raises(DeviceValueError, match="gaussian_shot_noise_above_e"):
        camera(gaussian_shot_noise_above_e=1.0)


def test_realtime_clock_paces_on_a_wall_clock_anchor(monkeypatch):
    wall = [100.0]
    monkeypatch.setattr("drivers.simulated.clock.time.monotonic", lambda: wall[0])
    monkeypatch.setattr("drivers.simulated.clock.time.sleep",
                        lambda s: wall.__setitem__(0, wall[0] + s))
    clock = SimClock(realtime=True, max_lag_s=0.1)
    clock.advance(0.05)
    assert wall[0] == pytest.approx(100.05)
    wall[0] += 0.03  # work between advances (rendering a frame) does not add up
    clock.advance(0.05)
    assert wall[0] == pytest.approx(100.10)
    wall[0] += 5.0  # idle: the clock does not race to catch up
    clock.advance(0.05)
    assert wall[0] == pytest.approx(105.15) and clock.slips == 1
    assert clock.wall_time_until(clock.now_s + 0.2) == pytest.approx(0.2)
    wall[0] += 0.05
    clock.resync()  # a short idle gap forgotten too
    assert clock.wall_time_until(clock.now_s + 0.2) == pytest.approx(0.2)
    clock.run_until(0.0)  # in the past: nothing happens
    assert clock.now_s == pytest.approx(0.15)
    assert SimClock().wall_time_until(5.0) == 0.0
    with pytest.raises(ValueError, match="max_lag_s"):
        SimClock(realtime=True, max_lag_s=0)


def test_realtime_stream_reports_an_unplugged_camera_to_the_reader():
    cam = camera(clock=SimClock(realtime=True), max_frame_rate_hz=100.0)
    cam.exposure_s = 0.002
    ring = FrameRing(4)
    cam.start_stream(ring)
    ring.get(timeout_s=30.0)  # a hang guard (a real-time grab thread a loaded host wakes
    cam.faults.disconnect()  # late), not the frame's speed
    with pytest.raises(DeviceDisconnectedError, match="unplugged"):
        for _ in range(200):  # the buffered frames, then the error
            ring.get(timeout_s=30.0)
    cam.stop_stream()

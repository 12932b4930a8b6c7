"""Video scenes on the virtual bench: truth per frame, frames that follow it."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.camera import FrameRing
from instrument.config import default_bench
from instrument.devices.video_scenes import BeadFlowScene, NeuronFieldScene, frame_time_s
from instrument.devices.virtual_bench import VirtualBench
from recon.errors import ReconInputError

BEADS = {"n_beads": 4, "channel_length_mm": 0.6, "channel_width_mm": 0.16,
         "bead_diameter_um": 40.0, "speed_um_per_s": 300.0, "bead_power_photons_per_s": 2e11}


@pytest.fixture(scope="module")
def bench():
    """A small virtual bench (64 x 80 sensor) so ray-traced renders are cheap."""
    cfg = default_bench()
    geo = cfg.geometry.model_copy(update={"sensor_shape_px": (64, 80),
                                          "aperture_mm": (0.9, 0.7)})
    with VirtualBench(cfg.model_copy(update={"geometry": geo}), seed=3) as vb:
        vb.led_array.all_off()
        yield vb


class _At:
    """A stand-in camera whose frame time is set by hand."""

    def __init__(self, t):
        self.frame_time_s = t


def _corr(a, b):
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def test_bead_truth_is_deterministic_and_moves_at_the_speed():
    a, b = BeadFlowScene(seed=5, **BEADS), BeadFlowScene(seed=5, **BEADS)
    np.testing.assert_array_equal(a.truth(0.7).positions_mm, b.truth(0.7).positions_mm)
    assert not np.allclose(a.truth(0.0).positions_mm,
                           BeadFlowScene(seed=6, **BEADS).truth(0.0).positions_mm)
    dt = 0.1
    p0, p1 = a.truth(0.3).positions_mm, a.truth(0.3 + dt).positions_mm
    step = p1 - p0
    moved = np.abs(step[:, 0]) < 0.5 * a.channel_length_mm  # the rest wrapped round
    assert moved.sum() >= 3
    np.testing.assert_allclose(step[moved, 0], a.speed_um_per_s * 1e-3 * dt, rtol=1e-9)
    np.testing.assert_allclose(step[:, 1:], 0.0, atol=1e-12)  # along +x, fixed y and z
    np.testing.assert_allclose(a.truth(a.period_s + 0.3).positions_mm, p0, atol=1e-12)
    slanted = BeadFlowScene(seed=5, direction_deg=90.0, **BEADS)
    st = slanted.truth(0.2).positions_mm - slanted.truth(0.1).positions_mm
    ok = np.abs(st[:, 1]) < 0.3
    np.testing.assert_allclose(st[ok, 1], 0.03, rtol=1e-9)


def test_bead_object_image_draws_discs_at_the_truth():
    scene = BeadFlowScene(seed=1, **BEADS)
    img = scene.object_image(0.2, (60, 80), 0.8)
    px = 0.8 / 80
    area = np.pi * (scene.bead_diameter_um * 5e-4) ** 2 / px**2
    assert img.sum() == pytest.approx(scene.n_beads * area, rel=0.1)
    for x, y, _ in scene.truth(0.2).positions_mm:
        assert img[int(y / px + 30), int(x / px + 40)] > 0.5


def test_time_step_quantises_scene_and_truth():
    scene = BeadFlowScene(time_step_s=0.05, **BEADS)
    assert scene.scene_time(0.074) == pytest.approx(0.05)
    np.testing.assert_array_equal(scene.truth(0.074).positions_mm,
                                  scene.truth(0.05).positions_mm)
    times = scene.distinct_times()
    assert len(times) == 40 and times[-1] < scene.period_s  # 2 s period in 50 ms steps
    assert NeuronFieldScene(time_step_s=0.1).distinct_times() is None  # not periodic
    for bad in ({"n_beads": 0}, {"speed_um_per_s": -1.0}, {"bead_diameter_um": 500.0},
                {"time_step_s": 0.0}):
        with pytest.raises(ReconInputError):
            BeadFlowScene(**{**BEADS, **bad})


def test_neuron_dff_truth_matches_the_trace_definition():
    scene = NeuronFieldScene(n_cells=5, spike_rate_hz=1.0, tau_s=0.4, dff_per_spike=0.8,
                             duration_s=10.0, seed=2)
    again = NeuronFieldScene(n_cells=5, spike_rate_hz=1.0, tau_s=0.4, dff_per_spike=0.8,
                             duration_s=10.0, seed=2)
    spikes = scene.spike_times_s
    assert all(np.array_equal(s, r) for s, r in zip(spikes, again.spike_times_s, strict=True))
    assert sum(len(s) for s in spikes) > 20  # ~50 spikes expected
    t = np.linspace(0, 12, 241)
    dff = scene.dff_traces(t)
    for i, s in enumerate(spikes):
        expected = [0.8 * sum(np.exp(-(tt - tk) / 0.4) for tk in s if tk <= tt) for tt in t]
        np.testing.assert_allclose(dff[:, i], expected, rtol=1e-12, atol=1e-12)
    truth = scene.truth(3.3)
    np.testing.assert_allclose(truth.f_photons_per_s, scene.f0_per_cell * (1 + truth.dff))
    np.testing.assert_allclose(truth.dff, scene.dff_traces([3.3])[0])
    k, tk = next((i, s[0]) for i, s in enumerate(spikes) if len(s))
    before, after = scene.dff_traces([tk - 1e-6, tk + 1e-6])[:, k]
    assert after - before == pytest.approx(0.8, rel=1e-4)  # a spike jumps by dff_per_spike
    img = scene.object_image(tk + 1e-6, (480, 640), 1.6)  # 2.5 um pixels
    x, y, _ = scene.positions_mm[k]
    centre = img[int(y / 0.0025 + 240), int(x / 0.0025 + 320)]
    assert centre == pytest.approx(1 + scene.truth(tk + 1e-6).dff[k])  # drawn at F / F0


def test_rendered_frames_change_with_the_frame_time(bench):
    scene = BeadFlowScene(seed=4, **BEADS)
    bench.set_scene(scene)
    a, b = bench.irradiance(_At(0.1)), bench.irradiance(_At(0.2))
    assert not a.flags.writeable and bench.irradiance(_At(0.1)) is a  # cached
    assert not np.allclose(a, b)
    expected = sum(p * bench.psf(x) for x, p in zip(*scene.sources_at(0.2), strict=True))
    np.testing.assert_allclose(b, expected, rtol=1e-12)  # the pinhole's ray-traced PSFs
    bench.set_scene(scene.__class__(time_step_s=0.25, seed=4, **BEADS))
    assert bench.prerender() == bench.render_cache_size  # 8 steps of the 2 s period
    bench.set_scene(NeuronFieldScene(n_cells=2))
    with pytest.raises(ReconInputError, match="times_s"):
        bench.prerender()  # not periodic: no finite set of scene times
    assert bench.prerender([0.0, 0.5, 0.5]) == 2
    bench.set_scene(None)


def test_streamed_frames_show_the_beads_where_the_truth_says(bench):
    scene = BeadFlowScene(seed=7, **BEADS)
    bench.set_scene(scene)
    cam = bench.camera
    cam.apply_settings({"exposure_s": 0.02, "frame_rate_hz": 10.0})
    ring = FrameRing(16)
    cam.start_stream(ring)
    frames = [ring.get(timeout_s=1.0) for _ in range(10)]
    cam.stop_stream()
    assert [f.index for f in frames] == list(range(frames[0].index, frames[0].index + 10))
    times = [frame_time_s(f) for f in frames]
    assert np.diff(times) == pytest.approx([0.1] * 9)
    truths = [sum(p * bench.psf(x) for x, p in zip(*scene.sources_at(t), strict=True))
              for t in times]
    images = [f.image.astype(float) for f in frames]
    for k in (0, 4, 9):
        own = _corr(images[k], truths[k])
        assert own > 0.95, own  # the frame shows the beads where they were at its time
        others = [_corr(images[k], truths[j]) for j in range(10) if abs(j - k) >= 2]
        assert max(others) < own - 0.2, (own, others)
    # frame differences follow the truth's motion
    assert _corr(images[5] - images[0], truths[5] - truths[0]) > 0.9
    bench.set_scene(None)


def test_neuron_frames_follow_the_cells_brightness(bench):
    scene = NeuronFieldScene(n_cells=3, field_mm=(0.5, 0.4), spike_rate_hz=1.5,
                             f0_photons_per_s=1e11, duration_s=5.0, seed=1)
    bench.set_scene(scene)
    t = np.arange(0.0, 5.0, 0.25)
    total = [bench.irradiance(_At(tt)).sum() for tt in t]
    psf_sums = np.array([bench.psf(x).sum() for x in scene.positions_mm])
    f = scene.f0_per_cell * (1 + scene.dff_traces(t))
    np.testing.assert_allclose(total, f @ psf_sums, rtol=1e-9)
    assert np.ptp(total) > 0.2 * np.min(total)  # the transients show in the frames
    bench.set_scene(None)


def test_realtime_bench_streams_a_prerendered_scene_on_the_wall_clock():
    import time

    cfg = default_bench()
    geo = cfg.geometry.model_copy(update={"sensor_shape_px": (64, 80),
                                          "aperture_mm": (0.9, 0.7)})
    with VirtualBench(cfg.model_copy(update={"geometry": geo}), seed=3, realtime=True,
                      render_cache_size=4) as vb:
        cam = vb.camera
        assert cam.gaussian_shot_noise_above_e == 100.0  # cheap noise in real time
        vb.led_array.all_off()
        vb.set_scene(BeadFlowScene(seed=2, time_step_s=0.5, **BEADS))  # 4 states
        assert vb.prerender() == 4
        # 4 fps: well below the 10-25 fps a host renders these frames unpaced
        cam.apply_settings({"exposure_s": 0.005, "frame_rate_hz": 4.0})
        ring = FrameRing(64)
        t0 = time.monotonic()
        cam.start_stream(ring)
        deadline = t0 + 60.0  # a hang guard: 4 frames take 1 s on an idle host
        while len(ring) < 4 and time.monotonic() < deadline:
            time.sleep(0.01)
        cam.stop_stream()
        elapsed = time.monotonic() - t0
        frames = [ring.get(0) for _ in range(len(ring))]
    # paced by the wall clock: at least 4 came, none faster than 4 fps (a loaded host
    # only makes them later)
    assert 4 <= len(frames) <= 4 * elapsed + 1, (len(frames), elapsed)
    assert [f.index for f in frames] == list(range(frames[0].index,
                                                   frames[0].index + len(frames)))
    assert ring.skipped == 0 and ring.dropped == 0

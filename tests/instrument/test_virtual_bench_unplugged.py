"""An unplugged LED array darkens the virtual bench; the camera keeps streaming (its grab
thread died with "led_array: the device stopped answering")."""

from __future__ import annotations

import numpy as np

from drivers.camera import FrameRing
from instrument.devices.virtual_bench import VirtualBench


def test_camera_streams_on_while_the_led_array_is_unplugged():
    vb = VirtualBench(seed=0).open()
    try:
        leds, cam = vb.led_array, vb.camera
        vb.source_stage.move_to({"z": 60.0})
        centre = int(np.argmin(np.hypot(*leds.positions_mm.T)))
        leds.set_leds([centre], "white", 1.0)
        lit = cam.snap().image.astype(float)
        leds.faults.disconnect()
        ring = FrameRing(8)
        cam.start_stream(ring)
        frames = [ring.get(timeout_s=5.0) for _ in range(3)]
        cam.stop_stream()
        dark = frames[-1].image.astype(float)
        assert dark.mean() < lit.mean()  # the source went dark, the stream went on
        assert vb.source_power_photons_per_s() == 0.0 and vb.point_sources() == ()
    finally:
        vb.close()

"""The bench as the operator left it, put back after a run.

A calibration, an alignment or a recording changes the bench to do its work: the
run's auto-exposure sets the camera's exposure (0.15 s after a PSF sweep: the live
view drops to a few frames a second and looks white), a sweep leaves the stage at
its last point, the runner's safe state switches the LEDs off, a recording applies
its frame rate. :func:`capture` notes the camera's settings, every stage's position
and the LEDs before the run, and :func:`restore` puts back whatever the run changed, also
when the run was aborted or failed, except the state a run exists to produce
(:meth:`BenchState.without`: the mask stage a completed alignment aligned); what
could not be put back is returned by :func:`restore` and logged, never raised over
the run's own outcome.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

__all__ = ["BenchState", "capture", "restore"]

log = logging.getLogger(__name__)

#: Camera settings a run may change and the operator set (applied back in this order).
CAMERA_SETTINGS = ("pixel_format", "binning", "roi", "exposure_s", "frame_rate_hz", "gain",
                   "trigger_mode")
#: A stage axis further than this from its position before the run is moved back (in
#: the axis's unit).
POSITION_TOLERANCE = 1e-4


@dataclass
class BenchState:
    """What :func:`restore` puts back: ``{device id: ...}`` per kind."""

    camera: dict[str, dict[str, Any]] = field(default_factory=dict)
    stages: dict[str, dict[str, float]] = field(default_factory=dict)
    leds: dict[str, tuple[dict[int, tuple[str, float]], str | None]] = field(
        default_factory=dict)

    def without(self, device_ids) -> BenchState:
        """This state less the devices ``device_ids`` (left as they are by
        :func:`restore`: the state a job exists to produce, e.g. the aligned mask
        stage)."""
        drop = set(device_ids)
        return BenchState(*({k: v for k, v in part.items() if k not in drop}
                            for part in (self.camera, self.stages, self.leds)))


def capture(bench) -> BenchState:
    """The camera settings, stage positions and lit LEDs of every open device.

    A device that cannot be read is left out (and so left alone by :func:`restore`).
    """
    from drivers.errors import DeviceError

    state = BenchState()
    for dev_id, dev in bench.devices.items():
        try:
            if not dev.is_open:
                continue
            if dev.kind == "camera":
                s = dev.settings()
                state.camera[dev_id] = {k: s[k] for k in CAMERA_SETTINGS if k in s}
            elif dev.kind == "stage":
                state.stages[dev_id] = dev.positions()
            elif dev.kind == "led_array":
                state.leds[dev_id] = (dev.lit(), dev.pattern)
        except DeviceError as exc:
            log.warning("could not note %s's state before the run: %s", dev_id, exc)
    return state


def restore(bench, state: BenchState, timeout_s: float = 60.0) -> dict[str, str]:
    """Put back what changed since ``state`` was captured.

    Camera settings that differ are applied again; stages that moved are moved back
    (all axes of a stage together); LEDs are lit as they were (or switched off).

    Returns
    -------
    dict
        ``{device id: problem}`` of what could not be put back (empty when all was).
    """
    from drivers.errors import DeviceError

    problems: dict[str, str] = {}
    for dev_id, before in state.camera.items():
        try:
            cam = bench.devices[dev_id]
            now = cam.settings()
            changed = {k: v for k, v in before.items() if now.get(k) != v}
            if changed:
                if cam.is_streaming:
                    cam.stop_stream()
                cam.apply_settings(changed)
                log.info("%s: settings put back after the run: %s", dev_id,
                         ", ".join(changed))
        except (DeviceError, KeyError) as exc:
            problems[dev_id] = str(exc)
    for dev_id, before in state.stages.items():
        try:
            stage = bench.devices[dev_id]
            now = stage.positions()
            if any(abs(now[a] - v) > POSITION_TOLERANCE for a, v in before.items()):
                stage.move_to(before, timeout_s=timeout_s)
                log.info("%s: moved back to its position before the run", dev_id)
        except (DeviceError, KeyError) as exc:
            problems[dev_id] = str(exc)
    for dev_id, (lit, pattern) in state.leds.items():
        try:
            leds = bench.devices[dev_id]
            if leds.lit() == lit and leds.pattern == pattern:
                continue
            if pattern is not None:
                leds.set_pattern(pattern)
            elif not lit:
                leds.all_off()
            else:
                groups: dict[tuple[str, float], list[int]] = {}
                for index, look in lit.items():
                    groups.setdefault(tuple(look), []).append(int(index))
                leds.all_off()
                for (colour, brightness), indices in groups.items():
                    leds.set_leds(indices, colour, brightness, additive=True)
        except (DeviceError, KeyError) as exc:
            problems[dev_id] = str(exc)
    for dev_id, problem in problems.items():
        log.warning("could not put %s back as it was before the run: %s", dev_id, problem)
    return problems


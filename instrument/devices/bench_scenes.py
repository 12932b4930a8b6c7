"""The video scenes of ``capture --simulate --scene``, placed and scaled for the bench.

:class:`~instrument.devices.video_scenes.BeadFlowScene` and
:class:`~instrument.devices.video_scenes.NeuronFieldScene` default to a lensless camera
looking at a plane 20 mm away (a field of 1.6 x 1.2 mm, beads of 60 um in a
0.3 mm channel). A bench whose calibrated depth range (``calibration.z_range_mm``)
holds 20 mm shows them as they are. Any other bench -- the diffuser microscope,
whose samples sit 1.7-3 mm from the diffuser (Kuo 2020, Sec. 6.4) -- gets the scene
at the middle of its calibrated range, with its lateral lengths (the cells' field;
the channel, its beads and the flow speed; the cells keep their size) scaled by
``w / 1.6 mm``: ``w`` is the width over which the pixels' angular response is at
least half its peak, ``2 z tan(1.177 sigma)`` for the Gaussian fall-off of width
``sigma`` (Sec. 5.3), at most 80 % of the sensor's field at that depth
(``sensor width * z / d``, Eq. 3.1). The flow's period and the spike statistics do
not change, so the rendering cost does not either.
"""

from __future__ import annotations

import dataclasses
import math

from recon.errors import ReconInputError

from .video_scenes import BeadFlowScene, NeuronFieldScene, VideoScene

__all__ = ["SCENE_NAMES", "scene_depth_and_scale", "show_video_scene", "video_scene_for_bench"]

#: ``--scene`` names of the moving scenes.
SCENE_NAMES = ("beads-flow", "neurons")

#: Depth and field width the scene classes' defaults are made for, mm.
_DEFAULT_Z_MM, _DEFAULT_WIDTH_MM = 20.0, 1.6
#: Half-maximum of a Gaussian in units of its sigma, sqrt(2 ln 2).
_HALF_MAX = math.sqrt(2 * math.log(2))


def scene_depth_and_scale(bench) -> tuple[float, float]:
    """Depth of a video scene on ``bench`` and the factor its lateral lengths take.

    Parameters
    ----------
    bench : instrument.devices.virtual_bench.VirtualBench
        Its ``config.calibration.z_range_mm`` and ``geometry`` (``d_mm``,
        ``sensor_shape``, ``sensor_pitch_um``, ``falloff_sigma_deg``).

    Returns
    -------
    (float, float)
        ``z_mm`` and the lateral scale (1.0 and 20 mm when the calibrated range holds
        20 mm; module notes).
    """
    z_lo, z_hi = (float(v) for v in bench.config.calibration.z_range_mm)
    if z_lo <= _DEFAULT_Z_MM <= z_hi:
        return _DEFAULT_Z_MM, 1.0
    g = bench.geometry
    z = 0.5 * (z_lo + z_hi)
    sensor_field_mm = g.sensor_shape[1] * g.sensor_pitch_um * 1e-3 * z / g.d_mm
    width = 0.8 * sensor_field_mm
    if g.falloff_sigma_deg:
        half = math.radians(min(80.0, _HALF_MAX * float(g.falloff_sigma_deg)))
        width = min(width, 2 * z * math.tan(half))
    return z, width / _DEFAULT_WIDTH_MM


def video_scene_for_bench(name: str, bench, *, seed: int = 0,
                          time_step_s: float | None = None) -> VideoScene:
    """The moving scene ``name`` placed and scaled for ``bench`` (module notes).

    Parameters
    ----------
    name : {"beads-flow", "neurons"}
    bench : instrument.devices.virtual_bench.VirtualBench
    seed : int
        Layout (and spike times) seed.
    time_step_s : float, optional
        Scene time resolution; default 0.5 s for the flow (8 distinct renders a
        period) and 0.25 s for the neurons.

    Returns
    -------
    BeadFlowScene or NeuronFieldScene

    Raises
    ------
    ReconInputError
        An unknown scene name.
    """
    if name not in SCENE_NAMES:
        raise ReconInputError(f"unknown scene {name!r}; choose one of {', '.join(SCENE_NAMES)}")
    z, s = scene_depth_and_scale(bench)
    if name == "beads-flow":
        base = BeadFlowScene(seed=seed, time_step_s=time_step_s or 0.5)
        if s == 1.0:
            return base
        return dataclasses.replace(
            base, z_mm=z, bead_diameter_um=base.bead_diameter_um * s,
            speed_um_per_s=base.speed_um_per_s * s,
            channel_centre_mm=tuple(v * s for v in base.channel_centre_mm),
            channel_length_mm=base.channel_length_mm * s,
            channel_width_mm=base.channel_width_mm * s)
    base = NeuronFieldScene(seed=seed, time_step_s=time_step_s or 0.25)
    if s == 1.0:
        return base
    return dataclasses.replace(base, z_mm=z, field_mm=tuple(v * s for v in base.field_mm))


def show_video_scene(bench, name: str, *, seed: int = 0) -> VideoScene:
    """Put the moving scene ``name`` (:func:`video_scene_for_bench`) in front of the
    virtual bench's camera and render it ahead of streaming.

    A periodic scene (the bead flow) is rendered at every distinct time; the neurons
    (fixed cells whose brightness changes, no finite set of distinct times) need only
    their cells' PSFs traced, after which a render is a weighted sum
    (:meth:`instrument.devices.virtual_bench.VirtualBench.prerender` at time 0).

    Parameters
    ----------
    bench : instrument.devices.virtual_bench.VirtualBench
    name : {"beads-flow", "neurons"}
    seed : int
        Layout (and spike times) seed.

    Returns
    -------
    VideoScene
        The scene shown.

    Raises
    ------
    ReconInputError
        An unknown scene name.
    """
    scene = video_scene_for_bench(name, bench, seed=seed)
    bench.set_scene(scene)
    bench.prerender(None if scene.distinct_times() is not None else [0.0])
    return scene

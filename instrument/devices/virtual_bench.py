"""The virtual bench: simulated devices coupled through one optical model.

What the simulated camera sees follows what the simulated stages, LED array and
SLM do (docs/architecture.md, "A simulated device is a driver like any other"):

* lensless branch: a pinhole on the source stage, lit from behind by the LED array,
  is a point source at the stage position; its image is the ray-traced PSF of the
  diffuser camera (:class:`recon.optics.lensless.LenslessModel`, shifting with
  lateral position by m = d/z, Eq. 3.1, and scaling with depth, Fig. 4.2); a scene
  (a plane at a depth, beads in 3D) adds its rendered image (local convolution
  model with spatial variance, Ch. 5); a display in front of the camera
  (:class:`DisplayScene`) is such a plane showing the display's current image. Stage
  ``z`` is the source's distance from the diffuser, mm.
* holography branch: the SLM's displayed image through the relay, the random mask
  on the 6-axis mask stage and the Fourier lens
  (:class:`recon.optics.holo_display.HolographicDisplayModel`). The SLM's physical
  gray -> phase response (:class:`~instrument.devices.slm_response.SlmPhaseResponse`, by
  default smooth and nonlinear, 2.1 pi at 532 nm) is unknown to the software, whose
  SLM driver believes a linear LUT until the SLM phase-LUT routine calibrates it; the
  laser is at the SLM's configured ``wavelength_nm``.

Operator actions a plan prompts for (:data:`ACTIONS`: cap the camera, remove the
diffuser for the bare-sensor angular response and flat field, remove the pinhole so
single LEDs are the sources, put an ND filter in front of the camera for the
unscattered far field of the SLM) are carried out by the virtual bench itself. Stray
light (a smooth glow carrying a fraction of each point source's collected power),
the camera's PRNU and hot pixels give the calibration routines something real to
remove and to find.

Rendering happens on a grid finer than the sensor (the optics models bin), the
sensor noise is the simulated camera's own, so nothing relies on the inverse crime.
"""

from __future__ import annotations

import collections
import logging
from dataclasses import dataclass

import numpy as np

from drivers.errors import DeviceDisconnectedError
from drivers.simulated import SimClock
from recon.errors import ReconInputError
from recon.optics.lensless import LenslessGeometry, LenslessModel, diffuser_for_sensor

from ..config import BenchConfig, GeometryConfig, default_bench
from .bench import Bench, PromptRefused
from .bench_setup import open_bench, with_simulated_drivers
from .registry import accepted_params
from .slm_response import SlmPhaseResponse
from .video_scenes import VideoScene

log = logging.getLogger(__name__)

BRANCHES = ("lensless", "holography")
#: Real-time virtual bench: the camera's ``gaussian_shot_noise_above_e`` (electrons).
REALTIME_GAUSSIAN_ABOVE_E = 100.0
#: Ray-traced PSFs kept (the positions used last; a 256 x 320 sensor's is 0.66 MB, and a
#: new one takes ~0.04 s): a long session that visits ever new stage positions keeps
#: ~10 MB of them, not the ~43 MB that 64 cost (measured in the operator's hour-long day).
PSF_CACHE_SIZE = 16

#: Operator actions the virtual bench carries out: action -> (state flag, value).
ACTIONS = {
    "cap_camera": ("camera_capped", True),
    "uncap_camera": ("camera_capped", False),
    "remove_diffuser": ("diffuser_installed", False),
    "install_diffuser": ("diffuser_installed", True),
    "remove_pinhole": ("pinhole_installed", False),
    "install_pinhole": ("pinhole_installed", True),
    "insert_nd_filter": ("nd_filter_installed", True),
    "remove_nd_filter": ("nd_filter_installed", False),
}


@dataclass(frozen=True)
class PlanarScene:
    """A Lambertian plane facing the camera at depth ``z_mm``.

    Attributes
    ----------
    image : ndarray, float, (rows, cols)
        Relative radiance in [0, 1] (scaled by ``radiance``).
    z_mm : float
        Distance in front of the diffuser, mm.
    width_mm : float
        Lateral extent of the image (height from square pixels), mm.
    radiance : float
        Radiance of a pixel of value 1, photons / s / mm^2 / sr.
    """

    image: np.ndarray
    z_mm: float
    width_mm: float
    radiance: float = 2e9


@dataclass(frozen=True)
class DisplayScene:
    """A display device (an SLM or monitor driven by :class:`drivers.slm.Slm`) facing
    the camera at depth ``z_mm``: whatever it shows is a :class:`PlanarScene` of its
    panel's size (resolution times pixel pitch), radiance linear in the gray level
    (``radiance`` at gray 255, no gamma). ``device``: the display's id or role.

    The default ``radiance``, 1e12 photons / s / mm^2 / sr, is a monitor's white
    (about 250 cd/m^2 at 555 nm, 1 lm = 4.1e15 photons / s): 500 times the lit
    :class:`PlanarScene`'s 2e9, at which the built-in bench's 0.96 mm SLM at 100 mm
    peaked at 1 % of full scale in the 1 s exposure cap. Now random binary patterns
    there auto-expose to 40-76 % of full scale in 0.13-0.23 s (0.04 s at 20 mm)."""

    z_mm: float
    device: str = "slm"
    radiance: float = 1e12


@dataclass(frozen=True)
class BeadScene:
    """Point-like beads in 3D: positions (N, 3) in mm (x, y, z) and powers (N,)
    in photons / s emitted isotropically. ``on_stage``: a bead slide carried by the
    source stage, the positions relative to the stage's (x, y, z) (compressive
    calibration, Sec. 5.4: the stage moves the slide between images)."""

    points_xyz_mm: np.ndarray
    powers_photons_per_s: np.ndarray
    on_stage: bool = False


@dataclass(frozen=True)
class TiltedTargetScene:
    """A resolution target tilted in depth: top row at ``z_near_mm``, bottom row at
    ``z_far_mm`` (mm), ``width_mm`` wide; ``target`` (rows, cols) in [0, 1] or None
    for the USAF-like default; ``radiance`` as in :class:`PlanarScene`."""

    z_near_mm: float
    z_far_mm: float
    width_mm: float
    target: np.ndarray | None = None
    radiance: float = 2e9


def lensless_geometry(geometry: GeometryConfig, seed: int = 0,
                      falloff_sigma_deg: float | None = 20.0) -> LenslessGeometry:
    """The optics model's geometry for a bench config's ``[geometry]`` table.

    The diffuser surface is :func:`recon.optics.lensless.diffuser_for_sensor` (seeded);
    ``falloff_sigma_deg`` is the pixels' angular response (None: none).
    """
    rows, cols = geometry.sensor_shape_px
    pitch_mm = geometry.sensor_pixel_pitch_um * 1e-3
    surface = diffuser_for_sensor(geometry.diffuser_kind, (cols * pitch_mm, rows * pitch_mm),
                                  seed)
    return LenslessGeometry(surface, geometry.diffuser_sensor_distance_mm,
                            tuple(geometry.aperture_mm), (rows, cols),
                            geometry.sensor_pixel_pitch_um, falloff_sigma_deg)


class VirtualBench(Bench):
    """Simulated devices of a bench config, coupled through the optics models.

    A :class:`~instrument.devices.bench.Bench` whose time is the simulated clock (settle
    times and waits cost nothing), whose noise is reseeded per plan point (so a
    resumed run equals an uninterrupted one) and which carries out the operator
    actions of :data:`ACTIONS` itself.

    Parameters
    ----------
    config : BenchConfig, optional
        The bench; every device is swapped for its simulated twin. Default
        :func:`instrument.config.default_bench`.
    seed : int
        Seeds the diffuser, the mask and every device's noise.
    source_power_photons_per_s : float
        Photons per second the pinhole emits with one LED at full brightness right
        behind it (also the power of one LED seen directly once the pinhole is out).
    stray_light_fraction : float
        Stray light of the point source: a smooth glow over the sensor carrying this
        fraction of the PSF's collected power (what the background removal of
        Sec. 6.4 takes out).
    prnu_fraction : float
        The camera's photo-response non-uniformity (what a flat field measures).
    falloff_sigma_deg : float or None or "bench"
        Sigma of the pixels' Gaussian angular response (Eq. 5.1), degrees (what the
        angular-response calibration measures); None: no fall-off; ``"bench"``
        (default): the bench file's ``geometry.sensor_falloff_sigma_deg``, else 20.
        The bench file's ``geometry.background_light_photons_per_s`` adds a smooth
        background (:meth:`stray_light_map`'s shape) whenever a source or a scene is
        lit with the diffuser in (the microscope's excitation leak and filter
        autofluorescence, Eq. 6.1's ``g``).
    hologram : HolographicDisplayModel, optional
        Model of the holography branch (its ``SlmModel`` holds the SLM's response);
        default built lazily from the SLM, ``slm_response`` and the camera shape
        (96 x 120 SLM, k = 4, q = 4).
    slm_response : SlmPhaseResponse, optional
        The SLM's true gray -> phase response; default
        :meth:`SlmPhaseResponse.nonlinear` (2.1 pi at gray 255 at 532 nm, scaled by
        532 nm / wavelength). :meth:`SlmPhaseResponse.linear` gives the ideal SLM the
        uncalibrated software assumes.
    nd_filter_transmission : float
        Transmission of the ND filter the ``insert_nd_filter`` action puts in front of
        the camera (default 0.01, OD 2).
    relay_na : float or None
        Image-side numerical aperture of the SLM -> mask relay (default 0.05: depth
        of field ``lambda / NA^2`` = 0.21 mm at 532 nm). The pupil rounds the SLM
        pixels' edges, which makes the spot's response to defocus smooth with one
        maximum, as on a real relay (sharp-edged pixels and no pupil give a cusp at
        focus); it costs two fine-grid FFTs per rendered frame. None: no pupil.
    laser_drift_per_sqrt_s : float
        Diffusion of the holography laser's log-power per sqrt(second) of bench time
        (mean-reverting over 600 s; :class:`recon.optics.holo_display.LaserDrift`,
        seeded by ``seed``); 0: a steady laser (a resumed run then reproduces an
        uninterrupted one exactly).
    realtime : bool
        Run the simulated clock in real time (``SimClock(realtime=True)``): waits
        take wall-clock time and a streaming camera delivers frames on the wall clock
        from its grab thread (live capture and demos); default False (tests, plans).
        The camera then draws Gaussian shot noise above
        :data:`REALTIME_GAUSSIAN_ABOVE_E` electrons (unless its bench parameters say
        otherwise), which makes 20 fps at 1200 x 1600 affordable.
    render_cache_size : int
        Noise-free camera images kept (keyed by everything they depend on, including
        the scene time of a :class:`~instrument.devices.video_scenes.VideoScene`), so a
        periodic video scene rendered ahead (:meth:`prerender`) streams without
        re-rendering.

    Attributes
    ----------
    devices : dict[str, drivers.base.Device]
        The opened devices (empty until :meth:`open`).
    clock : drivers.simulated.SimClock
    model : recon.optics.lensless.LenslessModel
    branch : {"lensless", "holography"}
        Which optical path the camera looks through.
    scene : PlanarScene or BeadScene or TiltedTargetScene or VideoScene or None
    state : dict[str, bool]
        Operator-controlled state: ``camera_capped``, ``diffuser_installed``,
        ``pinhole_installed``, ``nd_filter_installed``.
    slm_response : SlmPhaseResponse or None
        The SLM's true response (None when ``hologram`` was given).

    Raises
    ------
    ValueError
        Both ``hologram`` and ``slm_response`` given, or an ND transmission outside
        (0, 1].
    """

    def __init__(self, config: BenchConfig | None = None, *, seed: int = 0,
                 source_power_photons_per_s: float = 2e11, stray_light_fraction: float = 0.02,
                 prnu_fraction: float = 0.01, falloff_sigma_deg: float | None | str = "bench",
                 hologram=None, slm_response: SlmPhaseResponse | None = None,
                 nd_filter_transmission: float = 0.01, relay_na: float | None = 0.05,
                 laser_drift_per_sqrt_s: float = 1e-3, realtime: bool = False,
                 render_cache_size: int = 8):
        super().__init__({}, config=with_simulated_drivers(config or default_bench()))
        self.seed = int(seed)
        self.clock = SimClock(realtime=realtime)
        if isinstance(render_cache_size, bool) or not isinstance(render_cache_size, int) or (
                render_cache_size < 1):
            raise ValueError(f"render_cache_size={render_cache_size!r}: give an integer >= 1")
        self.render_cache_size = render_cache_size
        if isinstance(falloff_sigma_deg, str):  # "bench": the bench file's, else 20 deg
            falloff_sigma_deg = self.config.geometry.sensor_falloff_sigma_deg or 20.0
        self.geometry = lensless_geometry(self.config.geometry, seed, falloff_sigma_deg)
        self.background_light = float(self.config.geometry.background_light_photons_per_s)
        self.model = LenslessModel(self.geometry)
        self.source_power = float(source_power_photons_per_s)
        self.stray_light_fraction = float(stray_light_fraction)
        self.prnu_fraction = float(prnu_fraction)
        if hologram is not None and slm_response is not None:
            raise ValueError("give slm_response or hologram (whose SlmModel holds the SLM's "
                             "response), not both")
        if not 0 < nd_filter_transmission <= 1:
            raise ValueError(f"nd_filter_transmission={nd_filter_transmission!r}: give a "
                             "transmission in (0, 1]")
        self._hologram = hologram
        self.slm_response = None if hologram is not None else (
            slm_response or SlmPhaseResponse.nonlinear())
        self.nd_filter_transmission = float(nd_filter_transmission)
        self.relay_na = None if relay_na is None else float(relay_na)
        self.laser_drift_per_sqrt_s = float(laser_drift_per_sqrt_s)
        self.branch = "lensless"
        self.scene: (PlanarScene | DisplayScene | BeadScene | TiltedTargetScene | VideoScene
                     | None) = None
        self.state = {"camera_capped": False, "diffuser_installed": True,
                      "pinhole_installed": True, "nd_filter_installed": False}
        self._scene_version = 0
        self._renders: collections.OrderedDict[tuple, np.ndarray] = collections.OrderedDict()
        self._psf_cache: collections.OrderedDict[tuple, np.ndarray] = collections.OrderedDict()
        self._stray_map: np.ndarray | None = None

    def _construct(self, dev, cls):
        """Build one simulated device on the shared clock, the camera seeing
        :meth:`irradiance` (the ``construct`` hook of :func:`open_bench`)."""
        params = dict(dev.params)
        accepted = accepted_params(cls)
        index = [d.id for d in self.config.devices].index(dev.id)
        extra = {"clock": self.clock, "seed": self.seed + index}
        if dev.kind == "camera":
            params["sensor_shape"] = tuple(self.geometry.sensor_shape)
            params["pixel_pitch_um"] = self.geometry.sensor_pitch_um
            extra["irradiance"] = self.irradiance
            extra["prnu_fraction"] = self.prnu_fraction
            if self.clock.realtime and "gaussian_shot_noise_above_e" not in params:
                extra["gaussian_shot_noise_above_e"] = REALTIME_GAUSSIAN_ABOVE_E
        params.update({k: v for k, v in extra.items() if accepted is None or k in accepted})
        return cls(dev.id, **params)

    def open(self, timeout_s: float = 5.0) -> VirtualBench:
        """Construct and open every device through :func:`instrument.devices.bench_setup.open_bench`
        (nothing is left half-open if one fails); reopening builds fresh devices."""
        self.devices = open_bench(self.config, timeout_s=timeout_s, construct=self._construct)
        return self

    def __enter__(self) -> VirtualBench:
        return self.open()

    # -- Bench hooks: simulated time, per-point noise, operator actions -------------------
    def sleep(self, seconds: float) -> None:
        """Advance the simulated clock by ``seconds`` (no real wait)."""
        if seconds > 0:
            self.clock.advance(seconds)

    def now_s(self) -> float:
        """Simulated time, s."""
        return self.clock.now_s

    def on_point(self, key: tuple[int, ...]) -> None:
        """Reseed every simulated camera's noise from ``key`` (see
        :meth:`drivers.simulated.SimulatedCamera.reseed_noise`)."""
        for dev in self.devices.values():
            if hasattr(dev, "reseed_noise"):
                dev.reseed_noise(key)

    def prompt(self, action: str, message: str) -> None:
        """Carry out operator ``action`` (one of :data:`ACTIONS`) on the simulated optics.

        Raises
        ------
        PromptRefused
            An action the virtual bench cannot perform.
        """
        if action not in ACTIONS:
            raise PromptRefused(f"the virtual bench cannot {message!r} (action {action!r}); "
                                f"it knows {sorted(ACTIONS)}")
        name, value = ACTIONS[action]
        self.state[name] = value
        self._scene_version += 1
        log.info("virtual bench: %s", message)

    # -- the world ---------------------------------------------------------------------
    def set_scene(self, scene: PlanarScene | DisplayScene | BeadScene | TiltedTargetScene
                  | VideoScene | None) -> None:
        """Put a scene in front of the camera (None removes it).

        A :class:`~instrument.devices.video_scenes.VideoScene` changes with time: each frame
        shows it at the frame's :attr:`~drivers.simulated.SimulatedCamera.frame_time_s`
        (the middle of the exposure), see :meth:`irradiance`.
        """
        if scene is not None and not isinstance(scene, PlanarScene | DisplayScene | BeadScene
                                                | TiltedTargetScene | VideoScene):
            raise ReconInputError(
                "scene must be a PlanarScene, a DisplayScene, a BeadScene, a "
                "TiltedTargetScene, a video scene (instrument.devices.video_scenes) or None")
        self.scene = scene
        self._scene_version += 1

    def set_branch(self, branch: str) -> None:
        """Route the camera to the ``lensless`` or ``holography`` optical path."""
        if branch not in BRANCHES:
            raise ReconInputError(f"unknown branch {branch!r}; use one of {BRANCHES}")
        self.branch = branch

    def source_position_mm(self) -> tuple[float, float, float]:
        """(x, y, z) of the pinhole, mm (z = distance from the diffuser)."""
        pos = self.source_stage.positions()
        return (float(pos.get("x", 0.0)), float(pos.get("y", 0.0)), float(pos["z"]))

    def source_power_photons_per_s(self) -> float:
        """Power of the pinhole source from the lit LEDs.

        The pinhole sits on the source stage in front of the array (behind an 80 deg
        diffuser, App. A.2); an LED at lateral distance r from the pinhole couples
        with weight exp(-r^2 / (2 (2 pitch)^2)) times its brightness.
        """
        leds = self.led_array
        lit = self._lit_leds()
        if not lit:
            return 0.0
        x, y, _ = self.source_position_mm()
        index = np.fromiter(lit, int, len(lit))
        brightness = np.array([b for _, b in lit.values()], float)
        pos = np.asarray(leds.positions_mm)[index]
        sigma = 2.0 * float(leds.pitch_mm)
        r2 = (pos[:, 0] - x) ** 2 + (pos[:, 1] - y) ** 2
        total = float(np.sum(brightness * np.exp(-r2 / (2 * sigma**2))))
        return self.source_power * total

    def psf(self, xyz_mm) -> np.ndarray:
        """Ray-traced PSF (fraction of emitted power per pixel), cached per position
        (rounded to 0.1 um): the :data:`PSF_CACHE_SIZE` positions used last, or twice a
        video scene's sources if that is more; the least recently used goes first."""
        key = tuple(round(float(v), 4) for v in xyz_mm)
        cached = self._psf_cache.get(key)
        if cached is not None:
            self._psf_cache.move_to_end(key)
            return cached
        n = len(self.scene.sources_at(0.0)[1]) if isinstance(self.scene, VideoScene) else 0
        psf = self._psf_cache[key] = self.model.psf(key)
        while len(self._psf_cache) > max(PSF_CACHE_SIZE, 2 * n):
            self._psf_cache.popitem(last=False)
        return psf

    def point_sources(self) -> tuple[tuple[tuple[float, float, float], float], ...]:
        """The point sources lit now: ``((x, y, z) mm, power photons/s)`` each.

        With the pinhole installed: the pinhole at the source stage position, with the
        power of :meth:`source_power_photons_per_s` (nothing if dark). With it
        removed: every lit LED at ``(x_i, y_i, distance_mm)`` with power
        ``source_power * brightness`` (the LED array seen directly).
        """
        if self.state["pinhole_installed"]:
            power = self.source_power_photons_per_s()
            if power <= 0:
                return ()
            pos = tuple(round(v, 6) for v in self.source_position_mm())
            return ((pos, round(power, 3)),)
        leds = self.led_array
        xy = np.asarray(leds.positions_mm)
        z = float(leds.distance_mm)
        return tuple(((round(float(xy[i, 0]), 6), round(float(xy[i, 1]), 6), z),
                      self.source_power * float(b))
                     for i, (_, b) in sorted(self._lit_leds().items()))

    def _lit_leds(self) -> dict:
        """The lit LEDs; none while the array is unplugged (it lost its power: the
        camera keeps streaming a dark scene instead of failing with the array)."""
        try:
            return self.led_array.lit()
        except DeviceDisconnectedError:
            return {}

    def bare_sensor_irradiance(self, xyz_mm) -> np.ndarray:
        """Fraction of a point source's power per pixel with the diffuser and aperture
        removed: ``cos(theta) / (4 pi r^2) * pixel area * f(theta)`` per pixel, with
        ``r`` the source-pixel distance, ``theta`` the incidence angle and ``f`` the
        pixel angular response (Eq. 5.1's fall-off). The source's distance from the
        sensor is ``z + d``.

        Returns
        -------
        ndarray, float64, (rows, cols)
        """
        x, y, z = (float(v) for v in xyz_mm)
        rows, cols = self.geometry.sensor_shape
        pitch = self.geometry.sensor_pitch_um * 1e-3
        u = (np.arange(cols) - (cols - 1) / 2) * pitch - x
        v = (np.arange(rows) - (rows - 1) / 2) * pitch - y
        depth = z + self.geometry.d_mm
        r2 = v[:, None] ** 2 + u[None, :] ** 2 + depth**2
        value = depth / (4 * np.pi * r2 * np.sqrt(r2)) * pitch**2
        sigma = self.geometry.falloff_sigma_deg
        if sigma is not None:
            theta = np.arccos(depth / np.sqrt(r2))
            value *= np.exp(-theta**2 / (2 * np.radians(sigma) ** 2))
        return value

    def stray_light_map(self) -> np.ndarray:
        """The stray-light glow's shape: smooth, sums to 1 over the sensor."""
        if self._stray_map is None:
            rows, cols = self.geometry.sensor_shape
            rng = np.random.default_rng([self.seed, 0x57])
            r0, c0 = rng.uniform(0.2, 0.8, 2)
            yy, xx = np.meshgrid(np.linspace(0, 1, rows), np.linspace(0, 1, cols),
                                 indexing="ij")
            glow = np.exp(-((yy - r0) ** 2 + (xx - c0) ** 2) / (2 * 0.35**2)) + 0.3 * xx
            self._stray_map = glow / glow.sum()
        return self._stray_map

    def irradiance(self, camera) -> np.ndarray:
        """Photo-electrons per second per sensor pixel (noise-free), for the camera.

        Lensless branch: each point source's ray-traced PSF plus its stray light
        (diffuser installed) or its bare-sensor irradiance (diffuser removed), plus
        the scene's image (diffuser installed only). Holography branch: the display
        model's rendering of the SLM image at the mask stage's pose, times the laser's
        power drift (:class:`recon.optics.holo_display.LaserDrift`, advanced to the bench
        clock: a slow multiplicative walk, 1e-3 per sqrt(s) by default). Nothing when the
        camera is capped; times ``nd_filter_transmission`` with the ND filter in. Cached
        on everything it depends on (branch, sources, operator state, scene, SLM
        pattern and mask pose), so streaming a static bench costs nothing; the last
        ``render_cache_size`` images are kept.

        A video scene is shown at its scene time for ``camera.frame_time_s`` (the
        bench time for a camera without it): each bead or cell is a point source
        rendered with the ray-traced PSF of its position (:meth:`psf`, the pinhole's
        path), so cells that do not move cost one PSF each, once.

        Returns
        -------
        ndarray, float64, (rows, cols)
            Read-only (the simulated camera keeps its per-pixel maps while the same
            read-only array comes back).
        """
        state = tuple(sorted(self.state.items()))
        if self.branch == "holography":
            gray = self.slm.current_image()
            pose = self._mask_pose()
            key = ("holo", self.slm.pattern_id, pose, state)
        else:
            gray = pose = None
            sources = () if self.state["camera_capped"] else self.point_sources()
            slide = (self.source_position_mm() if isinstance(self.scene, BeadScene)
                     and self.scene.on_stage else None)
            shown = (self.device(self.scene.device).pattern_id
                     if isinstance(self.scene, DisplayScene) else None)
            key = ("lensless", sources, state, self._scene_version, slide, shown,
                   self._scene_time(camera))
        drift = 1.0
        if self.branch == "holography":  # the laser's power walks with bench time
            d = self.hologram.drift
            if self.now_s() > d.time_s:
                d.advance(self.now_s() - d.time_s)
            drift = d.factor
        cached = self._renders.get(key)
        if cached is not None:
            self._renders.move_to_end(key)
            return cached * drift if drift != 1.0 else cached
        value = np.zeros(self.geometry.sensor_shape)
        if self.state["camera_capped"]:
            pass
        elif self.branch == "holography":  # cached at unit power, scaled per call
            value = self.hologram.render(gray, pose) / drift
        elif self.state["diffuser_installed"]:
            for pos, power in sources:
                psf = self.psf(pos)
                value += power * psf
                if self.stray_light_fraction > 0:
                    value += (self.stray_light_fraction * power * float(psf.sum())
                              * self.stray_light_map())
            value += self._scene_image(key[-1])
            if self.background_light > 0 and (sources or self.scene is not None):
                value += self.background_light * self.stray_light_map()
        else:
            for pos, power in sources:
                value += power * self.bare_sensor_irradiance(pos)
        if self.state["nd_filter_installed"]:
            value = value * self.nd_filter_transmission
        value.flags.writeable = False
        self._renders[key] = value
        while len(self._renders) > self.render_cache_size:
            self._renders.popitem(last=False)
        return value * drift if drift != 1.0 else value

    def _scene_time(self, camera) -> float | None:
        """Scene time a camera frame shows (None: the scene does not change)."""
        if not isinstance(self.scene, VideoScene):
            return None
        t = getattr(camera, "frame_time_s", None)
        return self.scene.scene_time(self.now_s() if t is None else t)

    def prerender(self, times_s=None) -> int:
        """Render the video scene ahead of streaming, for the lensless camera as the
        bench is now (sources, operator state).

        Parameters
        ----------
        times_s : array_like of float, optional
            Times to render, s; default every distinct scene time
            (:meth:`~instrument.devices.video_scenes.VideoScene.distinct_times`).

        Returns
        -------
        int
            Distinct renders now cached (at most ``render_cache_size``; raise it to
            hold a whole period).

        Raises
        ------
        ReconInputError
            No video scene, or no ``times_s`` for a scene without finitely many
            distinct times.
        """
        s = self.scene
        if not isinstance(s, VideoScene):
            raise ReconInputError("prerender needs a video scene; call set_scene() first")
        times = s.distinct_times() if times_s is None else np.atleast_1d(
            np.asarray(times_s, float))
        if times is None:
            raise ReconInputError(
                "this scene has no finite set of distinct times (give time_step_s to a "
                "periodic scene), so pass times_s")
        distinct = sorted({s.scene_time(t) for t in times})
        probe = _SceneProbe()
        for t in distinct:
            probe.frame_time_s = t
            self.irradiance(probe)
        return min(len(distinct), self.render_cache_size)

    def _scene_image(self, scene_time_s: float | None = None) -> np.ndarray:
        s = self.scene
        if s is None:
            return 0.0
        if isinstance(s, VideoScene):
            out = np.zeros(self.geometry.sensor_shape)
            for pos, power in zip(*s.sources_at(scene_time_s), strict=True):
                if power > 0:
                    out += power * self.psf(pos)
            return out
        if isinstance(s, DisplayScene):
            s = self._displayed(s)
        if isinstance(s, PlanarScene):
            return s.radiance * self.model.render(np.asarray(s.image, float), s.z_mm,
                                                  s.width_mm)
        if isinstance(s, TiltedTargetScene):
            return s.radiance * self.model.render_tilted_target(
                s.z_near_mm, s.z_far_mm, s.width_mm, target=s.target)
        points = np.asarray(s.points_xyz_mm, float)
        if s.on_stage:
            points = points + np.asarray(self.source_position_mm())
        return self.model.render_points(points, np.asarray(s.powers_photons_per_s, float))

    def _displayed(self, scene: DisplayScene) -> PlanarScene:
        """The planar scene a display shows now (gray / 255 over its panel)."""
        display = self.device(scene.device)
        width_mm = display.resolution[1] * display.pixel_pitch_um * 1e-3
        return PlanarScene(display.current_image() / 255.0, scene.z_mm, width_mm,
                           scene.radiance)

    # -- holography branch --------------------------------------------------------------
    @property
    def hologram(self):
        """The holography model (built on first use; its SLM response is
        ``slm_response`` at the SLM's ``wavelength_nm``)."""
        if self._hologram is None:
            from recon.optics.holo_display import (
                CameraMapping,
                HolographicDisplayModel,
                LaserDrift,
                MaskModel,
                RelayModel,
                SlmModel,
            )

            slm = self.slm
            # supersample 4: stage moves of 1/16 mask px show (point sampling snaps the
            # mask edges to the fine grid, hiding sub-pixel alignment moves)
            mask = MaskModel(slm_shape=slm.resolution, slm_pitch_um=slm.pixel_pitch_um,
                             k=4, q=4, seed=self.seed, supersample=4)
            cam = CameraMapping.from_params(shape=tuple(self.geometry.sensor_shape))
            response = SlmModel(lut=self.slm_response.lut_rad(slm.wavelength_nm))
            relay = RelayModel(wavelength_um=slm.wavelength_nm / 1000.0, na=self.relay_na)
            drift = LaserDrift(seed=self.seed, sigma_per_sqrt_s=self.laser_drift_per_sqrt_s)
            self._hologram = HolographicDisplayModel(mask, slm=response, relay=relay,
                                                     camera=cam, drift=drift)
        return self._hologram

    def _mask_pose(self) -> tuple[float, ...]:
        p = self.mask_stage.positions()
        rad = np.pi / 180.0
        return (p.get("x", 0.0), p.get("y", 0.0), p.get("z", 0.0), p.get("tip", 0.0) * rad,
                p.get("tilt", 0.0) * rad, p.get("rotation", 0.0) * rad)

    # -- ground truth for evaluation -----------------------------------------------------
    def scene_truth(self, sensor_shape: tuple[int, int] | None = None) -> np.ndarray:
        """The planar scene as a reconstruction of the convolution model should show it
        (:meth:`recon.optics.lensless.LenslessModel.scene_truth`: area-resampled onto
        the object grid of Eq. 3.3, flipped, centred in the sensor field of view).

        Returns
        -------
        ndarray, float64, ``sensor_shape`` (default the camera's)

        Raises
        ------
        ReconInputError
            No planar scene in front of the camera.
        """
        s = self.scene
        if not isinstance(s, PlanarScene):
            raise ReconInputError("scene_truth needs a PlanarScene in front of the camera")
        return self.model.scene_truth(s.image, s.z_mm, s.width_mm, sensor_shape)


class _SceneProbe:
    """Stands in for the camera in :meth:`VirtualBench.prerender`: only its
    ``frame_time_s`` is read."""

    frame_time_s: float = 0.0

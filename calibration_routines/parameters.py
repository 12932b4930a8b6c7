"""Each calibration routine's parameters as one typed model, and the plan it builds.

``diffuserlab calibrate ROUTINE`` generates its options from these models
(:meth:`instrument.options.Options.add_arguments`: flag, type, default, unit, limits),
the GUI's calibration panel generates its forms from them
(:meth:`~instrument.options.Options.specs`) and validates the texts typed into a model
(:meth:`~instrument.options.Options.from_text`); both then hand the model to
:meth:`RoutineParams.plan`, which builds the routine's plan for an open bench. The
option tables of docs/calibration.md are generated from them
(``python -m calibration_routines.parameters_doc``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import ClassVar, Literal

from instrument.options import Options, option

__all__ = ["PARAMETERS", "AlignMaskParams", "AngularResponseParams", "DarkParams", "PsfBlindParams",
           "PsfFromScenesParams", "PsfGridParams", "PsfSweepParams", "RoutineParams",
           "SlmLutParams"]


class RoutineParams(Options, ABC):
    """Parameters every routine takes; subclasses add their own and build the plan."""

    #: The routine's name as ``calibrate`` takes it.
    routine: ClassVar[str] = ""
    #: One line for ``calibrate --help``.
    summary: ClassVar[str] = ""

    frames: int | None = option(None, ge=1, help="frames per point",
                                default_text="from the bench file")

    def _frames(self) -> dict[str, int]:
        return {} if self.frames is None else {"frames_per_point": self.frames}

    @abstractmethod
    def plan(self, bench, *, seed: int = 0, say: Callable[[str], None] = print):
        """The routine's plan for the open ``bench``.

        Parameters
        ----------
        bench : instrument.devices.bench.Bench or instrument.devices.virtual_bench.VirtualBench
            Open (plans read its devices, geometry and calibration defaults).
        seed : int
            Seed of the routine's random choices (psf-blind's slide offsets).
        say : callable
            Where a routine reports what it measured before planning (psf-sweep's
            probed step).

        Returns
        -------
        instrument.acquisition.plan.Plan

        Raises
        ------
        instrument.acquisition.plan.PlanError, recon.errors.ReconInputError
            Parameters the plan refuses on this bench.
        """


class DarkParams(RoutineParams):
    routine: ClassVar[str] = "dark"
    summary: ClassVar[str] = "dark frames, hot-pixel map and flat field"
    command: ClassVar[str] = "calibrate dark"

    exposure_s: float | None = option(None, gt=0, help="dark exposure", unit="s",
                                      default_text="the camera's current one")

    def plan(self, bench, *, seed: int = 0, say: Callable[[str], None] = print):
        from .dark_flat import DarkFlatPlan

        params = {} if self.frames is None else {"n_frames": self.frames}
        if self.exposure_s is not None:
            params["exposure_s"] = self.exposure_s
        return DarkFlatPlan.for_bench(bench, **params)


class PsfSweepParams(RoutineParams):
    routine: ClassVar[str] = "psf-sweep"
    summary: ClassVar[str] = "axial PSF sweep (Sec. 4.3)"
    command: ClassVar[str] = "calibrate psf-sweep"

    z_min: float | None = option(None, gt=0, help="nearest depth", unit="mm",
                                 default_text="the bench file's")
    z_max: float | None = option(None, gt=0, help="farthest depth", unit="mm",
                                 default_text="the bench file's")
    spacing: Literal["inverse", "uniform"] = option(
        "inverse", help="constant step in 1/z (Eq. 4.7) or in z")
    n_depths: int | None = option(None, ge=2, help="number of depth planes",
                                  default_text="the bench file's")
    c_per_mm: float | None = option(None, gt=0, help="step in 1/z", unit="1/mm",
                                    default_text="from the number of depths")
    probe_step: bool = option(False, help="derive the 1/z step from the depth sensitivity "
                              "of a PSF measured at z-min (Nyquist: half the "
                              "distinguishable step)")
    x_mm: float = option(0.0, help="source x position", unit="mm")
    y_mm: float = option(0.0, help="source y position", unit="mm")

    def plan(self, bench, *, seed: int = 0, say: Callable[[str], None] = print):
        from .psf_sweep import PsfSweepPlan, probe_inverse_depth_step

        cal = bench.config.calibration
        z_min = cal.z_range_mm[0] if self.z_min is None else self.z_min
        z_max = cal.z_range_mm[1] if self.z_max is None else self.z_max
        params = dict(z_min_mm=z_min, z_max_mm=z_max, spacing=self.spacing, x_mm=self.x_mm,
                      y_mm=self.y_mm, **self._frames())
        if self.probe_step:
            step = probe_inverse_depth_step(bench, z_min, x_mm=self.x_mm, y_mm=self.y_mm)
            say(f"depth step from the measured depth sensitivity at {z_min:g} mm: "
                f"{step:.4g} /mm in 1/z")
            params.update(spacing="inverse", c_per_mm=step,
                          depth_step_source=f"probed at {z_min:g} mm (threshold 0.8, /2)")
        elif self.c_per_mm is not None:
            params["c_per_mm"] = self.c_per_mm
        elif self.n_depths is not None:
            params["n_depths"] = self.n_depths
        return PsfSweepPlan.for_bench(bench, **params)


class PsfGridParams(RoutineParams):
    routine: ClassVar[str] = "psf-grid"
    summary: ClassVar[str] = "lateral PSF grid (Sec. 5.2-5.3)"
    command: ClassVar[str] = "calibrate psf-grid"

    mode: Literal["leds", "stage"] = option(
        "leds", help="light the array's LEDs, or raster the pinhole on the source stage")
    n: int = option(3, ge=2, help="positions a side (n x n)")
    spacing_mm: float | None = option(None, gt=0, help="stage raster spacing", unit="mm",
                                      default_text="from the field of view")
    z_mm: float = option(40.0, gt=0, help="stage mode depth", unit="mm")
    led_step: int = option(2, ge=1, help="leds mode: every k-th LED")
    falloff_sigma_deg: float | None = option(
        None, gt=0, help="measured sensor fall-off sigma, for the Nyquist check",
        unit="deg", default_text="no check")

    def plan(self, bench, *, seed: int = 0, say: Callable[[str], None] = print):
        from .psf_grid import PsfGridPlan

        return PsfGridPlan.for_bench(bench, mode=self.mode, n=self.n,
                                     spacing_mm=self.spacing_mm, z_mm=self.z_mm,
                                     led_step=self.led_step,
                                     falloff_sigma_deg=self.falloff_sigma_deg, **self._frames())


class PsfBlindParams(RoutineParams):
    routine: ClassVar[str] = "psf-blind"
    summary: ClassVar[str] = ("PSF grid from images of a bead slide at random stage "
                              "offsets, by blind deconvolution (Sec. 5.4)")
    command: ClassVar[str] = "calibrate psf-blind"

    images: int = option(4, ge=1, help="bead-slide images")
    grid: int = option(3, ge=2, help="PSFs a side to recover (grid x grid)")
    z_mm: float = option(..., gt=0, help="depth of the slide", unit="mm")
    node_spacing_mm: float = option(..., gt=0, help="spacing of the recovered PSFs in the "
                                    "object plane", unit="mm")
    exposure_s: float = option(..., gt=0, help="exposure of every image and dark", unit="s")
    rounds: int = option(6, ge=1, help="blind deconvolution rounds")
    bin_factor: int = option(1, ge=1, flag="--bin", help="bin the images before the blind "
                             "deconvolution, pixels per side")

    def plan(self, bench, *, seed: int = 0, say: Callable[[str], None] = print):
        from .psf_blind import PsfBlindPlan

        return PsfBlindPlan.for_bench(bench, n_images=self.images, z_mm=self.z_mm,
                                      grid=self.grid, node_spacing_mm=self.node_spacing_mm,
                                      exposure_s=self.exposure_s, seed=seed,
                                      rounds=self.rounds, bin_factor=self.bin_factor,
                                      **self._frames())


class AngularResponseParams(RoutineParams):
    routine: ClassVar[str] = "angular-response"
    summary: ClassVar[str] = "sensor angular response (Fig. 3.5)"
    command: ClassVar[str] = "calibrate angular-response"

    z_mm: float | None = option(None, gt=0, help="source depth", unit="mm",
                                default_text="from the stage's reach")
    max_angle_deg: float | None = option(None, gt=0, lt=85, help="largest source angle",
                                         unit="deg", default_text="from the stage's reach")
    n_angles: int | None = option(None, ge=3, help="angles per axis",
                                  default_text="the plan's")
    beta_deg: float | None = option(None, ge=0, lt=90, help="diffuser's maximum deflection "
                                    "for the field of view (Eq. 3.12)", unit="deg",
                                    default_text="the bench file's")

    def plan(self, bench, *, seed: int = 0, say: Callable[[str], None] = print):
        from .angular_response import AngularResponsePlan

        params = {k: v for k, v in (("z_mm", self.z_mm), ("max_angle_deg", self.max_angle_deg),
                                    ("n_angles", self.n_angles), ("beta_deg", self.beta_deg))
                  if v is not None}
        return AngularResponsePlan.for_bench(bench, **params, **self._frames())


class SlmLutParams(RoutineParams):
    routine: ClassVar[str] = "slm-lut"
    summary: ClassVar[str] = ("SLM phase look-up table (gray -> phase) from binary "
                              "gratings, mask retracted")
    command: ClassVar[str] = "calibrate slm-lut"

    n_levels: int | None = option(None, ge=8, le=256, flag="--levels",
                                  help="gray levels measured", default_text="48")
    period_px: int | None = option(None, ge=2, help="grating period in SLM pixels, even",
                                   unit="px", default_text="8")
    no_nd_filter: bool = option(False, help="do not ask for an ND filter in front of the "
                                "camera")

    def plan(self, bench, *, seed: int = 0, say: Callable[[str], None] = print):
        from .slm_lut import SlmLutPlan

        params = {k: v for k, v in (("n_levels", self.n_levels),
                                    ("period_px", self.period_px)) if v is not None}
        return SlmLutPlan.for_bench(bench, attenuate=not self.no_nd_filter, **params,
                                    **self._frames())


class PsfFromScenesParams(RoutineParams):
    routine: ClassVar[str] = "psf-from-scenes"
    summary: ClassVar[str] = ("PSF from known scenes shown on the display device (or from "
                              "scene/measurement files), by non-negative least squares")
    command: ClassVar[str] = "calibrate psf-from-scenes"

    z_mm: float = option(..., gt=0, help="distance of the scenes (the display) from the "
                         "diffuser", unit="mm")
    # the upper bound (256 patterns, or the number of bundled photographs,
    # recon.scenes.BUNDLED) is checked by the plan: importing recon.scenes here would load
    # numpy into every --help
    images: int = option(12, ge=2, help="scenes shown (at most 256 patterns, or as many "
                         "photographs as scikit-image ships)")
    patterns: Literal["random", "photographs"] = option(
        "random", help="random binary patterns in blocks of about one sensor pixel (a flat "
        "spectrum, gamma-free), or scikit-image's bundled photographs in order")
    display: str = option("slm", help="the display's device id or role (an SLM or the "
                          "full-screen monitor driver)")
    iterations: int = option(100, ge=1, help="the most ADMM iterations of the estimate "
                             "(it stops once an iteration changes the PSF by under 1/100)")
    recipe_images: int | None = option(
        None, ge=0, help="photographs shown after the scenes to fit the reconstruction "
        "recipe on (0, or 2 and more); default 4 after random patterns, 0 after photographs "
        "(the recipe is then fitted on them, each left out of its PSF)",
        default_text="4 or 0")

    def plan(self, bench, *, seed: int = 0, say: Callable[[str], None] = print):
        from .psf_from_scenes import PsfFromScenesPlan

        return PsfFromScenesPlan.for_bench(bench, images=self.images, z_mm=self.z_mm,
                                           display=self.display, patterns=self.patterns,
                                           recipe_images=self.recipe_images,
                                           iterations=self.iterations, **self._frames())


#: ``{routine: model}`` in the order ``calibrate`` lists them.
PARAMETERS: dict[str, type[RoutineParams]] = {
    m.routine: m for m in (DarkParams, PsfSweepParams, PsfGridParams, PsfBlindParams,
                           AngularResponseParams, SlmLutParams, PsfFromScenesParams)}


class AlignMaskParams(Options):
    """The parameters of ``align mask`` (the SLM-mask alignment with spot feedback,
    :class:`calibration_routines.mask_alignment.MaskAligner`); ``--sim-*`` place the
    virtual bench's mask with ``--simulate``
    (``calibration_routines.cli.align.simulated_truth``)."""

    command: ClassVar[str] = "align mask"

    mask_seed: int | None = option(None, help="seed of the installed mask's pattern",
                                   default_text="the virtual bench's")
    mask_pattern: str | None = option(
        None, help="the installed mask's pattern, .npy: uint8 0/1 bits (1 = phase pi) or "
        "+1/-1, shape (R k + 2 margin, C k + 2 margin); instead of --mask-seed",
        default_text="none")
    mask_margin: int = option(16, ge=0, help="mask pixels of --mask-pattern beyond the SLM "
                              "footprint on each side")
    k: int = option(4, ge=1, help="mask pixels per SLM pixel")
    lut: str | None = option(None, help="SLM LUT to load first: a `calibrate slm-lut` run "
                             "store (RUN.zarr) or its exported LUT file", default_text="none")
    coarse_range_px: int = option(12, ge=1, help="half-width of the coarse software search "
                                  "(widened x2 once)", unit="mask px")
    frames: int = option(3, ge=1, help="frames averaged per reading")
    no_rotation: bool = option(False, help="do not rotate the stage")
    no_focus: bool = option(False, help="do not adjust the stage's z, tip and tilt (step 5)")
    relay_na: float | None = option(
        None, gt=0, le=1, help="image-side NA of the SLM -> mask relay (sets the simulated "
        "ceiling and the first focus sweep, lambda/NA^2)",
        default_text="the virtual bench's with --simulate, else no pupil")
    focus_range_mm: float | None = option(None, gt=0, help="half-range of the first z sweep",
                                          unit="mm", default_text="from --relay-na")
    sim_translation_px: tuple[float, float] = option(
        (5.3, -3.6), help="--simulate: true mask offset", unit="mask px")
    sim_rotation_mrad: float = option(2.0, help="--simulate: true mask rotation", unit="mrad")
    sim_distortion_px: float = option(0.0, help="--simulate: quadratic distortion at the "
                                      "footprint edge", unit="mask px")
    sim_defocus_mm: float = option(0.08, help="--simulate: mask distance from the SLM image "
                                   "at stage z = 0", unit="mm")
    sim_tip_mrad: float = option(0.0, help="--simulate: mount rotation about x", unit="mrad")
    sim_tilt_mrad: float = option(0.0, help="--simulate: mount rotation about y", unit="mrad")

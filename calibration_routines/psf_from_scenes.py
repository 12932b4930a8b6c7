"""The PSF calibrated from known scenes, for a lab without a point source.

The convolution model is linear in the PSF once the scene is known
(:mod:`recon.analysis.psf_from_scenes`: non-negative least squares per colour
channel, with each pair's held-out residual). Two sources of pairs:

* files (:func:`psf_run_from_files`): scene images on the sensor grid and their
  measurements, matched by name, e.g. photographs shown on a monitor and captured by
  the lensless camera and, registered, by a lensed one. The scenes are on the model
  grid, as the bench's known scenes are: the scene rotated by 180 degrees (Kuo 2020
  Eq. 3.3, u = -m x; :data:`recon.io.DATA_ORIENTATION`), which a lensed camera's frame
  registered to the lensless one is; give them as registered, not turned upright
  (a reconstruction's PNG is turned upright, :func:`recon.io.scene_view`);
* the bench (:class:`PsfFromScenesPlan`): the display device (an SLM or monitor
  driven by :class:`drivers.slm.Slm`, e.g. the full-screen window of
  :class:`drivers.slm_window.FullscreenSlm`) at depth ``z_mm`` in front of the camera
  shows each scene at the panel's resolution, auto-exposed, then a black frame at the
  same exposure as its dark. The scenes are random binary patterns by default
  (:func:`random_pattern`: black and white blocks about one object-grid cell wide, a
  flat spectrum up to the sensor's sampling, and two gray levels only, so the
  monitor's gamma does not matter), or scikit-image's bundled photographs
  (:data:`recon.scenes.BUNDLED`, no download), whose ~1/f^2 spectrum leaves the
  PSF's finest detail under the noise. The known scene on the sensor grid is the
  displayed image inverted and scaled by the magnification ``d / z`` about the axis
  (:func:`recon.optics.lensless.plane_on_object_grid`), the display centred on the
  camera's axis; its radiance is taken as linear in the gray level (for photographs,
  set the monitor's gamma to 1, or calibrate it).

Both write a run holding ``psf_stack``: (1, rows, cols), or (1, rows, cols, channels)
with its ``channels`` recorded, at ``depths_mm = [z_mm]``, which ``recon --psf RUN``
and ``recon-run --psf RUN`` take (a dark-subtracted PSF: give the frames' dark level
with ``--dark``); the run's summary records each pair's held-out relative residual.
With two pairs or more the run also holds ``early_stop.json``
(:mod:`recon.analysis.early_stop`): the reconstruction recipe fitted on the pairs, each
reconstructed with the PSF estimated without it (on the bench with random patterns, on
photographs shown after them for the recipe alone, ``recipe_scenes``: a recipe is fitted
on scenes like those it will reconstruct, and the PSF from every pattern has not seen
them) (PSF threshold, iteration count of a
prior-free non-negative FISTA, TV denoising weight), tied to this PSF; ``recon --psf
RUN`` uses it by default (``--early-stop off`` declines it).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from instrument.acquisition.plan import (
    Capture,
    Expose,
    Plan,
    PlanError,
    PlanPoint,
    ShowSlm,
    register_plan,
)
from instrument.atomic import missing_dirs, remove_empty_dirs
from instrument.runs.coords import coord_specs
from instrument.runs.run_recipe import write_run_recipe
from instrument.runs.runstore import RunStore, discard_partial_run
from recon.analysis.early_stop import THRESHOLDS, fit_early_stop, fit_recipe, reference_db
from recon.analysis.psf_from_scenes import (
    ESTIMATE_ITERATIONS,
    PsfEstimate,
    check_pairs,
    estimate_psf_from_scenes,
    leave_one_out,
)
from recon.analysis.sensor_response import ROUNDS as SENSOR_ROUNDS
from recon.early_stop import FILE as EARLY_STOP_NAME
from recon.early_stop import EarlyStop
from recon.io import load_image
from recon.optics.lensless import plane_on_object_grid
from recon.scenes import BUNDLED, load_scene

from ._common import CALIBRATION_EXPOSURE, sensor_geometry, signal_minus_dark

__all__ = ["FILES_PLAN", "MAX_RANDOM", "PATTERNS", "RECIPE_IMAGES", "PsfFromScenesPlan",
           "display_gray", "match_pairs", "pattern_block_px", "psf_run_from_files",
           "random_pattern", "write_psf"]

#: The plan name of a run made from files (no frames; nothing to resume).
FILES_PLAN = "psf-from-scene-files"
#: Image files the file source reads.
SUFFIXES = (".npy", ".tif", ".tiff", ".png")
#: The reconstruction recipe's file in the run (:mod:`recon.analysis.early_stop`).
EARLY_STOP_FILE = EARLY_STOP_NAME
#: The kinds of scene the bench shows: generated random binary patterns, or photographs.
PATTERNS = ("random", "photographs")
#: Name of the random pattern of seed ``k``: ``RANDOM_PREFIX + str(k)``.
RANDOM_PREFIX = "random-"
#: The most random patterns a plan shows.
MAX_RANDOM = 256
#: Photographs shown after random patterns to fit the reconstruction recipe on.
RECIPE_IMAGES = 4


def random_pattern(seed: int, shape: tuple[int, int], block_px: int) -> np.ndarray:
    """Random binary pattern ``seed``: blocks of ``block_px`` display pixels, each black
    (0) or white (255) with probability 1/2.

    Parameters
    ----------
    seed : int
        >= 0; the same seed gives the same pattern.
    shape : (rows, cols)
        The display's resolution.
    block_px : int
        Side of the blocks, display pixels (>= 1; :func:`pattern_block_px`).

    Returns
    -------
    ndarray, uint8, ``shape``
    """
    rows, cols = shape
    rng = np.random.default_rng([int(seed), 0x5C])
    cells = rng.integers(0, 2, (-(-rows // block_px), -(-cols // block_px)), dtype=np.uint8)
    return (np.kron(cells, np.ones((block_px, block_px), np.uint8))[:rows, :cols] * 255
            ).astype(np.uint8)


def pattern_block_px(z_mm: float, d_mm: float, pitch_mm: float,
                     display_pitch_um: float) -> int:
    """Block side of the random patterns: one cell of the object grid (the sensor pitch
    scaled by ``z / d`` onto the display) in display pixels, rounded, at least 1.

    Finer blocks add detail within a cell, which the known scene (each cell's mean)
    does not hold; coarser ones leave the PSF's finest detail unmeasured.
    """
    return max(1, round(pitch_mm * z_mm / d_mm / (display_pitch_um * 1e-3)))


def display_gray(name: str, shape: tuple[int, int], block_px: int = 1) -> np.ndarray:
    """Scene ``name`` as the display shows it: uint8 gray, ``shape``.

    ``random-<k>`` is :func:`random_pattern` ``k`` with blocks of ``block_px`` display
    pixels; any other name is a bundled photograph (:data:`recon.scenes.BUNDLED`).
    """
    if name.startswith(RANDOM_PREFIX):
        return random_pattern(int(name[len(RANDOM_PREFIX):]), shape, block_px)
    return np.round(load_scene(name, shape) * 255.0).astype(np.uint8)


def _scene_name_ok(name: str) -> bool:
    tail = name[len(RANDOM_PREFIX):]
    return name in BUNDLED or (name.startswith(RANDOM_PREFIX) and tail.isdigit()
                               and str(int(tail)) == tail)


def write_psf(store: RunStore, estimate: PsfEstimate, held_out: np.ndarray | None,
              names: Sequence[str], z_mm: float, units: str,
              early_stop: EarlyStop | None = None, quality_db=None,
              quality_names: Sequence[str] | None = None, sensor_response=None) -> dict:
    """Write ``psf_stack`` and return the run's summary (module docstring).

    Parameters
    ----------
    store : RunStore
    estimate : PsfEstimate
        From every pair.
    held_out : ndarray (n_pairs, channels) or None
        Leave-one-out residuals (None for a single pair).
    names : sequence of str
        The pairs' names.
    z_mm : float
        Depth of the scenes, mm.
    units : str
        The PSF's unit.
    early_stop : EarlyStop, optional
        The reconstruction recipe fitted for this PSF
        (:func:`recon.analysis.early_stop.fit_recipe`): written as ``early_stop.json``
        in the run and summarised with its SHA-256 and held-out residual
        (:func:`instrument.runs.run_recipe.write_run_recipe`: not trusted as a default
        above :data:`recon.early_stop.TRUSTED_RESIDUAL`); the held-out figures are of
        the pairs binned as the recipe was fitted (``held_out_bin_factor``).

    quality_db : sequence of float, optional
        The PSF's quality figure: per held-out scene, the fixed reference
        reconstruction's gain-fitted error in dB (:func:`recon.analysis.early_stop.reference_db`,
        higher is better), recorded as ``held_out_reference_db`` and its mean.
    quality_names : sequence of str, optional
        The scenes of ``quality_db`` (default ``names``).
    sensor_response : ndarray, (n_rows, n_cols), optional
        The sensor response the PSF was estimated with
        (:mod:`recon.analysis.sensor_response`): recorded as ``sensor_response`` (its
        grid's shape, least and greatest gain).

    Returns
    -------
    dict
        JSON-able: per pair the training and held-out residuals, their mean, the method
        (and the early-stop count, the quality figure).
    """
    psf = estimate.psf
    attrs = {"depths_mm": [float(z_mm)], "units": units, "method": estimate.method,
             "pairs": list(names)}
    if psf.ndim == 3:
        attrs["channels"] = ["R", "G", "B"][:psf.shape[2]] if psf.shape[2] <= 3 else [
            f"c{c}" for c in range(psf.shape[2])]
    store.write_product("psf_stack", psf[None].astype(np.float32), **attrs)
    summary = {"z_mm": float(z_mm), "method": estimate.method,
               "fit_residual": {n: [round(float(v), 4) for v in estimate.residuals[k]]
                                for k, n in enumerate(names)}}
    if held_out is not None:
        summary["held_out_residual"] = {n: [round(float(v), 4) for v in held_out[k]]
                                        for k, n in enumerate(names)}
        summary["held_out_mean"] = round(float(np.mean(held_out)), 4)
    if quality_db is not None:
        summary["held_out_reference_db"] = {
            n: round(float(v), 2) for n, v in zip(quality_names or names, quality_db,
                                                  strict=True)}
        summary["held_out_reference_db_mean"] = round(float(np.mean(quality_db)), 2)
    if sensor_response is not None:  # a nuisance of the estimate: its extent recorded
        g = np.asarray(sensor_response)
        summary["sensor_response"] = {"grid_shape": list(g.shape),
                                      "min": round(float(g.min()), 3),
                                      "max": round(float(g.max()), 3)}
    if early_stop is not None:  # its SHA-256 and trust recorded (instrument.runs.run_recipe)
        if held_out is not None:
            summary["held_out_bin_factor"] = int(early_stop.fit_bin_factor)
        summary["early_stop"] = write_run_recipe(
            store, early_stop, None if held_out is None else float(np.mean(held_out)))
    return summary


def _calibrate(scenes, measurements, names, options, on_progress):
    """The PSF from every pair, each pair's PSF without it, the recipe and the quality
    figure, reporting ``on_progress(done, total, what)`` after each step."""
    n = len(scenes)
    # the recipe solves each pair twice per threshold: with its held-out PSF and with the
    # PSF from every pair (recon.analysis.early_stop.fit_recipe's in_sample)
    total = 1 + (SENSOR_ROUNDS + n + 2 * len(THRESHOLDS) * n if n > 1 else 0)
    done = 0

    def report(what):
        nonlocal done
        done += 1
        if on_progress is not None:
            on_progress(done, total, what)

    def psf_line(estimate):
        report(f"PSF from {n} pair(s): {estimate.iterations_run} iterations")

    if n == 1:
        estimate = estimate_psf_from_scenes(scenes, measurements, **options)
        psf_line(estimate)
        return estimate, None, None, None, None
    recipe = fit_recipe(scenes, measurements, names=names, on_psf=psf_line,  # beside the
                        on_estimate=lambda k: report(f"PSF without {names[k]}"),  # held-out
                        on_solve=lambda i, t: report(f"recipe: solve {i} of {t}"),
                        on_sensor=lambda r, _: report(
                            f"sensor response: round {r} of {SENSOR_ROUNDS}"), **options)
    return (recipe.estimate, recipe.held_out, recipe.fit, recipe.reference_db,
            recipe.sensor_response)


def _files(spec: Sequence[str], what: str) -> dict[str, Path]:
    """``{name: file}`` of the images a list of files or directories holds."""
    found: dict[str, Path] = {}
    for entry in spec:
        p = Path(entry)
        files = (sorted(f for f in p.iterdir() if f.suffix.lower() in SUFFIXES)
                 if p.is_dir() else [p])
        if p.is_dir() and not files:
            raise PlanError(f"{what} {p} holds no .npy, .tif or .png image; give the "
                            "directory of the images or the files themselves")
        for f in files:
            if not f.is_file():
                raise PlanError(f"{what} {f} does not exist; give existing images or "
                                "directories")
            if f.stem in found:
                raise PlanError(f"{what}: two images are named {f.stem!r} ({found[f.stem]} "
                                f"and {f}); scenes and measurements are matched by name")
            found[f.stem] = f
    return found


def match_pairs(scenes: Sequence[str], measurements: Sequence[str]
                ) -> list[tuple[str, Path, Path]]:
    """Scene and measurement files matched by name (the file name without suffix).

    Parameters
    ----------
    scenes, measurements : sequence of str
        Files, or directories of ``.npy``/``.tif``/``.png`` images.

    Returns
    -------
    list of (name, scene file, measurement file), sorted by name

    Raises
    ------
    PlanError
        A missing file, an empty directory, a name twice, or a name on one side only.
    """
    xs, bs = _files(scenes, "--scenes"), _files(measurements, "--measurements")
    alone = sorted(set(xs) ^ set(bs))
    if alone:
        raise PlanError(f"no {'measurement' if alone[0] in xs else 'scene'} named "
                        f"{alone[0]!r} ({len(alone)} name(s) on one side only: "
                        f"{', '.join(alone[:5])}); give each scene and its measurement the "
                        "same file name")
    return [(n, xs[n], bs[n]) for n in sorted(xs)]


def psf_run_from_files(scenes: Sequence[str], measurements: Sequence[str], out, *,
                       z_mm: float, note: str = "", overwrite: bool = False,
                       on_pair=None, on_progress=None, **options) -> RunStore:
    """Estimate the PSF from scene and measurement files and store it as a run.

    Parameters
    ----------
    scenes, measurements : sequence of str
        Files or directories (:func:`match_pairs`); the scenes on the sensor grid,
        the measurements dark-subtracted, each pair the same shape.
    out : str or Path
        The run store to create.
    z_mm : float
        Depth of the scenes in front of the diffuser, mm (> 0; recorded with the PSF).
    note : str
    overwrite : bool
    on_pair : callable, optional
        Called ``on_pair(name, fit_residuals, held_out_residuals)`` per pair (rows of
        channels; held-out None for a single pair).
    on_progress : callable, optional
        Called ``on_progress(done, total, what)`` after each step of the calibration
        (the PSF, each pair's held-out PSF, each of the recipe's solves), for progress
        lines.
    **options
        Of :func:`recon.analysis.psf_from_scenes.estimate_psf_from_scenes`.

    Returns
    -------
    RunStore
        Complete, with ``psf_stack``, the summary of :func:`write_psf` and, from two
        pairs, ``early_stop.json``.

    Raises
    ------
    PlanError
        Files that cannot be matched, or a depth that is not > 0.
    recon.errors.ReconInputError
        Unreadable images, or pairs the estimate refuses (shapes).
    instrument.runs.runstore.RunStoreError
        ``out`` exists (without ``overwrite``).
    """
    if not (np.isfinite(z_mm) and z_mm > 0):
        raise PlanError(f"--z-mm {z_mm}: give the scenes' distance from the diffuser, > 0 mm")
    pairs = match_pairs(scenes, measurements)
    names = [n for n, _, _ in pairs]
    xs = [load_image(x) for _, x, _ in pairs]
    bs = [load_image(b) for _, _, b in pairs]
    check_pairs(xs, bs)
    estimate, loo, early, quality, sensor = _calibrate(xs, bs, names, options, on_progress)
    held = None if loo is None else loo.residuals
    if on_pair is not None:
        for k, n in enumerate(names):
            on_pair(n, estimate.residuals[k], None if held is None else held[k])
    store, made = None, missing_dirs(out)
    try:  # whole or not at all: a run this call created is removed when it fails
        store = RunStore.create(
            out, plan_name=FILES_PLAN,
            plan_params={"scenes": [str(x) for _, x, _ in pairs],
                         "measurements": [str(b) for _, _, b in pairs], "z_mm": float(z_mm),
                         **{k: v for k, v in options.items() if v is not None}},
            points=[{"pair": n} for n in names], frame_tags=[[] for _ in names],
            frame_shape=xs[0].shape[:2], frame_dtype=np.float32,
            coord_names=["exposure_s"], coord_specs=coord_specs(["exposure_s"]), note=note,
            overwrite=overwrite, keep_lock=True)
        summary = write_psf(store, estimate, held, names, z_mm,
                            "measurement units per scene unit", early, quality,
                            sensor_response=sensor)
        store.update_attrs(status="complete", summary=summary)
        store.unlock()  # locked from its creation until written
    except BaseException:  # never a run another process created at ``out`` meanwhile
        if store is not None:
            discard_partial_run(out, made, token=store.creation_token)
        else:
            remove_empty_dirs(made)
        raise
    return store


@register_plan
class PsfFromScenesPlan(Plan):
    """Known scenes shown on the display device and the PSF they calibrate (module
    docstring).

    Parameters
    ----------
    scene_names : list of str
        Shown in order (at least 2): ``random-<k>`` (:func:`random_pattern` of seed
        ``k``, blocks of :func:`pattern_block_px`) or photographs of
        :data:`recon.scenes.BUNDLED`.
    z_mm : float
        Distance of the display from the diffuser, mm.
    display : str
        Device id or role of the display (an :class:`drivers.slm.Slm`).
    display_shape : (rows, cols)
        The display's resolution.
    display_pitch_um : float
        The display's pixel pitch, um.
    d_mm, pitch_mm : float
        Diffuser-sensor distance and sensor pitch, mm.
    frames_per_point : int
        Frames averaged per scene (and as many darks).
    iterations : int
        The most ADMM iterations of the estimate (it stops once converged).
    recipe_scenes : list of str
        Photographs of :data:`recon.scenes.BUNDLED` shown after ``scene_names`` for the
        reconstruction recipe alone (none, or at least 2): it is fitted on them with
        the PSF of every scene of ``scene_names``; without them, on ``scene_names``,
        each left out of the PSF it is reconstructed with.
    """

    name = "psf-from-scenes"

    def __init__(self, *, scene_names, z_mm: float, display: str = "slm", display_shape,
                 display_pitch_um: float, d_mm: float, pitch_mm: float,
                 frames_per_point: int = 4,
                 iterations: int = ESTIMATE_ITERATIONS,
                 recipe_scenes=()) -> None:
        names = [str(n) for n in scene_names]
        unknown = [n for n in names if not _scene_name_ok(n)]
        if len(names) < 2 or unknown:
            raise PlanError(f"scenes {names}: give at least 2, each random-<k> (k = 0, 1, "
                            f"...) or one of {', '.join(BUNDLED)}")
        recipe = [str(n) for n in recipe_scenes]
        if len(recipe) == 1 or any(n not in BUNDLED or n in names for n in recipe):
            raise PlanError(f"recipe scenes {recipe}: give none or at least 2 photographs of "
                            f"{', '.join(BUNDLED)} that the PSF's scenes do not include")
        if not (z_mm > 0 and display_pitch_um > 0 and frames_per_point >= 1):
            raise PlanError("z_mm and display_pitch_um must be > 0, frames_per_point >= 1")
        super().__init__(scene_names=names, z_mm=float(z_mm), display=str(display),
                         display_shape=[int(v) for v in display_shape],
                         display_pitch_um=float(display_pitch_um), d_mm=float(d_mm),
                         pitch_mm=float(pitch_mm), frames_per_point=int(frames_per_point),
                         iterations=int(iterations), recipe_scenes=recipe)

    @classmethod
    def for_bench(cls, bench, *, images: int = 12, z_mm: float, display: str = "slm",
                  patterns: str = "random", recipe_images: int | None = None,
                  **params) -> PsfFromScenesPlan:
        """``images`` scenes on the bench's ``display`` at ``z_mm``: random binary
        patterns ``random-0``, ``random-1``, ... (``patterns="random"``) or the first
        bundled photographs (``"photographs"``); then ``recipe_images`` photographs
        for the reconstruction recipe alone (default :data:`RECIPE_IMAGES` after
        random patterns, 0 after photographs: the recipe is then fitted on the
        photographs themselves, each left out of its PSF), the bundled ones the PSF's
        scenes do not include, in order.

        Raises
        ------
        PlanError
            Fewer than 2 images, more than :data:`MAX_RANDOM` patterns or the bundled
            photographs, another kind of pattern, 1 or more recipe images than the
            photographs left, or a display that is not an SLM/monitor of the bench.
        """
        if patterns not in PATTERNS:
            raise PlanError(f"--patterns {patterns!r}: give one of {', '.join(PATTERNS)}")
        most = MAX_RANDOM if patterns == "random" else len(BUNDLED)
        if isinstance(images, bool) or not isinstance(images, int) or not 2 <= images <= most:
            raise PlanError(f"--images {images!r}: give a whole number from 2 to {most} "
                            f"(--patterns {patterns})")
        try:
            panel = bench.device(display)
            shape, pitch = panel.resolution, panel.pixel_pitch_um
        except (KeyError, AttributeError, LookupError):
            raise PlanError(f"--display {display!r}: the bench has no display of that id or "
                            "role; give an SLM or monitor device of the bench file") from None
        d_mm, pitch_mm, _ = sensor_geometry(bench.config)
        params.setdefault("frames_per_point", bench.config.calibration.frames_per_point)
        names = ([f"{RANDOM_PREFIX}{k}" for k in range(images)] if patterns == "random"
                 else list(BUNDLED[:images]))
        left = [n for n in BUNDLED if n not in names]
        if recipe_images is None:
            recipe_images = RECIPE_IMAGES if patterns == "random" else 0
        if (isinstance(recipe_images, bool) or not isinstance(recipe_images, int)
                or recipe_images == 1 or not 0 <= recipe_images <= len(left)):
            raise PlanError(f"--recipe-images {recipe_images!r}: give 0 or a whole number "
                            f"from 2 to {len(left)} (the photographs the scenes leave)")
        return cls(scene_names=names, z_mm=z_mm, display=display,
                   display_shape=shape, display_pitch_um=pitch, d_mm=d_mm, pitch_mm=pitch_mm,
                   recipe_scenes=left[:recipe_images], **params)

    def points(self) -> list[PlanPoint]:
        n = self.params["frames_per_point"]
        return [PlanPoint({"scene": name}, ("scene",) * n + ("dark",) * n)
                for name in [*self.params["scene_names"], *self._recipe_scenes()]]

    def _recipe_scenes(self) -> list[str]:
        return list(self.params.get("recipe_scenes") or ())  # none in older runs

    def block_px(self) -> int:
        """Block side of this plan's random patterns, display pixels
        (:func:`pattern_block_px`)."""
        p = self.params
        return pattern_block_px(p["z_mm"], p["d_mm"], p["pitch_mm"], p["display_pitch_um"])

    def steps(self, index, point):
        p = self.params
        name = point.coords["scene"]
        gray = display_gray(name, tuple(p["display_shape"]), self.block_px())
        yield ShowSlm(gray=gray, label=name, device=p["display"])
        yield Expose(auto=CALIBRATION_EXPOSURE)
        yield Capture(p["frames_per_point"], "scene")
        yield ShowSlm(gray=np.zeros_like(gray), label="black", device=p["display"])
        yield Capture(p["frames_per_point"], "dark")

    def known_scene(self, name: str, sensor_shape: tuple[int, int]) -> np.ndarray:
        """Scene ``name`` as displayed, on the sensor grid (radiance 1 at gray 255)."""
        p = self.params
        gray = display_gray(name, tuple(p["display_shape"]), self.block_px()) / 255.0
        width_mm = p["display_shape"][1] * p["display_pitch_um"] * 1e-3
        return plane_on_object_grid(gray, p["z_mm"], width_mm, p["d_mm"],
                                    p["pitch_mm"] * 1e3, sensor_shape)

    def reduce(self, store) -> dict:
        """Estimate the PSF from the scenes and their dark-subtracted measurements
        (DN/s); write ``psf_stack`` and return the summary of :func:`write_psf`."""
        p = self.params
        names, recipe = p["scene_names"], self._recipe_scenes()
        every = [signal_minus_dark(store, i, "scene", "dark")[0].astype(np.float32)
                 for i in range(store.n_points)]
        shape = every[0].shape
        measurements, recipe_b = every[:len(names)], every[len(names):]
        scenes = [self.known_scene(n, shape).astype(np.float32) for n in names]
        if max(float(np.abs(b).max()) for b in measurements) == 0.0:
            raise PlanError("the displayed scenes left no signal on the camera; put the "
                            f"display ({p['display']}) in front of the camera, facing it")
        options = {"iterations": p["iterations"]}
        if recipe:  # photographs the PSF has not seen: its estimate is held out from them
            estimate = estimate_psf_from_scenes(scenes, measurements, **options)
            recipe_x = [self.known_scene(n, shape).astype(np.float32) for n in recipe]
            fit = fit_early_stop(recipe_x, recipe_b, [estimate.psf] * len(recipe),
                                 estimate.psf, names=recipe)
            quality = reference_db(recipe_x, recipe_b, [estimate.psf] * len(recipe), fit)
            loo = leave_one_out(scenes, measurements, **options)
        else:
            recipe_fit = fit_recipe(scenes, measurements, names=names, **options)
            estimate, fit = recipe_fit.estimate, recipe_fit.fit
            loo, quality = recipe_fit.held_out, recipe_fit.reference_db
            sensor = recipe_fit.sensor_response
        return write_psf(store, estimate, loo.residuals, names, p["z_mm"],
                         "DN/s per unit display radiance", fit, quality, recipe or names,
                         sensor_response=None if recipe else sensor)

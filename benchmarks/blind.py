"""Compressive calibration against centre-only and grid calibration (Kuo 2020, Fig. 5.4d).

On the virtual microscope (:func:`recon.optics.lensless.microscope_geometry`, every
image ray traced, Poisson and 5 e- read noise) each method gets the same number of
images ``N`` at the same exposure (a bead of the slide as bright as the
calibration bead):

* ``centre``: ``N`` images of one bead on the axis, averaged; the convolution model
  (one PSF everywhere);
* ``grid``: one bead at each of ``N`` positions on a ``sqrt(N) x sqrt(N)`` grid over
  the field, registered (Eq. 5.2); the local convolution model (bilinear weights);
* ``blind``: ``N`` images of a slide of ``beads`` beads at unknown positions;
  :func:`recon.spatial.blind_calibration` recovers ``K > N`` PSFs (``nodes x
  nodes``), started from the aligned images' mean (Sec. 5.4);
* ``blind+centre``: the same with one of the ``N`` images spent on the axial bead,
  whose PSF starts every node (``N - 1`` slide images), rank at most
  ``guided_rank`` (2);
* ``oracle``: the noise-free ray-traced PSFs at the ``K`` nodes (the local model's
  ceiling).

Accuracy: the normalised inner product of each model's image of a point (its
nodes' bilinear mix, Eq. 5.3-5.5, cropped to the sensor) with the ray-traced image
of that point, on a ``5 x 5`` raster over the field; and the PSNR (one
least-squares gain) of a dense off-axis scene (cells in one quadrant) rendered by
the finer 8 x 8-patch model of :meth:`~recon.optics.lensless.LenslessModel.render`
on a 2x grid, reconstructed with each model by l1 FISTA
(:func:`recon.spatial.fista_background`, no background). Blind deconvolution
leaves a translation free (beads at unknown positions); it is removed by one global
shift that registers the recovered central PSF to the true one (the other methods
know where their beads were).

The grid calibration keeps PsfGrid's sensor-sized registered PSFs: registering an
off-axis PSF by its shift drops the light that moves past the array's edge, so on
this microscope (PSFs over the whole sensor) a grid PSF does not reproduce even
its own measurement exactly (part of why it trails the centre-only model here).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from instrument.benchmarks import format_table, save_figure, write_json
from recon.errors import ReconInputError

__all__ = ["blind_calibration_table", "plot_blind_calibration", "run_blind_calibration"]

log = logging.getLogger(__name__)

#: Sizes: sensor (rows, cols) and pitch (um), images N, blind nodes a side, beads
#: per slide image, blind rounds, FISTA iterations (blind steps, scene).
#: N is an odd square so that the grid calibration has a node on the axis.
PRESETS = {
    "tiny": dict(sensor=(34, 60), pitch_um=92.8, n_images=9, nodes=3, beads=4, rounds=2,
                 blind_iterations=20, scene_iterations=40),
    "quick": dict(sensor=(34, 60), pitch_um=92.8, n_images=9, nodes=5, beads=20, rounds=4,
                  blind_iterations=100, scene_iterations=200),
    "full": dict(sensor=(68, 120), pitch_um=46.4, n_images=9, nodes=5, beads=20, rounds=6,
                 blind_iterations=100, scene_iterations=300),
}

METHODS = ("centre", "grid", "blind", "blind+centre", "oracle")


def _noisy(clean, exposure, rng):
    """Poisson photo-electrons and 5 e- read noise, back in irradiance units."""
    return (rng.poisson(clean * exposure) + rng.normal(0, 5.0, clean.shape)) / exposure


def _point_images(op, offsets_px):
    """The model's sensor image of a unit point at each object-grid offset (whole px)."""
    out = []
    for dr, dc in offsets_px:
        e = np.zeros(op.shape_in, np.float32)
        e[op.shape_in[0] // 2 + dr, op.shape_in[1] // 2 + dc] = 1.0
        out.append(op.forward(e))
    return out


def _inner(a, b):
    return float(np.vdot(a, b) / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-30))


def _anchor(grid, true_central):
    """The grid translated so its central PSF registers to the true one."""
    from scipy.ndimage import shift

    from recon.analysis import register_shift
    from recon.spatial import PsfGrid

    s = np.asarray(register_shift(true_central, grid.psfs[grid.central]))
    psfs = np.maximum(np.stack([shift(h, -s, order=1) for h in grid.psfs]), 0)
    psfs = np.where(np.any(psfs > 0, axis=(1, 2))[:, None, None], psfs, 1e-12)
    return PsfGrid(psfs, grid.shifts_px, grid.grid_shape, grid.z_mm, grid.d_mm), s


def _scene(rng, shape, quadrant_px):
    """Cells (Gaussian blobs, sigma 0.8 px) filling an off-axis window of the grid."""
    (r0, r1), (c0, c1) = quadrant_px
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    out = np.zeros(shape)
    for _ in range(max(8, (r1 - r0) * (c1 - c0) // 12)):
        r, c = rng.uniform(r0, r1), rng.uniform(c0, c1)
        out += rng.uniform(0.3, 1.0) * np.exp(-((yy - r) ** 2 + (xx - c) ** 2) / (2 * 0.8**2))
    return out


def run_blind_calibration(quick: bool, out: Path, *, preset: str | None = None,
                          seed: int = 0, **overrides) -> dict:
    """Fig. 5.4d on the virtual microscope (module docstring).

    Parameters
    ----------
    quick : bool
        The ``quick`` preset (a 34 x 60 sensor) instead of ``full`` (68 x 120); both
        N = 9 images and 5 x 5 blind nodes, as in Fig. 5.4.
    out : Path
        Writes ``blind_calibration.json`` and ``blind_calibration.png``.
    preset : {"tiny", "quick", "full"}, optional
        Overrides ``quick`` (``tiny``: a 34 x 60 sensor for tests).
    seed : int
    **overrides
        Entries of the preset to replace (``beads=20``, ``rounds=8``,
        ``psf_iterations=25``, ``guided_rank=3``, ...).

    Returns
    -------
    dict
        ``methods``: per method its images, PSFs, inner products over the field
        (``inner`` list, ``inner_mean``, ``inner_min``, ``inner_off_axis``), scene
        ``psnr_db``, seconds; ``setup``; ``images`` (truth and reconstructions of the
        scene window, for the figure).

    Raises
    ------
    ReconInputError
        A preset whose image count is not an odd square or whose node count is even.
    """
    from recon.analysis import lateral_calibration_spacing_mm
    from recon.optics.lensless import LenslessModel, microscope_geometry
    from recon.scenes import cell_overlap
    from recon.spatial import (
        PsfGrid,
        blind_calibration,
        build_operator,
        fista_background,
        local_convolution_operator,
    )

    p = {"psf_iterations": None, "guided_rank": 2, **PRESETS[preset or ("quick" if quick
                                                                         else "full")]}
    unknown = set(overrides) - set(p)
    if unknown:
        raise ReconInputError(f"unknown settings {sorted(unknown)}; use {sorted(p)}")
    p.update(overrides)
    rng = np.random.default_rng(seed)
    geo = microscope_geometry(seed=0, sensor_shape=p["sensor"], sensor_pitch_um=p["pitch_um"])
    model = LenslessModel(geo)
    z = 2.4
    m, pitch = geo.d_mm / z, geo.sensor_pitch_um * 1e-3
    half = lateral_calibration_spacing_mm(geo.falloff_sigma_deg, z)  # field +-half, mm
    n_img, nodes = p["n_images"], p["nodes"]
    side = int(round(np.sqrt(n_img)))
    if side * side != n_img or side % 2 == 0 or nodes % 2 == 0:
        raise ReconInputError(f"n_images {n_img} and nodes {nodes}: give an odd square number "
                              "of images and an odd number of nodes (a node on the axis)")

    def shift_px(x, y):
        return (-y * m / pitch, -x * m / pitch)

    # truth: ray-traced sensor images of points on a 5 x 5 raster over the field (at
    # whole object-grid pixels)
    ev = np.round(np.linspace(-half, half, 5) * m / pitch).astype(int)
    ev_px = [(int(r), int(c)) for r in ev for c in ev]
    ev_xy = [(-c * pitch / m, -r * pitch / m) for r, c in ev_px]
    truth = np.stack([model.psf((x, y, z)) for x, y in ev_xy])
    central_truth = truth[12]
    exposure = 1000.0 / central_truth.max()  # 1000 e- at the axial PSF's peak

    def psf_images(xy):
        return [_noisy(model.psf((x, y, z)), exposure, rng) for x, y in xy]

    grids, seconds = {}, {}
    t0 = time.perf_counter()
    centre = np.mean(psf_images([(0.0, 0.0)] * n_img), axis=0)
    grids["centre"] = PsfGrid(np.maximum(centre, 0)[None], [(0.0, 0.0)], (1, 1), z, geo.d_mm)
    seconds["centre"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    g = ((np.arange(side) + 0.5) / side * 2 - 1) * half  # cell centres of the field
    gxy = [(x, y) for y in g for x in g]
    grids["grid"] = PsfGrid.from_positions(np.maximum(psf_images(gxy), 0), gxy, z_mm=z,
                                           d_mm=geo.d_mm)  # registered to the axial node
    seconds["grid"] = time.perf_counter() - t0
    slides = []
    for _ in range(n_img):
        xy = rng.uniform(-1.1, 1.1, (p["beads"], 2)) * half
        pts = np.column_stack([xy, np.full(len(xy), z)])
        slides.append(_noisy(model.render_points(pts, np.ones(len(xy))), exposure, rng))
    slides = np.stack(slides)
    spacing = 2 * half / (nodes - 1) * m / pitch
    common = dict(object_iterations=p["blind_iterations"],
                  psf_iterations=p["psf_iterations"] or p["blind_iterations"], z_mm=z,
                  d_mm=geo.d_mm)
    t0 = time.perf_counter()
    blind = blind_calibration(slides, (nodes, nodes), spacing, rounds=p["rounds"], **common)
    grids["blind"] = blind.grid
    seconds["blind"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    start = np.maximum(psf_images([(0.0, 0.0)])[0], 0)
    guided = blind_calibration(slides[: n_img - 1], (nodes, nodes), spacing,
                               rounds=p["rounds"], initial_psf=start, max_rank=p["guided_rank"],
                               **common)
    grids["blind+centre"] = guided.grid
    seconds["blind+centre"] = time.perf_counter() - t0
    node = np.linspace(-half, half, nodes)
    nxy = [(x, y) for y in node for x in node]
    grids["oracle"] = PsfGrid(np.stack([model.psf((x, y, z), registered=True) for x, y in nxy]),
                              [shift_px(x, y) for x, y in nxy], (nodes, nodes), z, geo.d_mm)

    # the off-axis scene: cells in the quadrant x, y in [0.3, 1] half (object grid px)
    probe = local_convolution_operator(grids["oracle"])
    P0, P1 = probe.padded_shape
    q = pitch / m
    pos_y = -(np.arange(P0) - P0 // 2) * q
    pos_x = -(np.arange(P1) - P1 // 2) * q
    fov = 2.4 * half
    n_s = 96
    edges = np.linspace(-fov / 2, fov / 2, n_s + 1)
    lo, hi = int(n_s * (0.5 + 0.3 / 2.4)), int(n_s * (0.5 + 1.0 / 2.4))
    scene = _scene(rng, (n_s, n_s), ((lo, hi), (lo, hi)))
    truth_obj = cell_overlap(edges, pos_y, q) @ scene @ cell_overlap(edges, pos_x, q).T
    clean = model.render(scene, z, (fov, fov), oversample=2, patches=8)
    b = _noisy(clean, 4000.0 / clean.max(), rng)
    b = (b / b.max()).astype(np.float32)
    win = np.nonzero(truth_obj > 0.02 * truth_obj.max())
    box = (slice(win[0].min() - 2, win[0].max() + 3), slice(win[1].min() - 2, win[1].max() + 3))
    t_crop = truth_obj[box]
    results, images = {}, {"truth": t_crop.tolist()}
    off_axis = [i for i, (x, y) in enumerate(ev_xy) if np.hypot(x, y) > 0.7 * half]
    for name in METHODS:
        grid, s = (_anchor(grids[name], central_truth) if name.startswith("blind")
                   else (grids[name], np.zeros(2)))
        op = build_operator(grid, "convolution" if grid.n == 1 else "local")
        inner = [_inner(a, t) for a, t in zip(_point_images(op, ev_px), truth, strict=True)]
        x = fista_background(op, b, iterations=p["scene_iterations"], l1=1e-4,
                             estimate_background=False).x
        if x.shape != (P0, P1):
            raise AssertionError(f"object grid {x.shape} is not the scene's {(P0, P1)}")
        est = x[box].astype(np.float64)
        gain = float(np.vdot(est, t_crop) / max(np.vdot(est, est), 1e-30))
        mse = float(np.mean((gain * est - t_crop) ** 2))
        results[name] = {
            "images": 0 if name == "oracle" else n_img, "psfs": int(grid.n),
            "inner": inner, "inner_mean": float(np.mean(inner)), "inner_min": float(np.min(inner)),
            "inner_off_axis": float(np.mean([inner[i] for i in off_axis])),
            "psnr_db": float(10 * np.log10(t_crop.max() ** 2 / max(mse, 1e-30))),
            "global_shift_px": s.tolist(), "calibration_seconds": seconds.get(name)}
        images[name] = (gain * est).tolist()
        log.info("blind calibration %s: inner %.2f, %.2f dB", name, results[name]["inner_mean"],
                 results[name]["psnr_db"])
    result = {"setup": {**p, "z_mm": z, "field_half_mm": half, "exposure_peak_e": 1000,
                        "scene_peak_e": 4000, "eval_positions_mm": ev_xy,
                        "blind_history": blind.history, "guided_history": guided.history},
              "methods": results, "images": images, "quick": quick}
    write_json(Path(out) / "blind_calibration.json", result)
    plot_blind_calibration(result, Path(out) / "blind_calibration.png")
    return result


def blind_calibration_table(result: dict) -> str:
    """Text table of :func:`run_blind_calibration`."""
    rows = [[name, r["images"], r["psfs"], f"{r['inner_mean']:.2f}", f"{r['inner_min']:.2f}",
             f"{r['inner_off_axis']:.2f}", f"{r['psnr_db']:.2f}"]
            for name, r in result["methods"].items()]
    s = result["setup"]
    return (format_table(["method", "images", "PSFs", "inner mean", "inner min",
                          "inner off-axis", "scene PSNR dB"], rows)
            + f"\n(virtual microscope {s['sensor'][0]}x{s['sensor'][1]} at {s['pitch_um']} um, "
            f"z {s['z_mm']} mm, field +-{s['field_half_mm']:.2f} mm, {s['beads']} beads per "
            "slide image)")


def plot_blind_calibration(result: dict, path: Path) -> Path:
    """Inner products over the field, scene PSNR and the reconstructions (Fig. 5.4d)."""
    from matplotlib.figure import Figure

    methods = result["methods"]
    fig = Figure(figsize=(11, 6.2))
    axes = fig.subplots(2, 4)
    ax = axes[0, 0]
    r = np.hypot(*np.asarray(result["setup"]["eval_positions_mm"]).T)
    for i, (name, m) in enumerate(methods.items()):
        ax.plot(r + 0.01 * (i - 2), m["inner"], "o", ms=4, label=name)
    ax.set_xlabel("field radius, mm")
    ax.set_ylabel("inner product with true PSF")
    ax.set_ylim(0, 1.02)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    ax = axes[0, 1]
    ax.bar(range(len(methods)), [m["psnr_db"] for m in methods.values()],
           color=[f"C{i}" for i in range(len(methods))])
    ax.set_xticks(range(len(methods)), list(methods), rotation=30, fontsize=7)
    ax.set_ylabel("off-axis scene PSNR, dB")
    lo = min(m["psnr_db"] for m in methods.values())
    ax.set_ylim(max(lo - 3, 0), max(m["psnr_db"] for m in methods.values()) + 1)
    panels = ["truth", *methods]
    for ax, name in zip(list(axes[0, 2:]) + list(axes[1]), panels, strict=False):
        img = np.asarray(result["images"][name])
        ax.imshow(img, cmap="gray", vmin=0, vmax=float(np.max(result["images"]["truth"])))
        title = name if name == "truth" else f"{name}: {methods[name]['psnr_db']:.1f} dB"
        ax.set_title(title, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    s = result["setup"]
    fig.suptitle(f"Compressive calibration (Fig. 5.4d) on the virtual microscope: N = "
                 f"{s['n_images']} images each, blind {s['nodes']}x{s['nodes']} PSFs from "
                 f"{s['beads']}-bead slides", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)

"""Benchmarks of the spatially varying models (Kuo 2020, Ch. 5-6).

``spatial_speed`` (:func:`run_spatial_speed`): seconds per data-term apply (forward
+ adjoint, what one FISTA iteration costs) of the local convolution model with a
5 x 5 grid against the FFT floor of its K convolutions
(:func:`recon.volume.fft_floor_seconds`: K + 1 rfft2/irfft2 pairs at the padded
shape, measured in the same run, goal 1.5x), PCA with k components against it, and
the memory of a 1080 x 1920 sensor with a 5 x 5 grid and 10 depths
(:func:`recon.spatial.spatial_memory_bytes`, checked against a built operator's
:meth:`~recon.spatial.SpatialConvolutionOperator.memory_bytes`).

``spatial_accuracy`` (:func:`run_spatial_accuracy`): the virtual microscope
(:func:`recon.optics.lensless.microscope_geometry`): beads at one depth over the
field, each ray traced (the exact, fully spatially varying image; no model), on an
oversampled grid, a smooth background, Poisson and read noise; calibration PSFs
ray traced on a grid at the Eq. 5.9 spacing and registered by cross-correlation.
Every model (convolution with the central PSF, PCA with k = 1, 2, 4, ..., local)
reconstructs with the background-estimating FISTA of Eq. 6.2; PSNR (gain-fitted,
both images blurred by a 1-pixel Gaussian so a sub-pixel bead position is not
scored as a miss) over the whole field, near the axis and off-axis, against
seconds per iteration; and the model :func:`recon.spatial.choose_model` picks with
its predicted errors.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from instrument.benchmarks import fmt, format_table, log_x_axis, save_figure, write_json

__all__ = ["plot_spatial_panel", "run_spatial_accuracy", "run_spatial_speed",
           "spatial_accuracy_table", "spatial_speed_table"]

log = logging.getLogger(__name__)

#: Speed goal: seconds per apply over the FFT floor of the model's K convolutions.
GOAL = 1.5


def _median_seconds(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _synthetic_grid(shape, n, seed=0):
    from recon.spatial import PsfGrid

    rng = np.random.default_rng(seed)
    base = (rng.random(shape) > 0.995).astype(np.float32)
    step = (shape[0] / (n + 1), shape[1] / (n + 1))
    shifts = [((a - (n - 1) / 2) * step[0], (b - (n - 1) / 2) * step[1])
              for a in range(n) for b in range(n)]
    psfs = np.stack([base * (0.5 + rng.random(shape, dtype=np.float32)) for _ in shifts])
    return PsfGrid(psfs, shifts, (n, n))


def run_spatial_speed(quick: bool, out: Path) -> dict:
    """Speed of the local and PCA models against the FFT floor, and memory.

    Returns
    -------
    dict
        ``sizes``: per sensor shape the floor, the local model's ratio and the PCA
        models' seconds relative to the local model; ``memory``: estimates for
        1080 x 1920, 5 x 5 grid, 10 depths; ``estimate_check``: estimate against a
        built operator.
    """
    from recon.spatial import local_convolution_operator, pca_operator, spatial_memory_bytes
    from recon.volume import fft_floor_seconds

    shapes = [(96, 128)] if quick else [(270, 480), (540, 960)]
    repeats = 3 if quick else 7
    sizes = []
    for shape in shapes:
        grid = _synthetic_grid(shape, 5)
        local = local_convolution_operator(grid)
        rng = np.random.default_rng(1)
        x = rng.random(local.shape_in, dtype=np.float32)
        b = rng.random(local.shape_out, dtype=np.float32)
        floor_before = fft_floor_seconds(local.padded_shape, local.n_kernels, repeats=repeats)
        t_local = _median_seconds(lambda op=local, x=x, b=b: op.data_term(x, b), repeats)
        floor_after = fft_floor_seconds(local.padded_shape, local.n_kernels, repeats=repeats)
        floor = float(np.median([floor_before, floor_after]))
        entry = {"shape": list(shape), "padded_shape": list(local.padded_shape),
                 "kernels": local.n_kernels, "fft_floor_seconds": floor,
                 "local_seconds": t_local, "local_ratio": t_local / floor,
                 "meets_goal": t_local / floor <= GOAL, "pca": {}}
        for k in (1, 3, 5, 10):
            op = pca_operator(grid, k=k)
            t = _median_seconds(lambda op=op, x=x, b=b: op.data_term(x, b), repeats)
            kfloor = fft_floor_seconds(op.padded_shape, op.n_kernels, repeats=repeats)
            entry["pca"][str(k)] = {"seconds": t, "ratio_to_own_floor": t / kfloor,
                                    "fraction_of_local": t / t_local}
        sizes.append(entry)
        log.info("spatial speed %s: local %.2fx floor", shape, t_local / floor)
    memory = {"local_5x5_10_depths": spatial_memory_bytes((1080, 1920), 250, n_z=10),
              "pca_k3_10_depths": spatial_memory_bytes((1080, 1920), 30, n_z=10),
              "local_5x5_10_depths_binned_2": spatial_memory_bytes((540, 960), 250, n_z=10)}
    grid = _synthetic_grid(shapes[0], 5)
    built = local_convolution_operator(grid)
    est = spatial_memory_bytes(shapes[0], built.n_kernels, volumes=0)
    check = {"shape": list(shapes[0]), "estimate_operator_bytes": est["total"],
             "built_operator_bytes": built.memory_bytes()}
    result = {"goal": GOAL, "sizes": sizes, "memory": memory, "estimate_check": check,
              "quick": quick}
    write_json(Path(out) / "spatial_speed.json", result)
    return result


def spatial_speed_table(result: dict) -> str:
    """Text table of :func:`run_spatial_speed`."""
    rows = []
    for s in result["sizes"]:
        rows.append([f"{s['shape'][0]}x{s['shape'][1]}", s["kernels"],
                     f"{s['fft_floor_seconds'] * 1e3:.1f}", f"{s['local_seconds'] * 1e3:.1f}",
                     f"{s['local_ratio']:.2f}" + (" ok" if s["meets_goal"] else " MISSED"),
                     ", ".join(f"k={k}: {v['fraction_of_local']:.2f}"
                               for k, v in s["pca"].items())])
    text = format_table(["sensor", "K", "floor ms", "local ms", f"local/floor (goal {GOAL})",
                         "PCA seconds / local"], rows)
    mem = result["memory"]
    text += "\nmemory, 1080x1920, 5x5 grid, 10 depths: " + ", ".join(
        f"{k} {v['total'] / 2**30:.1f} GiB (spectra {v['kernel_spectra'] / 2**30:.1f})"
        for k, v in mem.items())
    c = result["estimate_check"]
    text += (f"\nestimate check {c['shape']}: estimated {c['estimate_operator_bytes'] / 2**20:.1f}"
             f" MiB, built {c['built_operator_bytes'] / 2**20:.1f} MiB")
    return text


# ----------------------------------------------------------------------------- accuracy
def _beads(rng, n, half_fov_mm, z):
    xy = rng.uniform(-1, 1, (n, 2)) * half_fov_mm
    return np.column_stack([xy, np.full(n, z)])


def _truth_image(beads, powers, geo, padded, crop):
    """Bead powers splatted bilinearly on the object grid (u = -m x, Eq. 3.3)."""
    out = np.zeros(padded)
    pitch = geo.sensor_pitch_um * 1e-3
    for (x, y, z), p in zip(beads, powers, strict=True):
        m = geo.d_mm / z
        r = padded[0] // 2 - y * m / pitch
        c = padded[1] // 2 - x * m / pitch
        r0, c0 = int(np.floor(r)), int(np.floor(c))
        fr, fc = r - r0, c - c0
        for dr, dc, w in ((0, 0, (1 - fr) * (1 - fc)), (1, 0, fr * (1 - fc)),
                          (0, 1, (1 - fr) * fc), (1, 1, fr * fc)):
            out[r0 + dr, c0 + dc] += p * w
    return out[crop]


def _scores(est, truth, bead_px, bead_region):
    """PSNR over the field and per-region SNR after a 1-px Gaussian blur and one
    least-squares gain, plus each bead's mass error (5 x 5 window)."""
    from scipy.ndimage import gaussian_filter

    e, t = gaussian_filter(est.astype(np.float64), 1.0), gaussian_filter(truth, 1.0)
    gain = float(np.vdot(e, t) / max(np.vdot(e, e), 1e-30))
    err = (gain * e - t) ** 2
    out = {"psnr_db": float(10 * np.log10(t.max() ** 2 / max(err.mean(), 1e-30)))}
    mass_err = []
    near = np.zeros(t.shape, bool)
    far = np.zeros(t.shape, bool)
    for (r, c), region in zip(bead_px, bead_region, strict=True):
        win = (slice(max(int(round(r)) - 2, 0), int(round(r)) + 3),
               slice(max(int(round(c)) - 2, 0), int(round(c)) + 3))
        true_mass = float(truth[win].sum())
        mass_err.append(abs(gain * float(est[win].sum()) - true_mass) / max(true_mass, 1e-30))
        (near if region == "axis" else far if region == "off_axis" else np.zeros_like(near)
         )[win] = True
    mass_err = np.array(mass_err)
    regions = np.array(bead_region)
    for key, mask in (("axis", near), ("off_axis", far)):
        out[f"snr_{key}_db"] = float(10 * np.log10(np.sum(t[mask] ** 2)
                                                   / max(np.sum(err[mask]), 1e-30)))
        out[f"mass_error_{key}"] = float(np.median(mass_err[regions == key]))
    return out


def run_spatial_accuracy(quick: bool, out: Path) -> dict:
    """PSNR against seconds of every model on the virtual microscope (module docstring).

    Returns
    -------
    dict
        ``models``: per model label its PSNR (all / axis / off-axis), seconds per
        iteration and convolutions; ``choice``: what :func:`choose_model` picks;
        ``setup``: the numbers of the simulation.
    """
    from recon.analysis import lateral_calibration_spacing_mm
    from recon.optics.lensless import LenslessModel, microscope_geometry
    from recon.spatial import PsfGrid, build_operator, choose_model, fista_background

    z = 2.4
    n_grid = 3 if quick else 5
    n_beads = 12 if quick else 40
    iterations = 60 if quick else 300
    geo = microscope_geometry(seed=0, sensor_shape=(68, 120) if quick else (135, 240),
                              sensor_pitch_um=46.4 if quick else 23.2)
    model = LenslessModel(geo)
    spacing = lateral_calibration_spacing_mm(geo.falloff_sigma_deg, z)
    off = (np.arange(n_grid) - (n_grid - 1) / 2) * spacing
    positions = [(x, y) for y in off for x in off]
    t0 = time.perf_counter()
    psfs = np.stack([model.psf((x, y, z)) for x, y in positions])
    grid = PsfGrid.from_positions(psfs, positions, z_mm=z, d_mm=geo.d_mm)
    calib_s = time.perf_counter() - t0
    rng = np.random.default_rng(7)
    half = spacing * (n_grid - 1) / 2
    beads = _beads(rng, n_beads, half, z)
    powers = rng.uniform(0.5, 1.0, n_beads) * 1e9
    clean = model.render_points(beads, powers, oversample=2)  # finer grid than the model
    glow = np.outer(np.linspace(0.6, 1.0, clean.shape[0]), np.linspace(1.0, 0.7, clean.shape[1]))
    background = 0.5 * clean.max() * glow
    exposure = 4000.0 / clean.max()  # 4000 photo-electrons at the brightest pixel
    noisy = _noisy(clean + background, exposure, rng)
    scale = float(noisy.max())
    b = (noisy / scale).astype(np.float32)
    labels = ["convolution", *[f"pca:{k}" for k in (1, 2, 4, 8, 16) if k < grid.n], "local"]
    models = {}
    pitch = geo.sensor_pitch_um * 1e-3
    r_mm = np.hypot(beads[:, 0], beads[:, 1])
    region = np.where(r_mm < 0.35 * half, "axis", np.where(r_mm > 0.7 * half, "off_axis",
                                                              "between"))
    fista_background(build_operator(grid, "convolution"), b, iterations=2)  # warm-up (JIT)
    for label in labels:
        name, _, k = label.partition(":")
        op = build_operator(grid, name, k=int(k) if k else None)
        truth = _truth_image(beads, powers, geo, op.padded_shape, op.crop)
        centre = (op.padded_shape[0] // 2 - op.offset[0], op.padded_shape[1] // 2 - op.offset[1])
        bead_px = [(centre[0] - y * geo.d_mm / z / pitch, centre[1] - x * geo.d_mm / z / pitch)
                   for x, y, _ in beads]
        res = fista_background(op, b, iterations=iterations, l1=1e-3)
        per_it = float(np.median(res.history.seconds))
        models[label] = {**_scores(res.x[op.crop], truth, bead_px, region),
                         "seconds_per_iteration": per_it,
                         "seconds_total": float(np.sum(res.history.seconds)),
                         "convolutions": int(op.n_kernels)}
        log.info("spatial accuracy %s: %.2f dB", label, models[label]["psnr_db"])
    choice = choose_model(grid)
    result = {"setup": {"z_mm": z, "grid": [n_grid, n_grid], "spacing_mm": spacing,
                        "beads": n_beads, "iterations": iterations,
                        "sensor_shape": list(geo.sensor_shape),
                        "pitch_um": geo.sensor_pitch_um, "calibration_seconds": calib_s,
                        "axis_radius_mm": 0.35 * half, "off_axis_radius_mm": 0.7 * half,
                        "beads_axis": int(np.sum(region == "axis")),
                        "beads_off_axis": int(np.sum(region == "off_axis")),
                        "background_over_peak": 0.5, "peak_photoelectrons": 4000},
              "models": models, "choice": choice.as_dict(), "quick": quick}
    write_json(Path(out) / "spatial_accuracy.json", result)
    plot_spatial(result, Path(out) / "spatial_psnr_vs_seconds.png")
    return result


def _noisy(irradiance, exposure, rng):
    """Poisson photo-electrons and 5 e- read noise, back in irradiance units."""
    electrons = rng.poisson(irradiance * exposure) + rng.normal(0, 5.0, irradiance.shape)
    return electrons / exposure


def spatial_accuracy_table(result: dict) -> str:
    """Text table of :func:`run_spatial_accuracy`."""
    rows = [[label, m["convolutions"], fmt(m["psnr_db"]), fmt(m["snr_axis_db"]),
             fmt(m["snr_off_axis_db"]), f"{100 * m['mass_error_axis']:.1f}",
             f"{100 * m['mass_error_off_axis']:.1f}", f"{m['seconds_per_iteration'] * 1e3:.1f}"]
            for label, m in result["models"].items()]
    c = result["choice"]
    return (format_table(["model", "convs", "PSNR dB", "SNR axis", "SNR off-axis",
                          "mass err axis %", "off-axis %", "ms/it"], rows)
            + f"\nauto choice: {c['label']} ({c['reason']})")


def plot_spatial_panel(ax, result: dict) -> None:
    """PSNR over the field (left axis) and SNR near the off-axis beads (right axis)
    against seconds per iteration, one point per model and k (a panel of the
    speed-vs-accuracy chart)."""
    models = result["models"]
    xs = [m["seconds_per_iteration"] for m in models.values()]
    ax.plot(xs, [m["psnr_db"] for m in models.values()], "o", ms=6, color="C0")
    for label, x, m in zip(models, xs, models.values(), strict=True):
        ax.annotate(label, (x, m["psnr_db"]), fontsize=7, xytext=(3, 3),
                    textcoords="offset points")
    log_x_axis(ax)
    ax.set_xlabel("seconds per iteration (Eq. 6.2 FISTA)")
    ax.set_ylabel("PSNR, whole field (dB, o)", color="C0")
    ax.grid(True, which="both", alpha=0.3)
    right = ax.twinx()
    right.plot(xs, [m["snr_off_axis_db"] for m in models.values()], "s", ms=5, color="C1")
    right.set_ylabel("SNR at the off-axis beads (dB, squares)", color="C1")
    ax.set_title("virtual microscope: forward models")


def plot_spatial(result: dict, path: Path) -> Path:
    """:func:`plot_spatial_panel` alone as a PNG."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.5, 4.0))
    plot_spatial_panel(fig.subplots(), result)
    fig.tight_layout()
    return save_figure(fig, path)

"""3D accuracy: bead localisation and tilted-target PSNR/SSIM against iterations and seconds.

Run with ``diffuserlab benchmark recon --only volume_accuracy [--quick] [--out DIR]``.

On the virtual bench's diffuser (:mod:`benchmarks.volume_scenes`: ray-traced,
spatially varying rendering on a finer grid with camera noise; reconstruction from
noisy on-axis calibration PSFs at the planes, so never the inverse crime), two scenes
are reconstructed with 3D FISTA and 3D ADMM (Eq. 4.4-4.5, App. A.1/A.3):

* beads at random 3D positions: detected as local maxima of the volume's 3 x 3 x 3
  local mass (:func:`recon.volume.localize.detect_peaks` with ``local_mass``, so a
  bead split between planes and pixels counts whole; threshold
  :data:`DETECT_THRESHOLD` of the largest), refined to their centroids and matched
  to the truth (:func:`recon.volume.localize.match_peaks`, gate :data:`GATE_PX` px
  / :data:`GATE_PLANES` planes): lateral error in object space (um, ``px * pitch *
  z / d``), axial error in planes and mm, missed and spurious beads;
* a USAF-like target tilted in depth: PSNR and SSIM (scikit-image, 3D window; one
  least-squares gain, as :mod:`recon.metrics`) of the sensor field of view of the
  volume against the ground-truth volume, next to two baselines (the zero volume
  and the gain-fitted back-projection ``A^T b``).

Regularisation: a sweep over 3D TV weights (l1 off), l1 weights (TV off) and none,
per method and scene, scored by PSNR (target) or by (missed + spurious, mean axial
error, mean lateral error) (beads); the recon3d default (TV
:data:`recon.volume.DEFAULT_TV`, l1 0) and the former default TV 1e-4 are always in
the grid and compared with the best. The curves then use the chosen weights on a
*second* instance of each scene (full mode: other bead positions, the target tilted
the other way), each checkpoint an independent solve with that iteration budget.
Seconds are the solver's per-iteration times (metrics and the one-off Lipschitz
power iteration excluded); each solve is bracketed by two samples of the FFT floor
(:func:`recon.volume.fft_floor_seconds`, ``n_z + 1`` rfft2 + irfft2) and speed is the
median over solves of (median seconds per iteration) / (mean of its floor samples).
Writes ``volume_accuracy.json`` and ``volume_accuracy.png``.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from instrument.benchmarks import fmt, format_table, write_json
from recon.analysis import condition_vs_k, condition_vs_k_axial
from recon.errors import DivergenceError, ReconInputError
from recon.metrics import fit_gain, psnr
from recon.volume import DEFAULT_TV, admm3d, fft_floor_seconds, fista3d
from recon.volume.localize import detect_peaks, match_peaks

from .volume_scenes import VolumeBench, VolumeScene, bead_scene, make_bench, tilted_target_scene

log = logging.getLogger(__name__)

FULL = {
    "bench": {"bin_factor": 2, "n_planes": 16, "z_min_mm": 24.0, "z_max_mm": 48.0},
    "beads": 10,
    "target": {"z_near_mm": 26.0, "z_far_mm": 44.0, "width_mm": 5.0, "slices": 24,
               "patches": 3},
    "tv": [1e-6, 1e-5, 1e-4, 1e-3],
    "l1": [1e-5, 1e-4, 1e-3],
    "sweep_iterations": 200,
    "checkpoints": [10, 30, 100, 300],
    "held_out": True,
}
QUICK = {
    "bench": {"bin_factor": 4, "n_planes": 8, "z_min_mm": 24.0, "z_max_mm": 48.0},
    "beads": 6,
    "target": {"z_near_mm": 26.0, "z_far_mm": 44.0, "width_mm": 5.0, "slices": 8,
               "patches": 3},
    "tv": [1e-5, 1e-4],
    "l1": [1e-3],
    "sweep_iterations": 60,
    "checkpoints": [10, 30, 100],
    "held_out": False,
}
#: The solvers compared.
METHODS3D = {"fista3d": fista3d, "admm3d": admm3d}
#: ``diffuserlab recon3d``'s default weights (TV :data:`recon.volume.DEFAULT_TV`, no
#: l1), always in the sweep and compared with the best.
RECON3D_DEFAULT = (DEFAULT_TV["admm"], 0.0)
#: Peak detection threshold (fraction of the largest 3 x 3 x 3 local mass) and
#: matching gate. The reconstructed mass of far beads is lower at a finite number of
#: iterations (their PSFs are dimmer, 1/z^2, and converge later), hence local mass.
DETECT_THRESHOLD = 0.25
GATE_PX = 3.0
GATE_PLANES = 3.0


# ----------------------------------------------------------------------------- metrics
def volume_psnr(estimate: np.ndarray, truth: np.ndarray) -> float:
    """PSNR (dB) of a volume after one least-squares gain (:func:`recon.metrics.psnr`).

    Parameters
    ----------
    estimate, truth : ndarray, shape (n_z, rows, cols)

    Returns
    -------
    float
        Voxel-wise PSNR, ``data_range`` of the truth.
    """
    e, t = np.asarray(estimate), np.asarray(truth)
    if e.ndim != 3 or e.shape != t.shape:
        raise ReconInputError(f"volumes must be 3D of one shape, got {e.shape} and {t.shape}")
    return psnr(e.reshape(-1, e.shape[-1]), t.reshape(-1, t.shape[-1]))


def volume_ssim(estimate: np.ndarray, truth: np.ndarray) -> float:
    """3D SSIM (:func:`skimage.metrics.structural_similarity`) after one gain fit.

    The window is 7 voxels per axis (the largest odd size <= the smallest axis when
    that is below 7, at least 3).

    Raises
    ------
    ReconInputError
        Shapes that differ or an axis shorter than 3.
    """
    from skimage.metrics import structural_similarity

    e = np.asarray(estimate, np.float64)
    t = np.asarray(truth, np.float64)
    if e.ndim != 3 or e.shape != t.shape:
        raise ReconInputError(f"volumes must be 3D of one shape, got {e.shape} and {t.shape}")
    short = min(t.shape)
    win = min(7, short if short % 2 else short - 1)
    if win < 3:
        raise ReconInputError(f"3D SSIM needs at least 3 voxels per axis, got {t.shape}")
    g = fit_gain(e.reshape(-1, e.shape[-1]), t.reshape(-1, t.shape[-1]))
    return float(structural_similarity(t, g * e, data_range=float(t.max() - t.min()),
                                       win_size=win))


def bead_metrics(bench: VolumeBench, scene: VolumeScene, volume: np.ndarray) -> dict:
    """Detect, match and measure beads in the sensor field of view of a volume.

    Parameters
    ----------
    bench : VolumeBench
    scene : VolumeScene
        A :func:`bead_scene` (``truth_voxels``, ``truth_xyz_mm``).
    volume : ndarray, shape (n_z, rows, cols)
        ``x[:, op.crop[0], op.crop[1]]``.

    Returns
    -------
    dict
        ``detected``, ``missed``, ``spurious`` (counts), ``lateral_um_mean/max``,
        ``axial_planes_mean_abs/max_abs``, ``axial_mm_mean_abs/max_abs`` (None
        without matches), ``within_one_plane`` (every bead found, each within one
        plane) and ``per_bead`` (true and detected voxel, errors).
    """
    det = detect_peaks(volume, threshold=DETECT_THRESHOLD, local_mass=True)
    m = match_peaks(det, scene.truth_voxels, max_lateral_px=GATE_PX,
                    max_axial_planes=GATE_PLANES)
    per = []
    for (t, k), lat, ax in zip(m["pairs"], m["lateral_px"], m["axial_planes"], strict=True):
        z_true = float(scene.truth_xyz_mm[t, 2])
        per.append({"bead": t, "true_voxel": scene.truth_voxels[t], "detected_voxel": det[k],
                    "true_z_mm": z_true,
                    "lateral_um": float(lat * bench.voxel_size_mm(z_true) * 1e3),
                    "axial_planes": float(ax),
                    "axial_mm": float(bench.depth_of(det[k, 0]) - z_true)})
    lat = np.array([p["lateral_um"] for p in per])
    ax = np.abs([p["axial_planes"] for p in per])
    axmm = np.abs([p["axial_mm"] for p in per])
    some = len(per) > 0
    return {
        "detected": int(len(det)), "missed": len(m["missed"]), "spurious": len(m["spurious"]),
        "lateral_um_mean": float(lat.mean()) if some else None,
        "lateral_um_max": float(lat.max()) if some else None,
        "axial_planes_mean_abs": float(ax.mean()) if some else None,
        "axial_planes_max_abs": float(ax.max()) if some else None,
        "axial_mm_mean_abs": float(axmm.mean()) if some else None,
        "axial_mm_max_abs": float(axmm.max()) if some else None,
        "within_one_plane": bool(not m["missed"] and some and ax.max() <= 1.0),
        "per_bead": per,
    }


def target_metrics(scene: VolumeScene, volume: np.ndarray) -> dict:
    """``psnr`` and ``ssim`` of a volume (field of view) against the target's truth."""
    return {"psnr": volume_psnr(volume, scene.truth_volume),
            "ssim": volume_ssim(volume, scene.truth_volume)}


# ----------------------------------------------------------------------------- solving
def _fov(bench: VolumeBench, x: np.ndarray) -> np.ndarray:
    return x[(slice(None), *bench.op.crop)]


def evaluate(kind: str, method: str, bench: VolumeBench, scene: VolumeScene, iterations: int,
             tv: float, l1: float, lipschitz: float) -> tuple[dict, np.ndarray | None]:
    """One timed solve and its metrics; returns the record and the field-of-view volume.

    The record has ``iterations``, ``tv``, ``l1``, ``seconds`` (sum of the solver's
    per-iteration times), ``seconds_per_iteration`` (median), ``fft_floor_seconds``
    (mean of the samples before and after), ``ratio`` (the two divided),
    ``floor_units`` (seconds / floor) and the scene's metrics (:func:`bead_metrics`
    or :func:`target_metrics`); ``diverged`` instead of metrics if the solver failed.
    """
    op = bench.op
    kw = {"lipschitz": lipschitz} if method == "fista3d" else {}
    f0 = fft_floor_seconds(op.padded_shape, op.n_z, repeats=3)
    rec = {"iterations": iterations, "tv": tv, "l1": l1}
    try:
        r = METHODS3D[method](op, scene.b, iterations=iterations, tv=tv, l1=l1, **kw)
    except DivergenceError as exc:
        return {**rec, "diverged": str(exc).splitlines()[0]}, None
    f1 = fft_floor_seconds(op.padded_shape, op.n_z, repeats=3)
    floor = 0.5 * (f0 + f1)
    sec = np.asarray(r.history.seconds, np.float64)
    vol = _fov(bench, r.x)
    metrics = bead_metrics(bench, scene, vol) if kind == "beads" else target_metrics(scene, vol)
    return {**rec, "seconds": float(sec.sum()), "seconds_per_iteration": float(np.median(sec)),
            "fft_floor_seconds": floor, "ratio": float(np.median(sec)) / floor,
            "floor_units": float(sec.sum()) / floor, **metrics}, vol


def score(kind: str, rec: dict) -> tuple:
    """Sort key of a sweep record (smaller is better); diverged records last."""
    if "diverged" in rec:
        return (np.inf,)
    if kind == "target":
        return (-rec["psnr"],)
    ax, lat = rec["axial_planes_mean_abs"], rec["lateral_um_mean"]
    return (rec["missed"] + rec["spurious"], np.inf if ax is None else ax,
            np.inf if lat is None else lat)


def _candidates(cfg: dict) -> list[tuple[float, float]]:
    return [(0.0, 0.0)] + [(tv, 0.0) for tv in cfg["tv"]] + [(0.0, l1) for l1 in cfg["l1"]]


def _scenes(bench: VolumeBench, cfg: dict, instance: int) -> dict[str, VolumeScene]:
    """Instance 0 (the sweep's) or 1 (other beads, the target tilted the other way)."""
    t = dict(cfg["target"])
    if instance:
        t["z_near_mm"], t["z_far_mm"] = t["z_far_mm"], t["z_near_mm"]
    return {"beads": bead_scene(bench, cfg["beads"], seed=instance),
            "target": tilted_target_scene(bench, seed=instance, **t)}


def _baselines(bench: VolumeBench, scene: VolumeScene) -> dict:
    """Target metrics of the zero volume and of the gain-fitted back-projection."""
    zero = np.zeros_like(scene.truth_volume)
    return {"zero_volume": {"psnr": volume_psnr(zero, scene.truth_volume)},
            "back_projection": target_metrics(scene, _fov(bench, bench.op.adjoint(scene.b)))}


def conditioning(bench: VolumeBench, k_max: int = 16) -> dict:
    """Local condition numbers of the benchmark's PSF stack, axially and laterally (Fig. 4.5).

    Axially: k sources at consecutive planes 1 and 2 planes apart (as many as fit);
    laterally: k sources in a line along x, 1 and 2 px apart, at the middle plane.
    """
    h = bench.op.psf_stack
    n_z, step = h.shape[0], float(np.mean(np.abs(np.diff(1.0 / bench.depths_mm))))
    out = {"axial": [], "lateral": [], "inverse_depth_step_per_mm": step}
    for s in (1, 2):
        ks = list(range(2, min(k_max, (n_z - 1) // s + 1) + 1))
        if ks:
            out["axial"].append({"separation_planes": s, "separation_inverse_mm": s * step,
                                 "ks": ks, "condition": condition_vs_k_axial(h, s, ks)})
    ks = list(range(2, k_max + 1))
    for s in (1, 2):
        out["lateral"].append({"separation_px": s, "depth_mm": float(bench.depths_mm[n_z // 2]),
                               "ks": ks, "condition": condition_vs_k(h[n_z // 2], s, ks)})
    return out


# ----------------------------------------------------------------------------- the run
def run_volume_accuracy(quick: bool = False, out: Path | None = None) -> dict:
    """Sweep the weights, trace the curves, time against the FFT floor; write JSON + PNG.

    Parameters
    ----------
    quick : bool
        Bin 4 and 8 planes, 6 beads, fewer weights and iterations, no held-out instance
        (tests/CI, about 15 s).
    out : Path, optional
        Directory for ``volume_accuracy.json`` and ``volume_accuracy.png``.

    Returns
    -------
    dict
        ``setup``, ``snr``, ``sweep`` (kind -> method -> records), ``chosen``
        (kind -> method -> ``{"tv", "l1"}``), ``recon3d_default``, ``curves`` (kind ->
        method -> records per checkpoint), ``baselines`` (target: zero volume,
        back-projection), ``speed`` (method -> median ratio to the FFT floor),
        ``final`` (kind -> method -> the record at the largest budget),
        ``conditioning`` and ``wall_seconds``.
    """
    cfg = QUICK if quick else FULL
    t_start = time.perf_counter()

    bench = make_bench(**cfg["bench"])
    op = bench.op
    t0 = time.perf_counter()
    lip = op.lipschitz()
    lip_seconds = time.perf_counter() - t0
    log.info(f"3D accuracy: {op.n_z} planes {bench.depths_mm[0]:g}-{bench.depths_mm[-1]:g} "
             f"mm (uniform in 1/z), grid {op.sensor_shape[0]}x{op.sensor_shape[1]} (bin "
             f"{bench.bin_factor}), padded {op.padded_shape}")
    sweep_scenes = _scenes(bench, cfg, 0)
    curve_scenes = _scenes(bench, cfg, 1) if cfg["held_out"] else sweep_scenes
    for name, solver in METHODS3D.items():  # warm-up: JIT caches, FFT plans
        solver(op, sweep_scenes["beads"].b, iterations=2, tv=1e-4,
               **({"lipschitz": lip} if name == "fista3d" else {}))

    sweep: dict = {k: {} for k in sweep_scenes}
    chosen: dict = {k: {} for k in sweep_scenes}
    default_cmp: dict = {k: {} for k in sweep_scenes}
    cands = _candidates(cfg)
    if RECON3D_DEFAULT not in cands:
        cands.append(RECON3D_DEFAULT)
    for kind, scene in sweep_scenes.items():
        for m in METHODS3D:
            recs = [evaluate(kind, m, bench, scene, cfg["sweep_iterations"], tv, l1, lip)[0]
                    for tv, l1 in cands]
            best = min(recs, key=lambda r: score(kind, r))
            sweep[kind][m] = recs
            chosen[kind][m] = {"tv": best["tv"], "l1": best["l1"]}
            dflt = next(r for r in recs if (r["tv"], r["l1"]) == RECON3D_DEFAULT)
            default_cmp[kind][m] = {"default": dflt, "best": best,
                                    "psnr_below_best_db": (best["psnr"] - dflt["psnr"])
                                    if kind == "target" and "psnr" in dflt else None}
            log.info(f"  sweep {kind} {m}: best tv {best['tv']:g}, l1 {best['l1']:g}")

    curves: dict = {k: {} for k in curve_scenes}
    final: dict = {k: {} for k in curve_scenes}
    volumes: dict = {}
    ratios: dict = {m: [] for m in METHODS3D}
    for kind, scene in curve_scenes.items():
        for m in METHODS3D:
            w = chosen[kind][m]
            pts = []
            for it in cfg["checkpoints"]:
                rec, vol = evaluate(kind, m, bench, scene, it, w["tv"], w["l1"], lip)
                pts.append(rec)
                if "ratio" in rec:
                    ratios[m].append(rec["ratio"])
                volumes[(kind, m)] = vol
            curves[kind][m] = pts
            final[kind][m] = pts[-1]
            log.info(f"  curve {kind} {m}: done")
    baselines = _baselines(bench, curve_scenes["target"])
    speed = {m: {"ratio_median": float(np.median(r)) if r else None,
                 "ratio_range": [float(min(r)), float(max(r))] if r else None,
                 "solves": len(r)} for m, r in ratios.items()}
    result = {
        "quick": quick,
        "setup": {**cfg["bench"], "depths_mm": bench.depths_mm,
                  "sensor_shape": list(op.sensor_shape), "padded_shape": list(op.padded_shape),
                  "pitch_um": bench.pitch_mm * 1e3, "d_mm": bench.d_mm,
                  "psf_snr_db": bench.psf_snr_db, "beads": cfg["beads"],
                  "target": cfg["target"], "sweep_iterations": cfg["sweep_iterations"],
                  "checkpoints": cfg["checkpoints"], "held_out": cfg["held_out"],
                  "weights_tv": cfg["tv"], "weights_l1": cfg["l1"],
                  "detect_threshold": DETECT_THRESHOLD, "gate_px": GATE_PX,
                  "gate_planes": GATE_PLANES, "lipschitz": lip, "lipschitz_seconds": lip_seconds,
                  "ffts_per_iteration": {"rfft2": op.n_z + 1, "irfft2": op.n_z + 1},
                  "scenes": {k: s.info for k, s in curve_scenes.items()}},
        "snr": {k: s.snr_db for k, s in curve_scenes.items()},
        "sweep": sweep, "sweep_baselines": _baselines(bench, sweep_scenes["target"]),
        "chosen": chosen,
        "recon3d_default": {"tv": RECON3D_DEFAULT[0], "l1": RECON3D_DEFAULT[1],
                            "comparison": default_cmp},
        "curves": curves, "final": final, "baselines": baselines, "speed": speed,
        "conditioning": conditioning(bench),
        "wall_seconds": time.perf_counter() - t_start,
    }
    if out is not None:
        from .volume_plots import plot_volume_accuracy

        out = Path(out)
        write_json(out / "volume_accuracy.json", result)
        plot_volume_accuracy(result, out / "volume_accuracy.png", volumes,
                             curve_scenes["target"].truth_volume)
    return result


def volume_accuracy_table(result: dict) -> str:
    """Text summary of a :func:`run_volume_accuracy` result."""
    s = result["setup"]
    lines = [f"3D accuracy ({'quick' if result['quick'] else 'full'}): {len(s['depths_mm'])} "
             f"planes, grid {s['sensor_shape'][0]}x{s['sensor_shape'][1]}, SNR beads "
             f"{result['snr']['beads']:.1f} dB, target {result['snr']['target']:.1f} dB; "
             f"speed as seconds per iteration / FFT floor ({s['ffts_per_iteration']['rfft2']} "
             "rfft2 + irfft2)"]
    rows = []
    for m in METHODS3D:
        b, t = result["final"]["beads"][m], result["final"]["target"][m]
        wb, wt = result["chosen"]["beads"][m], result["chosen"]["target"][m]
        rows.append([m, f"{wb['tv']:g}/{wb['l1']:g}", b["iterations"],
                     fmt(b.get("lateral_um_mean"), ".1f"), fmt(b.get("axial_planes_max_abs")),
                     fmt(b.get("axial_mm_mean_abs"), ".3f"),
                     f"{b.get('missed', '-')}/{b.get('spurious', '-')}",
                     f"{wt['tv']:g}/{wt['l1']:g}", fmt(t.get("psnr")), fmt(t.get("ssim"), ".3f"),
                     fmt(t.get("seconds"), ".2f"), fmt(result["speed"][m]["ratio_median"])])
    lines.append(format_table(["method", "beads tv/l1", "iters", "lat um", "max ax pl",
                               "ax mm", "miss/spur", "target tv/l1", "PSNR", "SSIM", "s",
                               "x floor"], rows))
    bl = result["baselines"]
    lines.append(f"baselines (target): zero volume {bl['zero_volume']['psnr']:.2f} dB, "
                 f"back-projection {bl['back_projection']['psnr']:.2f} dB / "
                 f"{bl['back_projection']['ssim']:.3f}")
    zero = result["sweep_baselines"]["zero_volume"]["psnr"]
    for m in METHODS3D:
        recs = [r for r in result["sweep"]["target"][m] if r["l1"] == 0 and "psnr" in r]
        lines.append(f"target sweep {m} (TV, l1 off; zero volume {zero:.2f} dB): " + ", ".join(
            f"{r['tv']:g}: {r['psnr']:.2f}" for r in sorted(recs, key=lambda r: r["tv"])))
    for kind, per in result["recon3d_default"]["comparison"].items():
        if kind == "target":
            lines.append(f"recon3d default tv {RECON3D_DEFAULT[0]:g} on the target: " + ", ".join(
                f"{m} {fmt(c['default'].get('psnr'))} dB vs best {fmt(c['best'].get('psnr'))} "
                f"(tv {c['best']['tv']:g}, l1 {c['best']['l1']:g})" for m, c in per.items()))
    for c in result["conditioning"]["axial"]:
        lines.append(f"axial condition number, {c['separation_planes']} plane(s) apart "
                     f"({c['separation_inverse_mm']:.4f} 1/mm): {c['condition'][0]:.3g} (k = 2) "
                     f"-> {c['condition'][-1]:.3g} (k = {c['ks'][-1]})")
    return "\n".join(lines)

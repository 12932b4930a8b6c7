"""3D solvers on external data: our 3D FISTA and ADMM beside LenslessPiCam's 3D FISTA.

Run with ``diffuserlab benchmark recon --only volume_external [--quick] [--out DIR]``.

Data: the 3D DiffuserCam sample LenslessPiCam distributes (:mod:`recon.volume.sample`:
44 calibrated PSFs and one raw image, no ground truth), dark-subtracted per image and
binned (2: 135 x 160; quick: 4, 67 x 80). In one process:

* our 3D FISTA (:func:`recon.volume.fista3d`) and 3D ADMM
  (:func:`recon.volume.admm3d`), non-negative, no regulariser, on the forward model
  of Eq. 4.4 with the normalised stack; their per-iteration seconds and relative data
  residuals come from the solvers' histories;
* LenslessPiCam's FISTA (``lensless.FISTA``, numpy, float32) on the same stack and
  image, run in chunks of iterations (``apply(reset=False)``), each chunk's
  wall time divided by its iterations; its residual is evaluated after each chunk
  on the Eq. 4.4 model after one least-squares gain (its volume has its own scale).
  LenslessPiCam 1.0.8 convolves each plane with its PSF and compares each with the
  whole image (its gradient has no sum over depth), so it solves a different
  problem than Eq. 4.4; the benchmark says how far its volume agrees with ours;
* the default of ``recon3d`` (:func:`recon.reconstruct` of a :class:`recon.PsfStack`,
  automatic weight);
  its time, residual and how much of the unregularised FISTA's fine structure its
  maximum projection keeps (:func:`fine_structure_share`).

Speed is the median seconds per iteration, also over the FFT floor
(:func:`recon.volume.fft_floor_seconds`, ``n_z + 1`` rfft2 + irfft2) measured in the
same run, and LenslessPiCam's over ours. LenslessPiCam is imported only here and
only if installed (``pip install lensless``, with a CPU torch); it is not a
dependency of DiffuserLab.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from instrument.benchmarks import fmt, format_table, save_figure, write_json
from recon.api import PsfStack, reconstruct
from recon.volume import admm3d, fft_floor_seconds, fista3d, normalize_psf_stack
from recon.volume.operator import VolumeConvolutionOperator
from recon.volume.sample import load_volume_sample

FULL = {"bin_factor": 2, "iterations": 200, "chunk": 10}
QUICK = {"bin_factor": 4, "iterations": 20, "chunk": 5}


def fine_structure(image: np.ndarray, sigma: float = 1.0) -> float:
    """How much fine structure an image holds, edges aside.

    On the image's support (pixels at least 10 % of its 99.5th percentile), the median
    of ``|image - blur(image)|`` (Gaussian blur of ``sigma`` px) over the median of the
    image: a textured image has detail at most pixels; a few flat blocks have it only
    at their edges, a small share of the pixels, so the median ignores them.

    Parameters
    ----------
    image : ndarray, 2D
        E.g. the maximum projection of a volume.
    sigma : float

    Returns
    -------
    float
        Scale-free (0 for flat blocks).
    """
    a = np.asarray(image, np.float64)
    support = a >= 0.1 * np.percentile(a, 99.5)
    if not np.any(support) or not np.median(a[support]) > 0:
        return 0.0
    detail = np.abs(a - ndimage.gaussian_filter(a, sigma))
    return float(np.median(detail[support]) / np.median(a[support]))


def fine_structure_share(image: np.ndarray, reference: np.ndarray) -> float:
    """:func:`fine_structure` of ``image`` over that of ``reference`` (e.g. the maximum
    projections of the default and of unregularised 3D FISTA): 1 keeps its detail."""
    return fine_structure(image) / max(fine_structure(reference), 1e-300)


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a, np.float64).ravel(), np.asarray(b, np.float64).ravel()
    den = float(np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.dot(a, b)) / den if den > 0 else 0.0


def _gain_residual(op, x: np.ndarray, b: np.ndarray) -> float:
    """Relative residual ``||g A x - b|| / ||b||`` after the least-squares gain ``g``."""
    ax = op.forward(np.ascontiguousarray(x, np.float32)).astype(np.float64)
    den = float(np.dot(ax.ravel(), ax.ravel()))
    g = float(np.dot(ax.ravel(), b.ravel())) / den if den > 0 else 0.0
    return float(np.linalg.norm(g * ax - b) / np.linalg.norm(b))


def _ours(name: str, solver, op, b, iterations: int) -> tuple[dict, np.ndarray]:
    r = solver(op, b, iterations=iterations, tv=0.0, l1=0.0, nonneg=True)
    sec = np.asarray(r.history.seconds, np.float64)
    return ({"method": name, "seconds_per_iteration": float(np.median(sec[1:])),
             "seconds": np.cumsum(sec).tolist(),
             "relative_residual": [float(v) for v in r.history.data_residual],
             "final_relative_residual": float(r.final_relative_residual)},
            r.x[(slice(None), *op.crop)])


def _lensless(stack: np.ndarray, raw: np.ndarray, op, b, iterations: int, chunk: int
              ) -> tuple[dict, np.ndarray | None]:
    """LenslessPiCam's FISTA in chunks, or a record of why it did not run."""
    try:
        import lensless
        from lensless import FISTA
    except ImportError as exc:
        return {"method": "lensless_fista", "skipped": f"lensless not installed ({exc}); "
                "pip install lensless (with a CPU torch) to compare"}, None
    psf = np.ascontiguousarray(stack[..., None], np.float32)  # (depth, rows, cols, 1)
    rec = FISTA(psf, dtype="float32", n_iter=iterations)
    rec.set_data(np.ascontiguousarray(raw[..., None], np.float32))
    done, seconds, resid, per = 0, [], [], []
    x = None
    while done < iterations:
        n = min(chunk, iterations - done)
        t0 = time.perf_counter()
        out = rec.apply(n_iter=n, disp_iter=None, reset=(done == 0))
        dt = time.perf_counter() - t0
        done += n
        per.append(dt / n)
        seconds.append((seconds[-1] if seconds else 0.0) + dt)
        x = np.asarray(out)[..., 0]  # (depth, rows, cols)
        vol = np.zeros(op.shape_in, np.float32)
        vol[(slice(None), *op.crop)] = x
        resid.append(_gain_residual(op, vol, b))
    return ({"method": "lensless_fista", "version": getattr(lensless, "__version__", "?"),
             "seconds_per_iteration": float(np.median(per)), "chunk": chunk,
             "seconds": seconds, "iterations_at": list(range(chunk, iterations + 1, chunk))
             + ([iterations] if iterations % chunk else []),
             "relative_residual": resid, "final_relative_residual": resid[-1],
             "residual_note": "Eq. 4.4 model after a least-squares gain"}, x)


def run_volume_external(quick: bool = False, out: Path | None = None) -> dict:
    """Our 3D FISTA, 3D ADMM and default, and LenslessPiCam's FISTA, on the 3D sample.

    Returns
    -------
    dict
        ``methods`` (per method: seconds per iteration, cumulative seconds and
        relative residual per iteration or chunk), ``fft_floor_seconds``,
        ``ratios`` (to the floor, LenslessPiCam over ours), ``agreement``
        (normalised correlations of the volumes and of their maximum projections),
        ``default`` (recon3d's automatic reconstruction: seconds, residual, weight,
        ``fine_structure_share`` of its projection against FISTA's), ``setup``.

    Raises
    ------
    recon.errors.ReconInputError
        The 3D sample is missing.
    """
    cfg = QUICK if quick else FULL
    t_start = time.perf_counter()
    sample = load_volume_sample(cfg["bin_factor"])
    stack = np.clip(sample.stack, 0, None)
    h, _ = normalize_psf_stack(stack)
    raw_scale = float(np.abs(sample.raw).max())
    b = (sample.raw / raw_scale).astype(np.float32)
    op = VolumeConvolutionOperator(h, depths=sample.depths)
    it = cfg["iterations"]
    floor0 = fft_floor_seconds(op.padded_shape, op.n_z)
    fista, v_fista = _ours("fista3d", fista3d, op, b, it)
    admm, v_admm = _ours("admm3d", admm3d, op, b, it)
    lens, v_lens = _lensless(stack, sample.raw, op, b, it, cfg["chunk"])
    floor = 0.5 * (floor0 + fft_floor_seconds(op.padded_shape, op.n_z))
    t0 = time.perf_counter()
    default = reconstruct(PsfStack(sample.stack, sample.depths), sample.raw, iterations=it,
                          dark="none")
    default_s = time.perf_counter() - t0
    auto = default.info.auto[0]
    methods = {m["method"]: m for m in (fista, admm, lens)}
    for m in methods.values():
        if "seconds_per_iteration" in m:
            m["ratio_to_fft_floor"] = m["seconds_per_iteration"] / floor
    ratios = {}
    agreement = {"admm3d_vs_fista3d": _correlation(v_admm, v_fista),
                 "admm3d_vs_fista3d_mip": _correlation(v_admm.max(0), v_fista.max(0))}
    if v_lens is not None:
        ratios = {f"lensless_over_{k}": lens["seconds_per_iteration"]
                  / methods[k]["seconds_per_iteration"] for k in ("fista3d", "admm3d")}
        agreement |= {"lensless_vs_fista3d": _correlation(v_lens, v_fista),
                      "lensless_vs_fista3d_mip": _correlation(v_lens.max(0), v_fista.max(0))}
    mips = {"fista3d": v_fista.max(0), "admm3d": v_admm.max(0),
            "default": default.volume.max(0)}
    if v_lens is not None:
        mips["lensless_fista"] = v_lens.max(0)
    result = {"quick": quick, "setup": dict(cfg, shape=list(op.shape_in),
                                            sensor_shape=list(op.sensor_shape)),
              "fft_floor_seconds": floor, "methods": methods, "ratios": ratios,
              "agreement": agreement,
              "default": {"seconds": default_s, "tv": auto["weight"],
                          "iterations_used": int(default.result.params["iterations_used"]),
                          "final_relative_residual": float(
                              default.result.final_relative_residual),
                          "relative_residual_all_pixels": _gain_residual(
                              op, default.result.x, b),
                          "planes_without_evidence": auto["drop"]["planes"],
                          "fine_structure_share": fine_structure_share(mips["default"],
                                                                       mips["fista3d"])},
              "wall_seconds": time.perf_counter() - t_start}
    if out is not None:
        out = Path(out)
        write_json(out / "volume_external.json", result)
        plot_volume_external(result, mips, out / "volume_external.png")
    return result


def plot_volume_external(result: dict, mips: dict, path: Path) -> Path:
    """Residual against seconds per method, and the maximum projections."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 6.2))
    grid = fig.add_gridspec(2, 4, height_ratios=[1.25, 1], hspace=0.35, wspace=0.3)
    ax = fig.add_subplot(grid[0, :])
    styles = {"fista3d": ("C0", "-"), "admm3d": ("C1", "-"), "lensless_fista": ("C3", "o--")}
    for name, m in result["methods"].items():
        if "seconds" not in m:
            continue
        color, style = styles[name]
        label = (f"{name} ({m['seconds_per_iteration'] * 1e3:.0f} ms/it, "
                 f"{m['ratio_to_fft_floor']:.1f}x FFT floor)")
        ax.plot(m["seconds"], m["relative_residual"], style, color=color, label=label, ms=3)
    d = result["default"]
    ax.plot([d["seconds"]], [d["relative_residual_all_pixels"]], "k*", ms=10,
            label=f"recon3d default (auto TV {d['tv']:.2g})")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("seconds")
    ax.set_ylabel("relative data residual (Eq. 4.4)")
    ax.legend(fontsize=8)
    st = result["setup"]
    ax.set_title(f"3D DiffuserCam sample (LenslessPiCam's), {st['shape'][0]} planes of "
                 f"{st['sensor_shape'][0]} x {st['sensor_shape'][1]}: no regulariser, "
                 "non-negative", fontsize=9)
    for i, (name, mip) in enumerate(mips.items()):
        a = fig.add_subplot(grid[1, i])
        view = np.asarray(mip)[::-1, ::-1]  # upright, as recon3d's projections
        a.imshow(view, cmap="gray", vmin=0, vmax=float(np.percentile(view, 99.5)) or None)
        a.set_title(f"max projection: {name}", fontsize=8)
        a.set_xticks([])
        a.set_yticks([])
    return save_figure(fig, path)


def volume_external_table(result: dict) -> str:
    """Text summary of :func:`run_volume_external`."""
    rows = []
    for name, m in result["methods"].items():
        if "skipped" in m:
            rows.append([name, "-", "-", "-", m["skipped"]])
            continue
        rows.append([name, f"{m['seconds_per_iteration'] * 1e3:.1f}",
                     fmt(m["ratio_to_fft_floor"]), f"{m['final_relative_residual']:.4f}",
                     ""])
    d, ag = result["default"], result["agreement"]
    st = result["setup"]
    lines = [f"3D external data: {st['shape'][0]} planes of {st['sensor_shape'][0]} x "
             f"{st['sensor_shape'][1]} (bin {st['bin_factor']}), {st['iterations']} "
             f"iterations, FFT floor {result['fft_floor_seconds'] * 1e3:.1f} ms",
             format_table(["method", "ms/it", "x floor", "residual", "note"], rows),
             "agreement (normalised correlation): " + ", ".join(
                 f"{k} {v:.3f}" for k, v in ag.items()),
             "LenslessPiCam per iteration over ours: " + (", ".join(
                 f"{k} {v:.2f}" for k, v in result["ratios"].items()) or "not run"),
             f"recon3d default: {d['seconds']:.1f} s, TV {d['tv']:.2g}, residual "
             f"{d['relative_residual_all_pixels']:.4f}, its projection keeps "
             f"{d['fine_structure_share']:.2f} of FISTA's fine structure"]
    return "\n".join(lines)

"""Mask design comparison of the diffuser microscope (Kuo 2020, Sec. 6.3, Fig. 6.2-6.3).

``python -m benchmarks.design`` runs :func:`run_design`: the four designs of
:mod:`recon.optics.design_masks` (objective lens, smooth diffuser, regular
microlens array, random microlens diffuser), each imaging the same sparse
fluorescent test objects on a small patch of the field (one PSF per depth, as the
chapter assumes), in 2D (one plane at the lenslets' conjugate depth) and
depth-resolved (three planes, the conjugate depth and +-0.3 mm). Measurements
are rendered with :class:`recon.volume.VolumeConvolutionOperator` on a grid 3 x
finer than the sensor (ray-traced PSFs at that resolution, objects drawn at
sub-pixel positions), binned to sensor pixels, normalised to the same number of
collected photons for every design and corrupted by

* shot noise (Poisson) at a sweep of collected photon counts (Fig. 6.3), or
* Gaussian noise of a standard deviation that is a sweep of multiples of the
  mean pixel value (Fig. 6.2: "the same quantity of Gaussian noise").

They are reconstructed as in Sec. 6.2 without the background term: FISTA with l1
and non-negativity (:func:`recon.volume.fista3d`) on the sensor-grid model of the
same object planes (the binned PSFs), each design at the best l1 weight of a
small grid (the oracle, so the comparison is of the masks and not of the tuning).
PSNR (:func:`recon.metrics.psnr`, gain fitted) is taken against the objects
binned to the sensor grid, over the object region that images onto the patch.

The periodic ghosts of the regular array (Sec. 6.3: "the reconstruction shows
periodic ghosting due to the regularity of the microlens array") are measured as
the reconstructed intensity one lattice period (of the PSF's spots on the sensor,
``lenslet (1 + d / z)``) away from the objects, as a fraction of the intensity on
them, for the regular and the random microlens masks at the highest photon count.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np

from instrument.benchmarks import fmt, format_table, log_x_axis, save_figure, write_json
from recon.errors import ReconInputError
from recon.metrics import psnr
from recon.optics.design_masks import DESIGNS, MaskDesign, bin_fine
from recon.volume import VolumeConvolutionOperator, fista3d, normalize_psf_stack

__all__ = ["design_table", "plot_design", "run_design"]

log = logging.getLogger(__name__)

#: Fine-grid factor of the rendering (odd, so fine and sensor pixels share centres).
OVERSAMPLE = 3

#: Default and quick settings.
FULL = {"size": 128, "photons": (1e3, 1e4, 1e5, 1e6), "gaussian": (0.3, 1.0, 3.0),
        "iterations": 100, "l1": (0.01, 0.03, 0.1)}
QUICK = {"size": 64, "photons": (1e3, 1e5), "gaussian": (0.3, 3.0), "iterations": 40,
         "l1": (0.01, 0.03)}


# ----------------------------------------------------------------------------- scene
def _draw(fine: np.ndarray, rows: np.ndarray, cols: np.ndarray, values: np.ndarray) -> None:
    """Bilinear splat of points (fractional fine-grid positions) into ``fine``."""
    r0, c0 = np.floor(rows).astype(int), np.floor(cols).astype(int)
    fr, fc = rows - r0, cols - c0
    for dr, dc, w in ((0, 0, (1 - fr) * (1 - fc)), (1, 0, fr * (1 - fc)),
                      (0, 1, (1 - fr) * fc), (1, 1, fr * fc)):
        np.add.at(fine, (r0 + dr, c0 + dc), values * w)


def design_scene(n_planes: int, padded: int, region: int, seed: int = 0) -> np.ndarray:
    """Sparse fluorescent objects on the fine padded grid, one set per plane.

    Each plane holds four beads and two short curved filaments (a continuous
    curve sampled every 0.5 fine pixel), all inside the central ``region`` fine
    pixels (the part of the object plane that images onto the sensor patch).

    Parameters
    ----------
    n_planes : int
    padded : int
        Fine padded grid size per axis.
    region : int
        Side of the central square holding the objects, fine pixels.
    seed : int

    Returns
    -------
    ndarray, float64, shape (n_planes, padded, padded)
        Non-negative emitted power per fine pixel (arbitrary unit).
    """
    rng = np.random.default_rng(seed)
    out = np.zeros((n_planes, padded, padded), np.float64)
    lo, hi = (padded - region) / 2 + 4, (padded + region) / 2 - 5
    for k in range(n_planes):
        n_beads = 4
        _draw(out[k], rng.uniform(lo, hi, n_beads), rng.uniform(lo, hi, n_beads),
              rng.uniform(2.0, 4.0, n_beads))
        for _ in range(2):
            start = rng.uniform(lo + region * 0.15, hi - region * 0.15, 2)
            length = region * rng.uniform(0.15, 0.3)
            ang0, bend = rng.uniform(0, 2 * math.pi), rng.uniform(-1.5, 1.5)
            t = np.linspace(0.0, 1.0, int(length * 2))
            ang = ang0 + bend * t
            rr = start[0] + np.cumsum(np.sin(ang)) * (length / t.size)
            cc = start[1] + np.cumsum(np.cos(ang)) * (length / t.size)
            ok = (rr > lo) & (rr < hi) & (cc > lo) & (cc < hi)
            _draw(out[k], rr[ok], cc[ok], np.full(int(ok.sum()), 0.5))
    return out


def _coarse(fine: np.ndarray) -> np.ndarray:
    """Fine planes to sensor-grid planes: fine pixel ``3 i`` is sensor-grid pixel ``i``
    (the fine and coarse models share that centre), so bin ``3 i - 1 .. 3 i + 1``."""
    return bin_fine(np.roll(fine, 1, axis=(-2, -1)), OVERSAMPLE)


# ----------------------------------------------------------------------------- one case
class _Case:
    """One design and one set of depths: the fine truth model, the sensor-grid model."""

    def __init__(self, design: MaskDesign, depths: list[float], truth_fine: np.ndarray):
        size = design.sensor_shape[0]
        fine_psf = design.psf_stack(depths, OVERSAMPLE)
        self.fine_op = VolumeConvolutionOperator(
            fine_psf, padded_shape=(2 * size * OVERSAMPLE,) * 2)
        stack, self.scale = normalize_psf_stack(bin_fine(fine_psf, OVERSAMPLE))
        self.op = VolumeConvolutionOperator(stack, padded_shape=(2 * size,) * 2)
        self.lipschitz = self.op.lipschitz()
        clean = bin_fine(self.fine_op.forward(truth_fine.astype(np.float32)), OVERSAMPLE)
        self.clean = np.maximum(clean, 0.0) / clean.sum()  # one collected photon in all
        self.psf_peak_fraction = float(stack[len(depths) // 2].max() / stack[len(depths) // 2]
                                       .sum())

    def solve(self, b: np.ndarray, iterations: int, l1_fraction: float) -> np.ndarray:
        """FISTA (l1, non-negative) on ``b``; the l1 weight is ``l1_fraction`` of
        ``max(A^T b)`` (at or above it the solution is zero)."""
        bs = (b / np.abs(b).max()).astype(np.float32)
        tau = l1_fraction * float(self.op.adjoint(bs).max())
        return fista3d(self.op, bs, iterations=iterations, tv=0.0, l1=max(tau, 1e-12),
                       lipschitz=self.lipschitz).x


def _region(size: int) -> tuple[slice, slice]:
    """Where the sensor patch's object region sits in the padded sensor grid."""
    s = slice(size // 2, size // 2 + size)
    return s, s


def _psnr(x: np.ndarray, truth: np.ndarray, size: int) -> float:
    r = _region(size)
    return psnr(np.concatenate([p[r] for p in x]), np.concatenate([p[r] for p in truth]))


def _noisy(clean: np.ndarray, sweep: str, level: float, rng) -> np.ndarray:
    if sweep == "photons":
        return rng.poisson(clean * level).astype(np.float64)
    return clean + level * float(clean.mean()) * rng.standard_normal(clean.shape)


def _ghost_fraction(x: np.ndarray, truth: np.ndarray, period_px: float) -> float:
    """Mean reconstruction one spot period away from the objects (4 directions,
    away from the objects themselves) over the mean on the objects."""
    on = truth > 0.05 * truth.max()
    p = int(round(period_px))
    shifted = np.zeros_like(on)
    for dr, dc in ((p, 0), (-p, 0), (0, p), (0, -p)):
        shifted |= np.roll(on, (dr, dc), axis=(0, 1))
    near = on.copy()
    for dr in (-2, -1, 0, 1, 2):
        for dc in (-2, -1, 0, 1, 2):
            near |= np.roll(on, (dr, dc), axis=(0, 1))
    ghost = shifted & ~near
    return float(x[ghost].mean() / max(x[on].mean(), 1e-30))


# ----------------------------------------------------------------------------- benchmark
def run_design(quick: bool = False, out: Path | None = None, *, designs=DESIGNS,
               seed: int = 0, settings: dict | None = None) -> dict:
    """PSNR of the four mask designs against photons and Gaussian noise, 2D and 3D.

    Parameters
    ----------
    quick : bool
        :data:`QUICK` settings (64 x 64 patch, 2 levels per sweep, 40 iterations)
        instead of :data:`FULL` (128 x 128, 4 photon counts and 3 Gaussian levels,
        100 iterations, 3 l1 weights).
    out : Path, optional
        Directory for ``design.json`` and ``design.png`` (not written when None).
    designs : sequence of str
        Subset of :data:`recon.optics.design_masks.DESIGNS`.
    seed : int
        Scene, noise and surface seed.
    settings : dict, optional
        Overrides of the chosen settings' keys (``size``, ``photons``,
        ``gaussian``, ``iterations``, ``l1``).

    Returns
    -------
    dict
        ``settings``; ``depths_mm`` (``2d``, ``3d``); ``psnr``:
        ``{sweep: {case: {design: [dB per level]}}}`` with sweeps ``photons`` and
        ``gaussian`` and cases ``2d`` and ``3d``; ``l1_chosen`` alike;
        ``psf_peak_fraction`` per design (the on-axis PSF's brightest pixel over
        its sum, the concentration of light); ``ghosts`` (regular and random:
        ghost fraction, period in pixels); ``ordering`` (per sweep and case, the
        designs by mean PSNR, best first; and ``random_best_flat_3d``: whether the
        random microlens diffuser has the highest mean 3D PSNR of the flat masks in
        both sweeps); ``seconds``; and ``images`` (2D truth and reconstructions at
        the highest photon count, sensor-grid object region, for the figure; not
        written to the JSON).

    Raises
    ------
    ReconInputError
        Unknown designs or settings.
    """
    t_start = time.perf_counter()
    cfg = dict(QUICK if quick else FULL)
    if settings:
        unknown = set(settings) - set(cfg)
        if unknown:
            raise ReconInputError(f"unknown design benchmark settings {sorted(unknown)}; use "
                                  f"{sorted(cfg)}")
        cfg.update(settings)
    bad = [d for d in designs if d not in DESIGNS]
    if bad or not designs:
        raise ReconInputError(f"unknown designs {bad}; choose from {', '.join(DESIGNS)}")
    size = int(cfg["size"])
    z0 = MaskDesign("random").conjugate_z_mm
    depths = {"2d": [z0], "3d": [z0 - 0.3, z0, z0 + 0.3]}
    padded_f = 2 * size * OVERSAMPLE
    truths = {case: design_scene(len(zs), padded_f, size * OVERSAMPLE,
                                 seed + (0 if case == "2d" else 1))
              for case, zs in depths.items()}
    coarse_truth = {case: _coarse(t) for case, t in truths.items()}
    result: dict = {"settings": {k: list(v) if isinstance(v, tuple) else v
                                 for k, v in cfg.items()},
                    "depths_mm": depths, "psnr": {}, "l1_chosen": {},
                    "psf_peak_fraction": {}, "images": {}}
    for sweep in ("photons", "gaussian"):
        result["psnr"][sweep] = {case: {} for case in depths}
        result["l1_chosen"][sweep] = {case: {} for case in depths}
    ghost_x = {}
    for name in designs:
        design = MaskDesign(name, (size, size), seed=seed)
        for case, zs in depths.items():
            t0 = time.perf_counter()
            c = _Case(design, zs, truths[case])
            if case == "2d":
                result["psf_peak_fraction"][name] = c.psf_peak_fraction
            for sweep in ("photons", "gaussian"):
                scores, chosen = [], []
                for i, level in enumerate(cfg[sweep]):
                    rng = np.random.default_rng([seed, i, sweep == "photons"])
                    b = _noisy(c.clean, sweep, float(level), rng)
                    best = (-math.inf, None, None)
                    for w in cfg["l1"]:
                        x = c.solve(b, int(cfg["iterations"]), float(w))
                        p = _psnr(x, coarse_truth[case], size)
                        if p > best[0]:
                            best = (p, float(w), x)
                    scores.append(best[0])
                    chosen.append(best[1])
                    if sweep == "photons" and case == "2d" and i == len(cfg[sweep]) - 1:
                        ghost_x[name] = best[2][0]
                result["psnr"][sweep][case][name] = scores
                result["l1_chosen"][sweep][case][name] = chosen
            log.info("design %s %s: %.1f s", name, case, time.perf_counter() - t0)
    r = _region(size)
    result["images"] = {"truth": coarse_truth["2d"][0][r],
                        **{n: x[r] for n, x in ghost_x.items()}}
    period = MaskDesign("regular").lenslet_um * (1 + MaskDesign("regular").d_mm / z0) / (
        MaskDesign("regular", (size, size)).pitch_um)
    result["ghosts"] = {"period_px": period, **{
        n: _ghost_fraction(ghost_x[n], coarse_truth["2d"][0], period)
        for n in ("regular", "random") if n in ghost_x}}
    result["ordering"] = _ordering(result["psnr"])
    result["seconds"] = time.perf_counter() - t_start
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "design.json", {k: v for k, v in result.items() if k != "images"})
        plot_design(result, out / "design.png")
    return result


def _ordering(scores: dict) -> dict:
    """Designs by mean PSNR per sweep and case, and the chapter's 3D claim."""
    order = {}
    for sweep, cases in scores.items():
        for case, per in cases.items():
            order[f"{sweep}_{case}"] = sorted(per, key=lambda n: -float(np.mean(per[n])))
    flat = ("smooth", "regular", "random")
    claims = []
    for sweep in scores:
        per = scores[sweep]["3d"]
        have = [n for n in flat if n in per]
        if "random" in have and len(have) > 1:
            claims.append(max(have, key=lambda n: float(np.mean(per[n]))) == "random")
    order["random_best_flat_3d"] = bool(claims) and all(claims)
    return order


# ----------------------------------------------------------------------------- output
def design_table(result: dict) -> str:
    """The PSNR table (one row per design and case, one column per noise level), the
    ghosts and the ordering found."""
    lines = []
    for sweep, unit in (("photons", "photons"), ("gaussian", "x mean pixel")):
        levels = result["settings"][sweep]
        headers = ["design", "case"] + [f"{v:g}" for v in levels] + ["mean"]
        rows = []
        for case in ("2d", "3d"):
            for name, vals in result["psnr"][sweep][case].items():
                rows.append([name, case, *(fmt(v, ".1f") for v in vals),
                             fmt(float(np.mean(vals)), ".1f")])
        title = ("shot noise: PSNR (dB) vs collected photons" if sweep == "photons" else
                 f"Gaussian noise: PSNR (dB) vs noise std ({unit})")
        lines += [title, format_table(headers, rows), ""]
    g = result["ghosts"]
    if "regular" in g:
        lines.append(f"ghosts one spot period ({g['period_px']:.1f} px) from the objects, "
                     "2D, most photons: regular " + fmt(g["regular"], ".3f")
                     + (f", random {fmt(g['random'], '.3f')}" if "random" in g else "")
                     + " of the on-object intensity")
    o = result["ordering"]
    for key in ("photons_2d", "gaussian_2d", "photons_3d", "gaussian_3d"):
        if key in o:
            lines.append(f"ordering {key} (mean PSNR, best first): " + " > ".join(o[key]))
    lines.append("random microlens best of the flat masks in 3D (both sweeps): "
                 + ("yes" if o["random_best_flat_3d"] else "no"))
    return "\n".join(lines)


def plot_design(result: dict, path: Path) -> Path:
    """``design.png``: PSNR vs photons, PSNR vs Gaussian noise (2D solid, 3D dashed),
    and the 2D reconstructions at the most photons (truth, regular, random)."""
    from matplotlib.figure import Figure

    imgs = result.get("images", {})
    shown = [n for n in ("truth", "regular", "random") if n in imgs]
    fig = Figure(figsize=(11, 7.5), layout="constrained")
    grid = fig.add_gridspec(2, 6)
    axes = [fig.add_subplot(grid[0, :3]), fig.add_subplot(grid[0, 3:])]
    colours = {n: f"C{i}" for i, n in enumerate(DESIGNS)}
    for ax, sweep in zip(axes, ("photons", "gaussian"), strict=True):
        levels = result["settings"][sweep]
        for case, style in (("2d", "o-"), ("3d", "s--")):
            for name, vals in result["psnr"][sweep][case].items():
                ax.plot(levels, vals, style, color=colours[name], label=f"{name} {case}")
        log_x_axis(ax)
        ax.set_xticks(levels, labels=[f"{v:g}" for v in levels])
        ax.set(ylabel="PSNR (dB)", xlabel="collected photons" if sweep == "photons"
               else "Gaussian noise std / mean pixel value",
               title="shot noise (Fig. 6.3)" if sweep == "photons"
               else "Gaussian noise (Fig. 6.2)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)
    for k, name in enumerate(shown):
        ax = fig.add_subplot(grid[1, 2 * k:2 * k + 2])
        img = imgs[name]
        ax.imshow(img, cmap="gray", vmin=0, vmax=float(np.percentile(img, 99.9)) or 1.0)
        title = "truth (2D)" if name == "truth" else f"{name} microlens, most photons"
        if name in result.get("ghosts", {}):
            title += f"\nghosts {result['ghosts'][name]:.2f} of on-object"
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    return save_figure(fig, path)


def run_design_benchmark(args) -> int:
    """Run the design comparison ``args`` ask for (``out``, ``quick``, ``overwrite``),
    print its table and the ordering it found; returns 0."""
    from instrument.writer.guards import check_outputs

    check_outputs([args.out / "design.json", args.out / "design.png"], None,
                  args.overwrite, directory=args.out)
    result = run_design(args.quick, args.out)
    print(design_table(result))
    print(f"({result['seconds']:.0f} s) results in {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m benchmarks.design``: :func:`run_design_benchmark` inside the
    ``diffuserlab`` error boundary (:func:`instrument.cli.run_handler`: 2 and one line
    for bad input, an OS error or an ``--out`` holding earlier results); returns the
    exit status."""
    import argparse

    from instrument.cli import run_handler

    p = argparse.ArgumentParser(
        prog="python -m benchmarks.design",
        description="Reconstruct sparse fluorescent objects (2D, and 3 depths) imaged by an "
        "objective lens, a smooth diffuser, a regular microlens array and a random microlens "
        "diffuser over sweeps of collected photons (shot noise) and Gaussian noise; print "
        "the PSNR table and the ordering, write design.json and design.png.")
    p.add_argument("--out", type=Path, default=Path("out/benchmark-design"),
                   help="directory for design.json and design.png (default "
                   "out/benchmark-design)")
    p.add_argument("--quick", action="store_true",
                   help="64 x 64 patch, 2 levels per sweep, 40 iterations (tests, ~30 s)")
    p.add_argument("--overwrite", action="store_true", help="replace earlier results in --out")
    p.add_argument("--debug", action="store_true", help="show a bug's traceback")
    p.set_defaults(handler=run_design_benchmark)
    return run_handler(p.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())

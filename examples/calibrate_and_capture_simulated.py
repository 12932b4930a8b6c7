"""A scripted bench session on the built-in simulated bench: calibrate, capture, reconstruct.

Run from the repository root (no hardware)::

    python examples/calibrate_and_capture_simulated.py [--out out/example-bench] [--depths 3]

What an operator's script does on a real bench, with the virtual bench standing in: open
the devices, run the PSF depth sweep (a calibration run stored as a Zarr run store that
can be resumed), put a scene in front of the camera at one calibrated depth, capture
it, reconstruct it with that depth's PSF and compare with the known scene (PSNR).
On a real bench, ``Bench.open(load_bench("bench.toml"))`` replaces ``VirtualBench()``.
"""

import argparse
import sys
from pathlib import Path

import numpy as np
from skimage import data

from calibration_routines.psf_sweep import PsfSweepPlan
from instrument.acquisition.exposure import average_frames
from instrument.acquisition.runner import Runner
from instrument.devices.virtual_bench import PlanarScene, VirtualBench
from instrument.runs.stacks import load_psf_stack
from instrument.writer.files import save_image
from recon import reconstruct
from recon.metrics import psnr, register_truth


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/example-bench"))
    parser.add_argument("--depths", type=int, default=3, help="depths of the PSF sweep")
    parser.add_argument("--iterations", type=int, default=200)
    args = parser.parse_args(argv)
    run_path = args.out / "psf_sweep.zarr"
    if run_path.exists():
        print(f"error: {run_path} exists: give another --out (runs are never "
              "overwritten)", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)

    with VirtualBench(seed=0).open() as bench:
        # 1. Calibration: the PSF at each depth, the LED behind the pinhole on the stage.
        plan = PsfSweepPlan.for_bench(bench, n_depths=args.depths, frames_per_point=2)
        result = Runner(bench).run(plan, run_path, note="example: scripted sweep")
        print(f"PSF sweep: {result.status}, {result.points_done} of "
              f"{result.points_total} depths, stored in {result.path}")
        stack, depths_mm, _ = load_psf_stack(result.path)
        k = len(depths_mm) // 2

        # 2. Capture: a photograph at the middle depth, the LEDs off.
        bench.led_array.all_off()
        scene = PlanarScene(image=data.camera().astype(np.float64) / 255.0,
                            z_mm=float(depths_mm[k]), width_mm=30.0)
        bench.set_scene(scene)
        raw, _ = average_frames(bench.camera, 4)
        truth = bench.scene_truth(raw.shape)

    # 3. Reconstruction with that depth's PSF (method and weight automatic).
    recon = reconstruct(stack[k], raw, iterations=args.iterations, dark=0.0)
    image = recon.image
    _, registered = register_truth(image, truth)
    print(f"reconstructed at {depths_mm[k]:.1f} mm: {recon.info.method}, TV weight "
          f"{recon.info.tv:.3g}; PSNR against the known scene "
          f"{psnr(image, registered):.1f} dB")
    save_image(args.out / "reconstruction.png", recon.upright())
    print(f"wrote {args.out / 'reconstruction.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

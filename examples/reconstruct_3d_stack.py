"""Reconstruct a 3D scene from a PSF stack and one raw image (3D DiffuserCam).

Run from the repository root::

    python examples/reconstruct_3d_stack.py [DATA_DIR] [--bin 2] [--planes 8]

``DATA_DIR`` holds ``psf/psf00.tiff ... psfNN.tiff`` (one PSF per depth, nearest
first) and ``image.tiff``: the 3D DiffuserCam sample distributed with LenslessPiCam
(default ``$DIFFUSERLAB_DATA3D`` or ``../shared/data/diffuser3d-lenslesspicam``). The
depths are not published with that data, so the script gives the planes increasing
nominal depths; their order is what matters. The TV weight is chosen automatically and
every plane is kept; the script
prints the per-plane energy (where the scene's light went) and writes the maximum
projection along depth as a PNG.
"""

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from instrument.writer.files import save_image
from recon import PsfStack, reconstruct
from recon.io import load_image


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = os.environ.get("DIFFUSERLAB_DATA3D", "../shared/data/diffuser3d-lenslesspicam")
    parser.add_argument("data", nargs="?", type=Path, default=Path(default))
    parser.add_argument("--bin", type=int, default=2, help="lateral binning (1: full size)")
    parser.add_argument("--planes", type=int, default=0,
                        help="use every k-th plane so that about this many remain (0: all)")
    parser.add_argument("--iterations", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("out/example-3d"))
    args = parser.parse_args(argv)
    files = sorted((args.data / "psf").glob("psf*.tif*"))
    if not files or not (args.data / "image.tiff").is_file():
        print(f"error: no PSF stack (psf/psf*.tiff) and image.tiff in {args.data}: pass "
              "the folder of the 3D sample", file=sys.stderr)
        return 2
    step = max(1, len(files) // args.planes) if args.planes else 1
    files = files[::step]
    stack = np.stack([load_image(f) for f in files]).astype(np.float32)
    depths_mm = np.arange(len(files), dtype=float) * step + 1.0  # nominal, increasing
    raw = load_image(args.data / "image.tiff")

    result = reconstruct(PsfStack(stack, depths_mm), raw, iterations=args.iterations,
                         bin_factor=args.bin)
    print(result)

    volume = result.image
    print(f"volume {volume.shape} {volume.dtype} (planes, rows, cols)")
    energy = volume.reshape(volume.shape[0], -1).sum(axis=1)
    share = energy / max(energy.sum(), 1e-30)
    for z, e in zip(depths_mm, share, strict=True):
        print(f"  plane at nominal depth {z:5.1f}: {100 * e:5.1f} % of the energy "
              + "#" * int(round(50 * e)))
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "max_projection.png"
    save_image(path, result.upright().max(axis=0))  # the scene's orientation
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

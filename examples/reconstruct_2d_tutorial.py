"""Reconstruct the DiffuserCam tutorial photograph (2D) from its PSF and raw image.

Run from the repository root::

    python examples/reconstruct_2d_tutorial.py [DATA_DIR] [--bin 4] [--out out/example-2d]

``DATA_DIR`` holds ``psf_sample.tif`` and ``rawdata_hand_sample.tif`` (the DiffuserCam
tutorial sample; default ``$DIFFUSERLAB_DATA`` or ``../shared/data/diffusercam-tutorial``).
The method and the TV weight are chosen automatically (``method="auto"``); the script
prints what was chosen and why, and writes the upright image as a PNG.
"""

import argparse
import os
import sys
from pathlib import Path

from instrument.writer.files import save_image
from recon import reconstruct
from recon.io import load_image


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = os.environ.get("DIFFUSERLAB_DATA", "../shared/data/diffusercam-tutorial")
    parser.add_argument("data", nargs="?", default=default, type=Path)
    parser.add_argument("--bin", type=int, default=4, help="lateral binning (1: full size)")
    parser.add_argument("--iterations", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("out/example-2d"))
    args = parser.parse_args(argv)
    psf_path, raw_path = args.data / "psf_sample.tif", args.data / "rawdata_hand_sample.tif"
    if not (psf_path.is_file() and raw_path.is_file()):
        print(f"error: no DiffuserCam tutorial sample in {args.data}: pass its folder "
              "or set DIFFUSERLAB_DATA", file=sys.stderr)
        return 2
    psf, raw = load_image(psf_path), load_image(raw_path)

    result = reconstruct(psf, raw, method="auto", iterations=args.iterations,
                         bin_factor=args.bin)

    info = result.info
    print(f"image {result.image.shape} {result.image.dtype}: {info.method}, TV weight "
          f"{info.tv:.3g}, {info.iterations_used} iterations, "
          f"{info.seconds_total:.1f} s; dark level {info.dark_level:.1f} DN "
          f"({info.dark_source})")
    for choice in info.auto:  # one per colour channel
        print("  method:", "; ".join(choice["method"]["reasons"]))
        print("  weight:", choice["weight"]["reason"])
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "reconstruction.png"
    save_image(path, result.upright())  # the scene's orientation
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

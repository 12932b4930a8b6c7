"""Box binning: downsample an image by averaging non-overlapping square blocks."""

from __future__ import annotations

import logging

import numpy as np

from recon.errors import ReconInputError

from .validation import as_array, check_bin_factor, require_image

logger = logging.getLogger(__name__)

__all__ = ["box_bin"]


def box_bin(image: np.ndarray, factor: int) -> np.ndarray:
    """Downsample by averaging non-overlapping ``factor x factor`` blocks.

    Parameters
    ----------
    image : numpy.ndarray
        Shape (H, W) or (H, W, C), real numeric dtype. Channels are binned
        independently.
    factor : int
        Block size, an integer >= 1 and <= min(H, W). If H or W is not a
        multiple of `factor`, the remainder rows (bottom) and columns (right)
        are cropped and a warning is logged.

    Returns
    -------
    numpy.ndarray
        float32, shape (H // factor, W // factor[, C]); block means
        (accumulated in float64). ``factor=1`` returns a float32 copy.

    Raises
    ------
    ReconInputError
        If `factor` is not an integer >= 1 (floats such as 2.0 and bools are
        refused), is larger than the image, or the image is not a non-empty
        numeric 2D/3D array.

    Notes
    -----
    Source: DiffuserCam tutorial ``resize``, which averages 2x2 blocks
    repeatedly (factor 1/4 per axis: 1200 x 1600 -> 300 x 400, i.e.
    ``box_bin(image, 4)``).
    """
    image = as_array(image, "image")
    require_image(image, "image")
    factor = check_bin_factor(factor)
    height, width = image.shape[:2]
    if factor > height or factor > width:
        raise ReconInputError(
            f"bin factor {factor} is larger than the image ({height}x{width}); "
            "use a smaller bin factor"
        )
    if factor == 1:
        return image.astype(np.float32, copy=True)
    out_h, out_w = height // factor, width // factor
    if out_h * factor != height or out_w * factor != width:
        logger.warning(
            "box_bin: image %dx%d is not divisible by bin factor %d; cropping %d row(s) at "
            "the bottom and %d column(s) at the right",
            height,
            width,
            factor,
            height - out_h * factor,
            width - out_w * factor,
        )
    cropped = image[: out_h * factor, : out_w * factor]
    blocks = cropped.reshape((out_h, factor, out_w, factor) + image.shape[2:])
    return blocks.mean(axis=(1, 3), dtype=np.float64).astype(np.float32)

"""Test scenes: a bar resolution chart, bundled natural images, and area resampling.

* :func:`usaf_target` - a USAF-1951-like bar chart (the resolution target of the
  lensless renderings and of the 3D benchmark's tilted target).
* :data:`SCENES`, :func:`load_scene` - natural photographs bundled with
  scikit-image (no download), the scenes of the simulated 2D measurements.
* :func:`cell_overlap`, :func:`tent_weights` - the weights that resample a scene
  onto an object grid (exact area overlap) and share it between depth slices or
  regions (piecewise-linear partition of unity).

Pure numpy (scikit-image only inside :func:`load_scene`); no optics.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import ReconInputError

__all__ = ["BUNDLED", "SCENES", "cell_overlap", "load_scene", "tent_weights", "usaf_target"]


def usaf_target(shape: tuple[int, int] = (256, 256)) -> np.ndarray:
    """A USAF-1951-like bar target: elements of three horizontal and three vertical
    bars (bar length five widths), bar widths shrinking by ``2^(1/2)`` per element
    from ``min(shape) / 16`` to 1 pixel, packed in rows.

    Parameters
    ----------
    shape : (rows, cols)
        At least 32 x 32.

    Returns
    -------
    ndarray, float64, shape ``shape``
        1 on the bars, 0 elsewhere.

    Raises
    ------
    ReconInputError
        ``shape`` is not a pair of integers, or is smaller than 32 x 32.
    """
    try:
        rows, cols = (int(v) for v in shape)
    except (TypeError, ValueError) as exc:
        raise ReconInputError(f"target shape must be (rows, cols), got {shape!r}") from exc
    if rows < 32 or cols < 32:
        raise ReconInputError(f"target shape {shape} is too small; use at least (32, 32)")
    img = np.zeros((rows, cols), np.float64)
    widths = []
    w = min(rows, cols) / 16
    while round(w) >= 1:
        if not widths or round(w) != widths[-1]:
            widths.append(int(round(w)))
        w /= math.sqrt(2.0)
    r0, c0, shelf = 2, 2, 0
    for w in widths:
        ew, eh = 11 * w, 5 * w  # horizontal-bar block, gap w, vertical-bar block
        if c0 + ew > cols - 2:
            r0, c0, shelf = r0 + shelf + 2 * w, 2, 0
        if r0 + eh > rows - 2:
            break
        for k in range(3):  # three horizontal bars (5w long, w thick)
            img[r0 + 2 * k * w:r0 + 2 * k * w + w, c0:c0 + 5 * w] = 1.0
        for k in range(3):  # three vertical bars
            img[r0:r0 + 5 * w, c0 + 6 * w + 2 * k * w:c0 + 6 * w + 2 * k * w + w] = 1.0
        c0 += ew + 2 * w
        shelf = max(shelf, eh)
    return img


#: Natural test images shipped inside scikit-image's package data (no network fetch).
SCENES: tuple[str, ...] = ("camera", "astronaut", "coffee", "chelsea")
#: Every image :func:`load_scene` loads: :data:`SCENES` and more that scikit-image
#: ships in its package (dense texture, printed text, coins, a star field).
BUNDLED: tuple[str, ...] = SCENES + ("brick", "grass", "gravel", "page", "text", "coins",
                                     "moon", "hubble_deep_field")


def load_scene(name: str, shape: tuple[int, int]) -> np.ndarray:
    """A bundled scikit-image photograph as a float32 gray image of a given shape.

    The image is converted to gray (luminance), centre-cropped to the aspect ratio
    of ``shape`` (no distortion) and resized with :func:`skimage.transform.resize`
    (anti-aliased). Values are in [0, 1].

    Parameters
    ----------
    name : str
        One of :data:`BUNDLED` (:data:`SCENES`: ``"camera"``, ``"astronaut"``,
        ``"coffee"``, ``"chelsea"``; and textures, text, coins, moon, a star field);
        these ship with scikit-image and need no download.
    shape : (rows, cols)
        Output shape, normally the fine sensor shape.

    Returns
    -------
    numpy.ndarray
        float32, ``shape``, values in [0, 1].

    Raises
    ------
    ReconInputError
        Unknown scene name or invalid shape.
    """
    import skimage.data
    from skimage.color import rgb2gray
    from skimage.transform import resize

    if name not in BUNDLED:
        raise ReconInputError(
            f"unknown scene {name!r}; use one of {', '.join(BUNDLED)} (bundled with "
            "scikit-image, no download)"
        )
    rows, cols = (int(s) for s in shape)
    if rows < 2 or cols < 2:
        raise ReconInputError(f"scene shape must be at least 2x2, got {shape}")
    image = np.asarray(getattr(skimage.data, name)())
    if image.ndim == 3:
        image = rgb2gray(image[..., :3])
    image = image.astype(np.float64)
    if image.max() > 1.0:
        image /= 255.0
    h, w = image.shape
    target = cols / rows
    if w / h > target:  # too wide: crop columns
        new_w = max(1, round(h * target))
        left = (w - new_w) // 2
        image = image[:, left:left + new_w]
    else:  # too tall: crop rows
        new_h = max(1, round(w / target))
        top = (h - new_h) // 2
        image = image[top:top + new_h, :]
    out = resize(image, (rows, cols), order=1, anti_aliasing=True, mode="reflect")
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def cell_overlap(edges: np.ndarray, centres: np.ndarray, q: float) -> np.ndarray:
    """Overlap lengths of grid cells with the intervals of a partition.

    Row ``i`` of the result holds the length of the intersection of the cell
    ``[centres[i] - q/2, centres[i] + q/2]`` with each interval
    ``[edges[j], edges[j + 1]]``: ``R @ scene @ C.T`` (``R``, ``C`` the overlaps
    along rows and columns) resamples a piecewise-constant scene onto the cells
    exactly (radiance times area).

    Parameters
    ----------
    edges : ndarray, float64, shape (n + 1,)
        Increasing interval boundaries (e.g. scene pixel edges, mm).
    centres : ndarray, float64, shape (m,)
        Cell centres, same unit.
    q : float
        Cell width, same unit (> 0).

    Returns
    -------
    ndarray, float64, shape (m, n)
        Non-negative overlap lengths.
    """
    lo = np.maximum(centres[:, None] - q / 2, edges[None, :-1])
    hi = np.minimum(centres[:, None] + q / 2, edges[None, 1:])
    return np.clip(hi - lo, 0.0, None)


def tent_weights(pos: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Piecewise-linear partition of unity over a set of centres.

    Weight ``k`` is 1 at ``centres[k]``, falls linearly to 0 at its neighbours and
    is constant beyond the outer centres (:func:`numpy.interp`); the weights sum to
    1 at every position.

    Parameters
    ----------
    pos : ndarray, float64, shape (n,)
        Positions to weight.
    centres : ndarray, float64, shape (k,)
        Increasing centres.

    Returns
    -------
    ndarray, float64, shape (k, n)
    """
    eye = np.eye(len(centres))
    return np.stack([np.interp(pos, centres, eye[k]) for k in range(len(centres))])

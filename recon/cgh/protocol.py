"""Pre-registered evaluation protocol for Table 7.1 (docs/protocols.md).

Images, preprocessing and metrics are fixed here and never tuned per image:

1. Images: the ten natural photographs bundled in the scikit-image wheel
   (:data:`BUNDLED_IMAGES`; loaded from the installed package, never downloaded),
   or any folder of PNG/JPEG/TIFF/.npy images.
2. Grey: :func:`skimage.color.rgb2gray` (Rec. 709) for colour; integers scaled by
   their dtype's maximum (uint8 / 255).
3. Centre crop to the target's aspect (square for Table 7.1) and
   :func:`skimage.transform.resize` with ``anti_aliasing=True``.
4. Contrast stretch: the 1st-99th percentile to [0, 1], then clip. The result is the
   target *intensity* (linear, no sRGB decoding).
5. Metrics: the Butterworth low-pass of the loss (Eq. 7.18, passband = SLM pixel
   count) on result and target; the result scaled to the target's mean; both
   clipped to [0, 1]; ``PSNR = 10 log10(1 / MSE)`` and SSIM with a Gaussian window
   (``sigma = 1.5``, ``use_sample_covariance=False``, data range 1; Wang et al.).
   Over the full field of view and over the central quarter (the central
   ``G_y/2 x G_x/2`` crop, normalised on its own mean).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import ReconInputError
from .losses import butterworth_lowpass, lowpass

__all__ = [
    "BUNDLED_IMAGES",
    "centre_quarter",
    "image_metrics",
    "load_bundled",
    "load_folder",
    "prepare_target",
    "to_grey",
]

#: The A10 set: (``skimage.data`` function, the files it reads from the installed package).
BUNDLED_IMAGES = (
    ("astronaut", ("astronaut.png",)),
    ("camera", ("camera.png",)),
    ("chelsea", ("chelsea.png",)),
    ("clock", ("clock_motion.png",)),
    ("coffee", ("coffee.png",)),
    ("coins", ("coins.png",)),
    ("hubble_deep_field", ("hubble_deep_field.jpg",)),
    ("moon", ("moon.png",)),
    ("rocket", ("rocket.jpg",)),
    ("stereo_motorcycle", ("motorcycle_left.png", "motorcycle_right.png",
                           "motorcycle_disp.npz")),
)

_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".npy")


def load_bundled(name: str) -> np.ndarray:
    """One of :data:`BUNDLED_IMAGES` from the installed scikit-image, offline.

    The file is checked to be inside the installed package before the
    ``skimage.data`` loader runs, so nothing can be fetched from the network.

    Parameters
    ----------
    name : str
        Image name (e.g. ``"camera"``); ``stereo_motorcycle`` gives the left view.

    Returns
    -------
    numpy.ndarray
        The image as ``skimage.data`` returns it (uint8, grey or RGB).

    Raises
    ------
    ReconInputError
        Unknown name, or the file is missing from this scikit-image installation.
    """
    import skimage.data as skdata

    files = dict(BUNDLED_IMAGES)
    if name not in files:
        raise ReconInputError(f"unknown bundled image {name!r}; choose from {sorted(files)}")
    folder = Path(skdata.__file__).parent
    missing = [f for f in files[name] if not (folder / f).is_file()]
    if missing:
        raise ReconInputError(
            f"{', '.join(missing)} not bundled in this scikit-image installation ({folder}); "
            "pass a folder of images instead (nothing is downloaded)")
    img = getattr(skdata, name)()
    return img[0] if isinstance(img, tuple) else img


def load_folder(folder) -> list[tuple[str, np.ndarray]]:
    """All PNG/JPEG/TIFF/.npy images of a folder, sorted by file name.

    Parameters
    ----------
    folder : str or pathlib.Path

    Returns
    -------
    list of (str, numpy.ndarray)
        ``(file stem, image)``.

    Raises
    ------
    ReconInputError
        Not a folder, no images in it, or an unreadable file.
    """
    p = Path(folder)
    if not p.is_dir():
        raise ReconInputError(f"{p} is not a folder; pass a folder of PNG/JPEG/TIFF/.npy images")
    files = sorted(f for f in p.iterdir() if f.suffix.lower() in _SUFFIXES and f.is_file())
    if not files:
        raise ReconInputError(f"no PNG/JPEG/TIFF/.npy images in {p}")
    out = []
    for f in files:
        try:
            if f.suffix.lower() == ".npy":
                img = np.load(f, allow_pickle=False)
            elif f.suffix.lower() in (".tif", ".tiff"):
                import tifffile

                img = tifffile.imread(f)
            else:
                from skimage import io

                img = io.imread(f)
        except Exception as exc:  # noqa: BLE001 - any reader failure is a bad file
            raise ReconInputError(f"cannot read {f}: {exc}; convert it to PNG or .npy") from exc
        out.append((f.stem, np.asarray(img)))
    return out


def to_grey(image) -> np.ndarray:
    """Grey float64 image in [0, 1] for integer input (step 2 of the protocol).

    Parameters
    ----------
    image : numpy.ndarray
        ``(rows, cols)`` grey, ``(rows, cols, 3)`` RGB or ``(rows, cols, 4)`` RGBA
        (alpha dropped); integer (scaled by the dtype's maximum), bool or float.

    Returns
    -------
    numpy.ndarray
        float64 ``(rows, cols)``.
    """
    from skimage.color import rgb2gray

    a = np.asarray(image)
    if a.dtype.kind not in "fiub":
        raise ReconInputError(f"image must be numeric, got dtype {a.dtype}")
    if a.dtype.kind in "iu":
        a = a.astype(np.float64) / float(np.iinfo(a.dtype).max)
    else:
        a = a.astype(np.float64)
    if a.ndim == 3 and a.shape[2] in (3, 4):
        a = rgb2gray(a[..., :3])
    if a.ndim != 2:
        raise ReconInputError(f"image must be grey (H, W) or colour (H, W, 3|4), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ReconInputError("image contains NaN or inf")
    return a


def prepare_target(image, shape) -> np.ndarray:
    """Target intensity by the protocol: grey, centre crop, resize, 1-99 % stretch.

    Parameters
    ----------
    image : numpy.ndarray
        Any image accepted by :func:`to_grey`.
    shape : int or (int, int)
        Output ``(rows, cols)`` (an int means square ``N x N``).

    Returns
    -------
    numpy.ndarray
        float32 ``shape`` in [0, 1].

    Raises
    ------
    ReconInputError
        Image smaller than 2 x 2 or flat (1st and 99th percentiles equal).
    """
    from skimage.transform import resize

    rows, cols = (int(shape), int(shape)) if np.isscalar(shape) else (int(v) for v in shape)
    if rows < 2 or cols < 2:
        raise ReconInputError(f"target shape must be at least 2 x 2, got {(rows, cols)}")
    g = to_grey(image)
    h, w = g.shape
    if h < 2 or w < 2:
        raise ReconInputError(f"image is too small ({h} x {w})")
    if h * cols > w * rows:  # too tall for the aspect: crop rows
        ch, cw = max(1, round(w * rows / cols)), w
    else:
        ch, cw = h, max(1, round(h * cols / rows))
    top, left = (h - ch) // 2, (w - cw) // 2
    g = resize(g[top:top + ch, left:left + cw], (rows, cols), anti_aliasing=True)
    lo, hi = np.percentile(g, [1.0, 99.0])
    if not hi > lo:
        raise ReconInputError("image is flat (1st and 99th percentiles equal); nothing to show")
    return np.clip((g - lo) / (hi - lo), 0.0, 1.0).astype(np.float32)


def centre_quarter(shape) -> tuple[slice, slice]:
    """Slices of the central ``G_y/2 x G_x/2`` region (the partial FoV of Table 7.1)."""
    gy, gx = (int(v) for v in shape)
    return (slice(gy // 4, gy // 4 + gy // 2), slice(gx // 4, gx // 4 + gx // 2))


def _psnr_ssim(result: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    from skimage.metrics import structural_similarity

    m_r = float(result.mean())
    scaled = result * (float(target.mean()) / m_r) if m_r > 0 else result
    t = np.clip(target, 0.0, 1.0)
    r = np.clip(scaled, 0.0, 1.0)
    mse = float(np.mean((t - r) ** 2))
    psnr = float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)
    ssim = float(structural_similarity(t, r, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                       use_sample_covariance=False))
    return psnr, ssim


def image_metrics(displayed, target, n_slm: int, order: int = 5) -> dict:
    """Filtered PSNR/SSIM of a displayed intensity against its target (step 5).

    Parameters
    ----------
    displayed : numpy.ndarray
        Simulated intensity, centred frame, ``(G_y, G_x)``, any scale.
    target : numpy.ndarray
        Target intensity in [0, 1], same shape.
    n_slm : int
        SLM pixel count (sets the Butterworth passband, Eq. 7.18).
    order : int
        Butterworth order.

    Returns
    -------
    dict
        ``psnr_full``, ``ssim_full``, ``psnr_centre``, ``ssim_centre`` (filtered,
        mean-normalised, clipped) and ``psnr_unfiltered`` (full FoV, no filter).

    Raises
    ------
    ReconInputError
        Mismatched shapes or non-finite values.
    """
    d = np.asarray(displayed, dtype=np.float64)
    t = np.asarray(target, dtype=np.float64)
    if d.shape != t.shape or d.ndim != 2:
        raise ReconInputError(f"displayed {d.shape} and target {t.shape} must be equal 2D shapes")
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(t))):
        raise ReconInputError("displayed or target image contains NaN or inf")
    h = butterworth_lowpass(d.shape, n_slm, order).astype(np.float64)
    dl, tl = lowpass(d, h), lowpass(t, h)
    out = {}
    out["psnr_full"], out["ssim_full"] = _psnr_ssim(dl, tl)
    c = centre_quarter(d.shape)
    out["psnr_centre"], out["ssim_centre"] = _psnr_ssim(dl[c], tl[c])
    m = float(d.mean())
    raw = np.clip(d * (float(t.mean()) / m) if m > 0 else d, 0.0, 1.0)
    mse = float(np.mean((np.clip(t, 0.0, 1.0) - raw) ** 2))
    out["psnr_unfiltered"] = float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)
    return out

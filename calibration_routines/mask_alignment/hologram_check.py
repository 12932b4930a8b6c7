"""The verification step's test hologram: captured frame against its simulation.

Step 7 of the alignment procedure (docs/protocols.md, "Mask alignment": a test hologram
captured and compared with its simulation; Kuo 2020, Sec. 7.4):
a phase hologram of a test photograph is computed for the *corrected* mask (the
model mask stitched from the alignment's per-section shifts), shown on the SLM and
captured, and the capture is compared with a perfectly aligned simulation of the
same corrected mask. A well-aligned bench reproduces the simulation's speckle
pixel for pixel (high PSNR and correlation); a mask off by a mask pixel or more
scrambles it.

Conventions (checked by ``tests/calibration_routines/test_hologram_check.py``):
the hologram grid of :class:`recon.cgh.ScatteringDisplay` is centred, grid
sample ``[i, j]`` is the far-field frequency ``u = (j - G_x // 2, i - G_y // 2)``
(x, y; far-field samples, cycles per SLM aperture) of
:mod:`recon.optics.holo_display`, and the camera sees it at
``camera_map.to_camera(u)``. Both models use the forward FFT of the field
``exp(i phase)`` (a blazed ramp ``2 pi (ux c / C + uy r / R)`` lands at ``+u``), so
there is no flip between them; the mask-pixel box of the fine model only dims the
image towards the edge of the field of view (``sinc^2``, 0.4 at ``|u| = G / 2``).
"""

from __future__ import annotations

import math
import time

import numpy as np

from instrument.acquisition.plan import PlanError
from recon.cgh import ScatteringDisplay, optimize_hologram
from recon.errors import ReconInputError
from recon.optics.holo_display import (
    CameraMapping,
    HolographicDisplayModel,
    MaskModel,
    RelayModel,
)

__all__ = ["compare_frames", "default_image", "hologram_check", "place_target", "target_region"]

#: Linear fraction of the largest visible rectangle the test image fills.
FILL = 0.9
#: Camera pixels kept clear of the frame edge when placing the target.
EDGE_PX = 2.0


def _grid_u(grid_shape) -> tuple[np.ndarray, np.ndarray]:
    """Far-field coordinates ``(ux, uy)`` of the centred grid's columns and rows."""
    gy, gx = grid_shape
    return np.arange(gx, dtype=np.float64) - gx // 2, np.arange(gy, dtype=np.float64) - gy // 2


def _inside(camera_map: CameraMapping, grid_shape, ux, uy) -> np.ndarray:
    """Whether far-field points lie on the hologram grid and on the camera (with a border)."""
    gy, gx = grid_shape
    ux = np.asarray(ux, np.float64)
    uy = np.asarray(uy, np.float64)
    c = camera_map.to_camera(np.stack(np.broadcast_arrays(ux, uy), axis=-1))
    rows, cols = camera_map.shape
    on_grid = (ux >= -(gx // 2)) & (ux <= (gx - 1) // 2) & (uy >= -(gy // 2)) \
        & (uy <= (gy - 1) // 2)
    on_cam = (c[..., 0] >= EDGE_PX) & (c[..., 0] <= cols - 1 - EDGE_PX) \
        & (c[..., 1] >= EDGE_PX) & (c[..., 1] <= rows - 1 - EDGE_PX)
    return on_grid & on_cam


def default_image() -> np.ndarray:
    """The bundled test photograph: scikit-image's ``camera`` (512 x 512, grey), float64 0-1.

    Shipped with scikit-image (no download).
    """
    from skimage.data import camera

    return camera().astype(np.float64) / 255.0


def place_target(image, camera_map: CameraMapping, grid_shape) -> tuple[np.ndarray, tuple]:
    """Put a test image on the hologram grid where the camera sees it.

    The image (aspect kept, anti-aliased resize) fills :data:`FILL` of the largest
    rectangle of its aspect ratio that is centred on the visible part of the grid
    (the grid points whose camera position, ``camera_map.to_camera(u)``, lies
    :data:`EDGE_PX` or more inside the frame) and lies wholly within it; the rest of
    the target is dark. The visible part is convex (a parallelogram cut by the
    grid), so a rectangle lies in it when its four corners do.

    Parameters
    ----------
    image : numpy.ndarray
        2-D real intensities (>= 0, finite, not all zero), any size >= 2 x 2; grey
        levels are taken as intensities.
    camera_map : recon.optics.holo_display.CameraMapping
        Far field -> camera pixels (the alignment's pre-flight affine).
    grid_shape : (int, int)
        Hologram grid ``(G_y, G_x) = (R k, C k)``, centred (zero order at
        ``(G_y // 2, G_x // 2)``).

    Returns
    -------
    target : numpy.ndarray
        float32 ``grid_shape``, the target intensity (0-1 for a 0-1 image).
    rect : (int, int, int, int)
        ``(i0, i1, j0, j1)``: grid rows ``i0:i1`` and columns ``j0:j1`` hold the image.

    Raises
    ------
    PlanError
        A bad image, or a camera that sees too little of the grid (fewer than 8 x 8
        grid points) to place it: check ``camera_map``.
    """
    from skimage.transform import resize

    img = _check_image(image)
    gy, gx = (int(v) for v in grid_shape)
    ux, uy = _grid_u((gy, gx))
    vis = _inside(camera_map, (gy, gx), ux[None, :], uy[:, None])
    if vis.sum() < 64:
        raise PlanError(f"the camera sees only {int(vis.sum())} points of the hologram's far-field "
                        f"grid {gy}x{gx} (u within +-{gx // 2}, +-{gy // 2} samples); check "
                        "camera_map (its shape, matrix and offset come from the pre-flight)")
    ii, jj = np.nonzero(vis)
    cy, cx = float(uy[ii].mean()), float(ux[jj].mean())
    aspect = img.shape[1] / img.shape[0]

    def fits(h: float) -> bool:
        hy, hx = h / 2.0, h * aspect / 2.0
        cu = np.array([cx - hx, cx + hx, cx - hx, cx + hx])
        cv = np.array([cy - hy, cy - hy, cy + hy, cy + hy])
        return bool(np.all(_inside(camera_map, (gy, gx), cu, cv)))

    lo, hi = 0.0, float(max(gy, gx / aspect))
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    h = max(2, int(math.floor(FILL * lo)))
    w = max(2, int(math.floor(FILL * lo * aspect)))
    i0 = int(round(cy - h / 2.0)) + gy // 2
    j0 = int(round(cx - w / 2.0)) + gx // 2
    i0, j0 = min(max(i0, 0), gy - h), min(max(j0, 0), gx - w)
    target = np.zeros((gy, gx), np.float32)
    target[i0:i0 + h, j0:j0 + w] = resize(img, (h, w), anti_aliasing=True, mode="reflect")
    np.maximum(target, 0.0, out=target)
    if not np.any(target):
        raise PlanError("the test image is all dark at the placed size; use a brighter image")
    return target, (i0, i0 + h, j0, j0 + w)


def target_region(camera_map: CameraMapping, grid_shape, rect) -> np.ndarray:
    """Camera pixels that see the target's rectangle of the hologram grid.

    Parameters
    ----------
    camera_map : recon.optics.holo_display.CameraMapping
    grid_shape : (int, int)
        ``(G_y, G_x)`` of the centred hologram grid.
    rect : (int, int, int, int)
        ``(i0, i1, j0, j1)`` from :func:`place_target`.

    Returns
    -------
    numpy.ndarray
        bool ``camera_map.shape``: pixels whose far-field position
        (``camera_map.to_far_field``) lies within the rectangle's grid points.
    """
    gy, gx = (int(v) for v in grid_shape)
    i0, i1, j0, j1 = (int(v) for v in rect)
    rows, cols = camera_map.shape
    yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float64)
    u = camera_map.to_far_field(np.stack([xx, yy], axis=-1))
    gj = u[..., 0] + gx // 2
    gi = u[..., 1] + gy // 2
    return (gi >= i0) & (gi <= i1 - 1) & (gj >= j0) & (gj <= j1 - 1)


def compare_frames(captured, simulated, region) -> dict:
    """PSNR, SSIM and correlation of a captured frame against its simulation.

    Each frame is divided by its mean over ``region`` (laser power, exposure and
    gain cancel); PSNR (:func:`skimage.metrics.peak_signal_noise_ratio`) is taken
    over the region's pixels with the data range of the normalised simulation there,
    SSIM (:func:`skimage.metrics.structural_similarity`, 7 x 7 window, same data range)
    is the mean of the SSIM map over the region, and the correlation is Pearson's
    coefficient of the region's pixels.

    Parameters
    ----------
    captured, simulated : numpy.ndarray
        2-D real frames of the same shape (e.g. DN/s and e-/s), finite.
    region : numpy.ndarray
        bool, same shape, at least 7 x 7 pixels across (SSIM's window).

    Returns
    -------
    dict
        ``psnr_db``, ``ssim``, ``correlation`` (floats; None when the capture has no
        light in the region), ``data_range`` (of the normalised simulation),
        ``region_pixels`` and ``energy_in_region_simulated`` /
        ``energy_in_region_captured`` (fraction of each frame's energy in the region).

    Raises
    ------
    PlanError
        Mismatched shapes, NaN/inf, a region too small for SSIM, or a simulation
        without light or contrast in the region.
    """
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    cap = np.asarray(captured, np.float64)
    sim = np.asarray(simulated, np.float64)
    reg = np.asarray(region, bool)
    if cap.ndim != 2 or cap.shape != sim.shape or reg.shape != sim.shape:
        raise PlanError(f"captured {cap.shape}, simulated {sim.shape} and region {reg.shape} "
                        "must be 2-D frames of one shape; simulate with the camera's own "
                        "CameraMapping (its shape is the camera's)")
    if not (np.all(np.isfinite(cap)) and np.all(np.isfinite(sim))):
        raise PlanError("captured or simulated frame contains NaN or inf")
    ii, jj = np.nonzero(reg)
    if ii.size == 0 or ii.max() - ii.min() < 6 or jj.max() - jj.min() < 6:
        raise PlanError(f"the target covers {ii.size} camera pixels, too few for SSIM (7 x 7): "
                        "check camera_map, or use a camera that sees more of the far field")
    sim_mean = float(sim[reg].mean())
    if not sim_mean > 0:
        raise PlanError("the simulation puts no light on the target region; check the hologram "
                        "and camera_map")
    a = sim / sim_mean
    data_range = float(a[reg].max() - a[reg].min())
    if not data_range > 0:
        raise PlanError("the simulated target region is uniform (data range 0): PSNR undefined")
    out = {"psnr_db": None, "ssim": None, "correlation": None, "data_range": data_range,
           "region_pixels": int(ii.size),
           "energy_in_region_simulated": float(sim[reg].sum() / sim.sum()),
           "energy_in_region_captured": None}
    cap_mean = float(cap[reg].mean())
    if not cap_mean > 0:
        return out
    b = cap / cap_mean
    out["energy_in_region_captured"] = float(cap[reg].sum() / cap.sum())
    out["psnr_db"] = float(peak_signal_noise_ratio(a[reg], b[reg], data_range=data_range))
    win = (slice(ii.min(), ii.max() + 1), slice(jj.min(), jj.max() + 1))
    _, smap = structural_similarity(a[win], b[win], data_range=data_range, full=True)
    out["ssim"] = float(smap[reg[win]].mean())
    out["correlation"] = float(np.corrcoef(a[reg], b[reg])[0, 1])
    return out


def hologram_check(meter, mask_model: MaskModel, corrected_mask: np.ndarray,
                   camera_map: CameraMapping, relay: RelayModel, *, target=None,
                   steps: int = 60, seed: int = 0) -> dict:
    """Show a test hologram for the corrected mask and compare its capture with simulation.

    Verification of the mask alignment (Kuo 2020, Sec. 7.4; docs/protocols.md,
    "Mask alignment", step 7: a test hologram captured and compared with its
    simulation):

    1. the target (default: scikit-image's ``camera`` photograph, grey) is placed on
       the centred ``R k x C k`` hologram grid where the camera sees it
       (:func:`place_target`);
    2. a phase hologram is optimised for the corrected mask
       (:class:`recon.cgh.ScatteringDisplay` with ``mask=corrected_mask``,
       :func:`recon.cgh.optimize_hologram`, frequency loss);
    3. it is shown on the SLM and captured (``meter.show``, ``meter.frame``:
       auto-exposed, averaged, dark-subtracted);
    4. the expected frame is simulated for a perfectly aligned corrected mask
       (:class:`recon.optics.holo_display.HolographicDisplayModel` with
       ``MaskModel(..., bits=corrected_mask, margin=0, supersample=1)``, the design
       ``relay`` and ``camera_map``; ideal SLM: linear phase, fill factor 1);
    5. both are compared over the camera pixels that see the target
       (:func:`target_region`, :func:`compare_frames`).

    Parameters
    ----------
    meter : calibration_routines.mask_alignment.SpotMeter
        Set up on the bench (:meth:`~SpotMeter.measure_dark` has run).
    mask_model : recon.optics.holo_display.MaskModel
        The software's mask model: only ``slm_shape``, ``slm_pitch_um``, ``k`` and
        ``q`` are used (never its ground truth).
    corrected_mask : numpy.ndarray
        float32 +1/-1 ``(R k, C k)``, the SLM footprint at mask resolution, as made
        by :func:`~calibration_routines.mask_alignment.corrected_mask` (the model
        with each section's integer shift applied); uint8 0/1 bits are accepted too.
    camera_map : recon.optics.holo_display.CameraMapping
        Far-field samples -> camera pixels, measured in the alignment's pre-flight;
        its shape must be the camera frame's.
    relay : recon.optics.holo_display.RelayModel
        The design relay (wavelength, NA).
    target : numpy.ndarray, optional
        2-D test image (intensities >= 0, any size; placed and resized by
        :func:`place_target`); default the ``camera`` photograph.
    steps : int
        Hologram optimiser steps (its iterations, >= 1;
        :func:`recon.cgh.optimize_hologram`'s ``steps``); 60 take about 0.8 s for
        384 x 480.
    seed : int
        Seed of the optimiser's one-step start.

    Returns
    -------
    dict
        JSON-ready: ``psnr_db``, ``ssim``, ``correlation`` (None when no light was
        captured on the target; PSNR is ``inf`` only for a capture identical to the
        simulation), ``data_range``, ``region_pixels``,
        ``energy_in_region_simulated`` / ``energy_in_region_captured`` (see
        :func:`compare_frames`), ``exposure_s``, ``peak_fraction``, ``railed``,
        ``frames``, ``pattern_id``, ``frame_shape``, ``slm_shape``, ``grid_shape``,
        ``target`` (its name), ``target_shape`` and ``target_rect`` (``[i0, i1, j0,
        j1]`` on the grid), ``iterations``, ``hologram_loss``, ``hologram_seconds``,
        ``simulation_seconds``, ``normalisation``.

    Raises
    ------
    PlanError
        A meter without ``show``/``frame``, wrong model types, a corrected mask of
        the wrong shape or not +1/-1, a bad target, a camera frame whose shape is not
        ``camera_map.shape``, or a camera that sees too little of the far field.
    instrument.acquisition.exposure.ExposureError
        From the meter: the hologram saturates at the shortest exposure.
    """
    if not (callable(getattr(meter, "show", None)) and callable(getattr(meter, "frame", None))):
        raise PlanError(f"meter must be a SpotMeter (show and frame), got {type(meter).__name__}")
    for name, val, typ in (("mask_model", mask_model, MaskModel),
                           ("camera_map", camera_map, CameraMapping), ("relay", relay, RelayModel)):
        if not isinstance(val, typ):
            raise PlanError(f"{name} must be a {typ.__name__}, got {type(val).__name__}")
    rows, cols = mask_model.slm_shape
    k = mask_model.k
    grid = (rows * k, cols * k)
    cm = np.asarray(corrected_mask)
    if cm.shape != grid:
        raise PlanError(f"corrected_mask has shape {cm.shape}; the SLM footprint at mask "
                        f"resolution is {grid} = SLM {mask_model.slm_shape} x k {k}: pass the "
                        "corrected_mask of the alignment record for this mask model")
    try:
        ideal = MaskModel(mask_model.slm_shape, mask_model.slm_pitch_um, k, mask_model.q,
                          margin=0, supersample=1, bits=cm)
        display = ScatteringDisplay(mask_model.slm_shape, k, mask=ideal.model,
                                    slm_pitch_um=mask_model.slm_pitch_um)
    except ReconInputError as exc:
        raise PlanError(f"corrected_mask: {exc}") from None
    name = "skimage.data.camera" if target is None else "user"
    image = default_image() if target is None else target
    placed, rect = place_target(image, camera_map, grid)
    region = target_region(camera_map, grid, rect)
    try:
        holo = optimize_hologram(display, placed, steps=steps, seed=seed)
    except ReconInputError as exc:
        raise PlanError(f"test hologram: {exc}") from None
    pattern = meter.show(holo.phase)
    frame, exposure, peak, railed, n = meter.frame()
    if tuple(frame.shape) != tuple(camera_map.shape):
        raise PlanError(f"camera frame {tuple(frame.shape)} differs from camera_map.shape "
                        f"{tuple(camera_map.shape)}; measure the camera mapping with this "
                        "camera's current ROI and binning")
    t0 = time.perf_counter()
    sim = HolographicDisplayModel(ideal, relay=relay, camera=camera_map).render_phase(holo.phase)
    sim_s = time.perf_counter() - t0
    out = compare_frames(frame, sim, region)
    out.update({
        "exposure_s": float(exposure), "peak_fraction": float(peak), "railed": bool(railed),
        "frames": int(n), "pattern_id": None if pattern is None else int(pattern),
        "frame_shape": [int(v) for v in frame.shape], "slm_shape": [rows, cols],
        "grid_shape": list(grid), "target": name,
        "target_shape": [int(v) for v in np.shape(image)], "target_rect": list(rect),
        "iterations": int(holo.iterations), "hologram_loss": float(holo.loss),
        "hologram_seconds": float(holo.seconds), "simulation_seconds": sim_s,
        "normalisation": "each frame divided by its mean over the target region",
    })
    return out


def _check_image(image) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 2 or a.dtype.kind not in "fiu" or min(a.shape) < 2:
        raise PlanError(f"target must be a 2-D grey image (real numbers, at least 2 x 2), got "
                        f"shape {a.shape} dtype {a.dtype}; convert a colour image with "
                        "skimage.color.rgb2gray")
    a = a.astype(np.float64)
    if not np.all(np.isfinite(a)):
        raise PlanError("target contains NaN or inf")
    if np.any(a < 0) or not np.any(a > 0):
        raise PlanError("target must be intensities >= 0 with some light (not all zero)")
    return a

"""Numba kernel of the lensless ray tracer (see :mod:`recon.optics.lensless`).

One pass per ray: exact incidence direction from the point source, refraction at
the flat input face and at the textured output face (vector Snell's law, thin
element: the ray leaves from the point where it entered), straight propagation to
the sensor plane, and a bilinear splat of the ray's photon weight onto the fine
sensor grid. Rays are split into a fixed number of row chunks, each splatting into
its own buffer, so the result does not depend on the thread count.
"""

from __future__ import annotations

import math

from ..jit import PARALLEL, njit, prange

#: Ray-row chunks (and per-chunk output buffers); fixed for determinism.
CHUNKS = 4


@njit(**PARALLEL)
def trace(gx, gy, surf_pitch, n, xs, ys, zs, power, d, half_w, half_h, nx, ny,
          inv_two_sigma2, fine_pitch, off_x, off_y, out):
    """Accumulate one point source's rays into ``out`` (CHUNKS, H, W), float64.

    Lengths in mm. ``gx, gy``: surface slopes (rows, cols) on a grid of pitch
    ``surf_pitch`` centred on the axis; the aperture [-half_w, half_w] x
    [-half_h, half_h] is sampled by ``nx x ny`` rays at cell centres; the source at
    (xs, ys, -zs) has total power ``power`` (isotropic). ``inv_two_sigma2`` is
    1/(2 sigma^2) of the pixel fall-off (0 disables it). The fine sensor grid
    (H, W) of pitch ``fine_pitch`` is centred on (off_x, off_y).
    Returns nothing; adds to ``out``.
    """
    srows, scols = gx.shape
    cj = 0.5 * (scols - 1)
    ci = 0.5 * (srows - 1)
    nchunks, hh, ww = out.shape
    cx = 0.5 * (ww - 1)
    cy = 0.5 * (hh - 1)
    dx = 2.0 * half_w / nx
    dy = 2.0 * half_h / ny
    w_area = power * dx * dy / (4.0 * math.pi)
    for c in prange(nchunks):
        buf = out[c]
        r_lo = (c * ny) // nchunks
        r_hi = ((c + 1) * ny) // nchunks
        for iy in range(r_lo, r_hi):
            yd = (iy + 0.5) * dy - half_h
            fi = yd / surf_pitch + ci
            i0 = int(math.floor(fi))
            if i0 < 0:
                i0 = 0
            if i0 > srows - 2:
                i0 = srows - 2
            ti = fi - i0
            vy = yd - ys
            for ix in range(nx):
                xd = (ix + 0.5) * dx - half_w
                fj = xd / surf_pitch + cj
                j0 = int(math.floor(fj))
                if j0 < 0:
                    j0 = 0
                if j0 > scols - 2:
                    j0 = scols - 2
                tj = fj - j0
                a00 = (1.0 - ti) * (1.0 - tj)
                a01 = (1.0 - ti) * tj
                a10 = ti * (1.0 - tj)
                a11 = ti * tj
                sx = (a00 * gx[i0, j0] + a01 * gx[i0, j0 + 1] + a10 * gx[i0 + 1, j0]
                      + a11 * gx[i0 + 1, j0 + 1])
                sy = (a00 * gy[i0, j0] + a01 * gy[i0, j0 + 1] + a10 * gy[i0 + 1, j0]
                      + a11 * gy[i0 + 1, j0 + 1])
                # incidence from the source: exact direction, 1/r^2 and obliquity
                vx = xd - xs
                r2 = vx * vx + vy * vy + zs * zs
                r = math.sqrt(r2)
                w = w_area * zs / (r * r2)
                ux_ = vx / r
                uy_ = vy / r
                # flat input face (normal +Z): tangential component / n
                tx = ux_ / n
                ty = uy_ / n
                tz = math.sqrt(1.0 - tx * tx - ty * ty)
                # textured output face, normal towards the glass: (sx, sy, -1)/N
                nn = 1.0 / math.sqrt(1.0 + sx * sx + sy * sy)
                nx_ = sx * nn
                ny_ = sy * nn
                nz_ = -nn
                c1 = -(nx_ * tx + ny_ * ty + nz_ * tz)
                k = 1.0 - n * n * (1.0 - c1 * c1)
                if k <= 0.0:
                    continue  # total internal reflection
                a = n * c1 - math.sqrt(k)
                ox = n * tx + a * nx_
                oy = n * ty + a * ny_
                oz = n * tz + a * nz_
                if oz <= 0.0:
                    continue
                if inv_two_sigma2 > 0.0:
                    th = math.acos(min(oz, 1.0))
                    w *= math.exp(-th * th * inv_two_sigma2)
                ux = xd + ox / oz * d
                uy = yd + oy / oz * d
                fx = (ux - off_x) / fine_pitch + cx
                fy = (uy - off_y) / fine_pitch + cy
                if fx <= -1.0 or fy <= -1.0 or fx >= ww or fy >= hh:
                    continue
                x0 = int(math.floor(fx))
                y0 = int(math.floor(fy))
                bx = fx - x0
                by = fy - y0
                if y0 >= 0:
                    if x0 >= 0:
                        buf[y0, x0] += w * (1.0 - by) * (1.0 - bx)
                    if x0 + 1 < ww:
                        buf[y0, x0 + 1] += w * (1.0 - by) * bx
                if y0 + 1 < hh:
                    if x0 >= 0:
                        buf[y0 + 1, x0] += w * by * (1.0 - bx)
                    if x0 + 1 < ww:
                        buf[y0 + 1, x0 + 1] += w * by * bx

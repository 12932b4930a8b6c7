"""The scattering display model through the array API (CuPy, PyTorch, any conforming array).

The generic twin of :class:`recon.cgh.scattering_display.ScatteringDisplay`'s operator and
of the numba kernels :func:`recon.cgh._kernels.upsample_multiply` and
:func:`~recon.cgh._kernels.bin_conj_multiply`, written with whole-array operations of the
Python array API standard (``array-api-compat``) so the same code runs on the CPU or a
GPU. The masks are copied to the device once; the box upsampling ``U`` (Eq. 7.15) is a
broadcast product and its transpose ``U^T`` a sum over the ``k x k`` blocks, so the
upsampled field is never stored on its own.

Frames: :meth:`XpDisplay.fields` and :meth:`XpDisplay.back` work in the raw frame of
``fft2`` (as :class:`recon.cgh.optimize._Engine` does); :meth:`XpDisplay.adjoint` takes
the centred frame of :meth:`ScatteringDisplay.adjoint`.
"""

from __future__ import annotations

import numpy as np

from ..backend import Backend

__all__ = ["XpDisplay"]


class XpDisplay:
    """A :class:`~recon.cgh.scattering_display.ScatteringDisplay` on a backend's device.

    Parameters
    ----------
    display : ScatteringDisplay
        The model (masks, ``k``, planes); its NumPy masks are copied to the device.
    backend : recon.backend.Backend
        Where the arrays live (``backend.xp`` the namespace, ``backend.device``).

    Attributes
    ----------
    masks : list of arrays
        ``m_z`` per plane on the device, ``grid_shape`` (float32 for a real mask at
        ``z = 0``, else complex64).
    energy : array
        float32 ``slm_shape``: ``U^T |m|^2`` (:attr:`ScatteringDisplay.mask_energy`).
    """

    def __init__(self, display, backend: Backend):
        self.display = display
        self.xp = backend.xp
        self.device = backend.device
        self.k = display.k
        self.slm_shape = tuple(display.slm_shape)
        self.grid = tuple(display.grid_shape)
        self.masks = [self.asarray(m) for m in display.plane_masks]
        self.energy = self.asarray(display.mask_energy)

    def asarray(self, a):
        """A NumPy array (or any array-like) as an array on the device, dtype kept."""
        if isinstance(a, np.ndarray):  # C order, writable (PyTorch shares CPU memory)
            a = np.require(a, requirements=["C", "W"])
        return self.xp.asarray(a, device=self.device)

    def _blocks(self, a):
        """``a`` (``grid_shape``) viewed as ``(N_y, k, N_x, k)`` blocks of SLM pixels."""
        ny, nx = self.slm_shape
        return self.xp.reshape(a, (ny, self.k, nx, self.k))

    def upsample_multiply(self, s, plane: int):
        """``m_z (U s)`` on the mask grid (Eq. 7.15 times the mask), complex64.

        Parameters
        ----------
        s : array
            complex64 ``slm_shape`` on the device.
        plane : int
            Plane index.

        Returns
        -------
        array
            complex64 ``grid_shape``.
        """
        ny, nx = self.slm_shape
        xp = self.xp
        prod = self._blocks(self.masks[plane]) * xp.reshape(s, (ny, 1, nx, 1))
        return xp.reshape(prod, self.grid)

    def bin_conj_multiply(self, x, plane: int):
        """``U^T (conj(m_z) x)``: the sum over each ``k x k`` block (Eq. A.9), complex64.

        Parameters
        ----------
        x : array
            complex64 ``grid_shape``.
        plane : int

        Returns
        -------
        array
            complex64 ``slm_shape``.
        """
        xp = self.xp
        m = self.masks[plane]
        prod = (xp.conj(m) if xp.isdtype(m.dtype, "complex floating") else m) * x
        return xp.sum(self._blocks(prod), axis=(1, 3))

    def fields(self, s) -> list:
        """``fft2(m_z U s)`` per plane, unitary, raw frame (zero order at index 0)."""
        fft = self.xp.fft
        return [fft.fftn(self.upsample_multiply(s, p), axes=(-2, -1), norm="ortho")
                for p in range(len(self.masks))]

    def back(self, y, plane: int):
        """``U^T conj(m_z) ifft2(y)`` for one plane's raw-frame field ``y``, complex64
        ``slm_shape`` (the adjoint of :meth:`fields` for that plane)."""
        x = self.xp.fft.ifftn(y, axes=(-2, -1), norm="ortho")
        return self.bin_conj_multiply(x, plane)

    def adjoint(self, y):
        """``U^T sum_z conj(m_z) F_c^H y_z`` (:meth:`ScatteringDisplay.adjoint`).

        Parameters
        ----------
        y : array
            complex64 ``(n_planes, *grid_shape)`` on the device, centred frame.

        Returns
        -------
        array
            complex64 ``slm_shape``.
        """
        fft = self.xp.fft
        acc = None
        for p in range(len(self.masks)):
            x = fft.fftshift(fft.ifftn(fft.ifftshift(y[p, ...], axes=(-2, -1)), axes=(-2, -1),
                                       norm="ortho"), axes=(-2, -1))
            part = self.bin_conj_multiply(x, p)
            acc = part if acc is None else acc + part
        return acc

    def power(self, s) -> float:
        """``sum I`` on each plane: ``sum mask_energy |s|^2`` (Parseval), a float."""
        xp = self.xp
        return float(xp.sum(self.energy * (xp.real(s) ** 2 + xp.imag(s) ** 2)))

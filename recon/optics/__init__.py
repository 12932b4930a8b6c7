"""Optics models (layer 1, numerics only): propagation, PSF synthesis and holography.

Import the submodules directly (this package imports nothing, so ``import
recon.optics`` stays light and compiles no numba kernels):

* :mod:`recon.optics.diffuser` - diffuser surfaces (smooth random, random microlens).
* :mod:`recon.optics.lensless_geometry` - the lensless bench geometry and the
  default bench geometries.
* :mod:`recon.optics.lensless` - ray-traced lensless PSFs and local-convolution scene
  rendering (re-exports the geometry).
* :mod:`recon.optics.holo_display` - the holographic display bench as built
  (SLM, relay, random mask, Fourier lens, camera).
"""

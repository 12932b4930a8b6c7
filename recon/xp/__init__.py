"""The array-API (generic) path of the numerics that matter for speed.

One implementation for any array library that follows the Python array API standard
(CuPy and PyTorch on a GPU or the CPU, ``array-api-strict`` in the tests), reached
through ``array-api-compat``. The solvers of the NumPy path dispatch here at their
entry when the measurement is not a ``numpy.ndarray`` (:mod:`recon.backend`); the
NumPy path keeps its numba kernels.

Generic today: the 2D and 3D convolution models (:mod:`recon.xp.operators`), 2D FISTA
and gradient descent (:mod:`recon.xp.fista`), 2D ADMM (:mod:`recon.xp.admm`) and 3D ADMM
(:mod:`recon.xp.admm3d`). Nothing here is imported by a CPU reconstruction.
"""

"""Image priors of the ADMM's u split: TV, wavelet sparsity and a learned denoiser.

Every ADMM of the project solves min_x f(M x) + g(G_u x) + i_+(x) in the split of
Eq. 4.5 / App. A.3 (Kuo 2020); the prior is the pair (G_u, prox of g). A prior here is
that pair's proximal half, a plain function on arrays, so TV, l1 of wavelet
coefficients and plug-and-play denoisers share one loop, its stopping rule and its
penalty balancing (:func:`recon.solvers.admm_loop.run_admm`):

* :class:`TotalVariation` -- anisotropic TV (Eq. 3.9): G_u the finite differences,
  prox the soft threshold at ``weight / mu2`` (the project's default prior).
* :class:`IsotropicTV` -- isotropic TV: the same G_u, prox the group soft threshold
  of each pixel's difference vector (no preference for the grid's axes).
* :class:`TgvPrior` -- second-order total generalised variation (Bredies, Kunisch &
  Pock 2010), a0/a1 = 2: G_u the identity, the prox the TGV denoising step solved by
  a few primal-dual iterations (Chambolle & Pock 2011); piecewise-affine images
  without TV's staircase.
* :class:`WaveletPrior` -- l1 of orthonormal wavelet detail coefficients
  (symlets, PyWavelets), G_u the identity, prox the soft threshold of the
  coefficients averaged over a few circular shifts (translation-invariant
  denoising by cycle spinning, Coifman & Donoho 1995).
* :class:`DncnnPrior` -- plug-and-play (Venkatakrishnan, Bouman & Wohlberg 2013):
  G_u the identity, the prox replaced by a small DnCNN (Zhang et al. 2017)
  conditioned on the noise level (FFDNet's sigma map, Zhang, Zuo & Zhang 2018),
  shipped with the package as ONNX (``dncnn.onnx``, trained by
  ``scripts/train_dncnn.py`` on scikit-image images the benchmarks do not use) and
  run by onnxruntime. Nothing is downloaded.

The priors whose G_u is the identity are applied over the whole padded object grid
(the field of view and the rim the crop split leaves free), as the TV split is.

:data:`PRIORS` names them for the command line (``--prior tv|tv-iso|tgv|wavelet|dncnn|auto``);
:func:`prior_of` makes one from its name.
"""

from __future__ import annotations

from ..errors import ReconInputError
from .base import Prior, TotalVariation
from .dncnn import DncnnPrior
from .tgv import TgvPrior
from .tv_iso import IsotropicTV
from .wavelet import WaveletPrior

__all__ = ["AUTO_PRIORS", "PRIORS", "DncnnPrior", "IsotropicTV", "Prior", "TgvPrior",
           "TotalVariation", "WaveletPrior", "prior_of"]

#: The priors by name, simplest first.
PRIORS: tuple[str, ...] = ("tv", "tv-iso", "tgv", "wavelet", "dncnn")

#: The candidates of the automatic choice (``--prior auto``), simplest first: it
#: prefers the earlier of priors that predict the held-out pixels equally well.
#: Isotropic TV and TGV are not among them (not measured in that choice).
AUTO_PRIORS: tuple[str, ...] = ("tv", "wavelet", "dncnn")


def prior_of(name) -> Prior:
    """The prior named ``name`` (one of :data:`PRIORS`), ``name`` itself when it is a
    :class:`Prior` already, or TV for None (the solvers' default).

    Raises
    ------
    ReconInputError
        An unknown name (the message lists the known ones).
    """
    if isinstance(name, Prior):
        return name
    if name is None:
        return TotalVariation()
    makers = {"tv": TotalVariation, "tv-iso": IsotropicTV, "tgv": TgvPrior,
              "wavelet": WaveletPrior, "dncnn": DncnnPrior}
    if name not in makers:
        raise ReconInputError(f"prior {name!r}: use one of {', '.join(PRIORS)} (or 'auto' "
                              "where the command chooses)")
    return makers[name]()

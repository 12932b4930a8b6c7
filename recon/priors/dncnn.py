"""Plug-and-play prior: a small noise-level-conditioned DnCNN run by onnxruntime."""

from __future__ import annotations

import json
import threading
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import ReconInputError
from .base import Prior, on_host, put_like

__all__ = ["DEFAULT_MODEL", "DncnnPrior"]

#: The shipped weights (``scripts/train_dncnn.py``; settings and training images in
#: the ``.json`` beside it).
DEFAULT_MODEL = "dncnn.onnx"
#: Quantile of the split's values that sets the denoiser's unit (the network was
#: trained on images in [0, 1]): robust to a few hot pixels.
SCALE_QUANTILE = 0.999

_SESSIONS: dict = {}
_LOCK = threading.Lock()


def _session(path: Path, providers: tuple[str, ...]):
    """One onnxruntime session per model file and providers in this process."""
    key = (str(path), providers)
    with _LOCK:
        if key not in _SESSIONS:
            try:
                import onnxruntime as ort
            except ImportError as exc:  # a core dependency: a broken install
                raise ReconInputError("the dncnn prior needs onnxruntime: pip install "
                                      "onnxruntime (or use --prior tv|wavelet)") from exc
            opts = ort.SessionOptions()
            opts.log_severity_level = 3
            _SESSIONS[key] = ort.InferenceSession(str(path), opts, providers=list(providers))
        return _SESSIONS[key]


class DncnnPrior(Prior):
    """Plug-and-play ADMM's denoising step (Venkatakrishnan, Bouman & Wohlberg 2013):
    the u-update z = D(t; sigma) with D a DnCNN (Zhang et al. 2017, residual learning)
    that takes the noise level as a second input channel (FFDNet, Zhang, Zuo & Zhang
    2018), so one network serves every strength.

    The u split is u = x (G_u the identity), over the whole padded object. The
    strength is the prior's ``weight`` itself: the noise level sigma relative to the
    iterate's scale (its 99.9 % quantile), independent of mu2, so residual balancing
    does not change how hard the step denoises (the form of the PnP-ADMM of Chan, Wang &
    Elgendy 2017 with a fixed sigma). There is no explicit g: the objective's prior term
    is 0 and the result's record says so.

    Parameters
    ----------
    model : str or Path, optional
        An ONNX file with input ``input`` (N, 2, H, W) float32 (image, sigma map) and
        output (N, 1, H, W); default the shipped :data:`DEFAULT_MODEL`.
    providers : tuple of str, optional
        onnxruntime execution providers; default CUDA where onnxruntime has it and the
        iterate is on a GPU, else the CPU (arrays on a device are copied to the host
        and back each iteration).

    Raises
    ------
    ReconInputError
        A model file that does not exist.

    Examples
    --------
    The camera (not among the training images) in white noise of 0.1, denoised at
    that level:

    >>> import numpy as np
    >>> from skimage import data
    >>> clean = data.camera()[::2, ::2].astype(np.float32) / 255
    >>> noise = np.random.default_rng(1).normal(0, 0.1, clean.shape).astype(np.float32)
    >>> out = DncnnPrior().denoise(clean + noise, 0.1)
    >>> bool(np.sqrt(np.mean((out - clean) ** 2)) < 0.5 * 0.1)
    True
    """

    name = "dncnn"
    identity_split = True

    def __init__(self, model: str | Path | None = None,
                 providers: tuple[str, ...] | None = None):
        if model is None:
            path = Path(str(resources.files(__package__) / DEFAULT_MODEL))
        else:
            path = Path(model)
        if not path.is_file():
            raise ReconInputError(f"denoiser model {path} not found; give an ONNX file or "
                                  "leave it out for the shipped DnCNN")
        self.path, self.providers = path, providers

    def _providers(self, on_device: bool) -> tuple[str, ...]:
        if self.providers is not None:
            return tuple(self.providers)
        import onnxruntime as ort

        if on_device and "CUDAExecutionProvider" in ort.get_available_providers():
            return ("CUDAExecutionProvider", "CPUExecutionProvider")
        return ("CPUExecutionProvider",)

    def denoise(self, a: np.ndarray, sigma: float, *, on_device: bool = False
                ) -> np.ndarray:
        """D(a; sigma) of a float32 image (H, W) or stack of planes (N, H, W) in the
        network's unit ([0, 1] images), sigma >= 0 in the same unit."""
        planes = a.reshape(-1, 1, *a.shape[-2:])
        inp = np.empty((planes.shape[0], 2, *a.shape[-2:]), np.float32)
        inp[:, :1] = planes
        inp[:, 1:] = np.float32(sigma)
        sess = _session(self.path, self._providers(on_device))
        return sess.run(None, {sess.get_inputs()[0].name: inp})[0].reshape(a.shape)

    def prox(self, xp, t: tuple, weight: float, mu2: float) -> tuple:
        (s,) = t
        if weight <= 0:
            return (s,)
        a = on_host(s)
        scale = float(np.quantile(a, SCALE_QUANTILE)) if a.size else 0.0
        if not scale > 0:
            scale = float(np.max(np.abs(a))) or 1.0
        z = self.denoise(a / np.float32(scale), weight,
                         on_device=not isinstance(s, np.ndarray)) * np.float32(scale)
        return (put_like(xp, z.astype(np.float32, copy=False), s),)

    def value(self, xp, x, g: tuple) -> float:
        return 0.0

    def training(self) -> dict:
        """The training record shipped beside the weights (empty for another model)."""
        meta = self.path.with_suffix(".json")
        return json.loads(meta.read_text()) if meta.is_file() else {}

    def record(self) -> dict:
        return {"prior": self.name, "model": self.path.name,
                "strength": "noise level relative to the iterate's 99.9 % quantile"}

    def __repr__(self) -> str:
        return f"DncnnPrior({self.path.name!r})"

"""Train the small noise-level-conditioned DnCNN shipped as ``recon/priors/dncnn.onnx``.

Run once by a maintainer (PyTorch and onnx needed here only, never at run time)::

    python scripts/train_dncnn.py --steps 3000 --out recon/priors/dncnn.onnx

The network is DnCNN (Zhang et al. 2017, "Beyond a Gaussian denoiser", IEEE TIP 26,
3142) made small (``--depth`` 3x3 convolutions of ``--features`` channels, ReLU, no
batch normalisation) and conditioned on the noise level as FFDNet is (Zhang, Zuo &
Zhang 2018): its input is two channels, the noisy image and a constant map of the
noise's standard deviation sigma, its output the noise estimate (residual learning),
so one set of weights serves every strength a plug-and-play ADMM asks for.

Training images: scikit-image's bundled images that the scene-suite benchmark
(``benchmarks.auto.SUITE``) does *not* use (:data:`TRAINING_IMAGES`), as grey levels in
[0, 1]; random 40 x 40 patches, flips and 90-degree turns, each with additive white
Gaussian noise of sigma uniform in [0, ``--max-sigma``]. The weights are written as
ONNX (opset 17, dynamic height and width) for onnxruntime, with a JSON sidecar that
records the training settings, the images and the final loss.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

#: scikit-image images bundled in its package, none of them in the scene suite
#: (camera, astronaut, coffee, chelsea, brick, gravel, page, hubble_deep_field and
#: the generated scenes).
TRAINING_IMAGES = ("grass", "coins", "moon", "rocket", "clock", "cell",
                   "immunohistochemistry", "retina", "cat", "colorwheel",
                   "shepp_logan_phantom", "horse")


def training_images() -> list[np.ndarray]:
    """The :data:`TRAINING_IMAGES` as float32 grey levels in [0, 1]."""
    import skimage.data
    from skimage.color import rgb2gray
    from skimage.util import img_as_float32

    out = []
    for name in TRAINING_IMAGES:
        im = getattr(skimage.data, name)()
        if im.ndim == 3:
            im = rgb2gray(im[..., :3])
        im = img_as_float32(im).astype(np.float32)
        out.append((im - im.min()) / max(float(im.max() - im.min()), 1e-6))
    return out


def build(depth: int, features: int):
    """The network: ``depth`` convolutions, the first and last without ReLU after."""
    import torch.nn as nn

    layers = [nn.Conv2d(2, features, 3, padding=1), nn.ReLU(inplace=True)]
    for _ in range(depth - 2):
        layers += [nn.Conv2d(features, features, 3, padding=1), nn.ReLU(inplace=True)]
    layers.append(nn.Conv2d(features, 1, 3, padding=1))
    body = nn.Sequential(*layers)

    class Dncnn(nn.Module):
        """Input (N, 2, H, W): image and sigma map; output (N, 1, H, W) denoised."""

        def __init__(self):
            super().__init__()
            self.body = body

        def forward(self, x):
            return x[:, :1] - self.body(x)

    return Dncnn()


def coloured(noise: np.ndarray, rng, patch: int, max_alpha: float) -> np.ndarray:
    """Half of the (N, 1, P, P) white ``noise`` patches made correlated: amplitude
    spectrum |f|^-alpha, alpha uniform in [0, ``max_alpha``], rescaled to unit
    variance (the ADMM iterate's error is correlated: the PSF's weak frequencies)."""
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(patch), np.fft.fftfreq(patch), indexing="ij"))
    f[0, 0] = f[0, 1]
    out = noise.copy()
    for k in range(0, noise.shape[0], 2):
        alpha = rng.uniform(0, max_alpha)
        c = np.real(np.fft.ifft2(np.fft.fft2(noise[k, 0]) * f ** -alpha))
        out[k, 0] = (c / max(float(c.std()), 1e-6)).astype(np.float32)
    return out


def batches(images, rng, patch: int, batch: int, max_sigma: float, colored: float = 0.0):
    """Endless (noisy input with sigma map, clean target) batches, float32; with
    ``colored`` > 0 half the patches get correlated noise (:func:`coloured`)."""
    while True:
        clean = np.empty((batch, 1, patch, patch), np.float32)
        for k in range(batch):
            im = images[rng.integers(len(images))]
            i, j = rng.integers(im.shape[0] - patch), rng.integers(im.shape[1] - patch)
            p = np.rot90(im[i:i + patch, j:j + patch], rng.integers(4))
            clean[k, 0] = p[:, ::-1] if rng.integers(2) else p
        sigma = rng.uniform(0, max_sigma, (batch, 1, 1, 1)).astype(np.float32)
        noise = rng.standard_normal(clean.shape).astype(np.float32)
        if colored:  # half the patches: noise of spectrum |f|^-alpha, unit variance
            noise = coloured(noise, rng, patch, colored)
        noisy = clean + sigma * noise
        inp = np.concatenate([noisy, np.broadcast_to(sigma, clean.shape)], axis=1)
        yield np.ascontiguousarray(inp), clean


def main(argv=None) -> int:
    """Train, report the loss and the PSNR gain on held-back patches, write ONNX."""
    import torch

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--depth", type=int, default=8)
    p.add_argument("--features", type=int, default=32)
    p.add_argument("--patch", type=int, default=40)
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--max-sigma", type=float, default=0.25)
    p.add_argument("--colored", type=float, default=0.0,
                   help="largest spectral exponent of correlated noise on half the "
                        "patches (0: white noise only)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, required=True)
    a = p.parse_args(argv)
    if a.out.exists():
        raise SystemExit(f"{a.out} exists: move it away first (nothing is overwritten)")
    torch.manual_seed(a.seed)
    torch.set_num_threads(a.threads)
    rng = np.random.default_rng(a.seed)
    images = training_images()
    net = build(a.depth, a.features)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, a.steps)
    t0, losses = time.time(), []
    for step, (inp, clean) in zip(range(a.steps), batches(images, rng, a.patch, a.batch,
                                                          a.max_sigma, a.colored),
                                  strict=False):
        out = net(torch.from_numpy(inp))
        loss = torch.mean((out - torch.from_numpy(clean)) ** 2)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        losses.append(loss.item())
        if (step + 1) % 200 == 0:
            print(f"step {step + 1}: mse {np.mean(losses[-200:]):.3g} "
                  f"({time.time() - t0:.0f} s)", flush=True)
    net.eval()
    check = {}
    test = batches(images, np.random.default_rng(a.seed + 1), 64, 64, a.max_sigma)
    inp, clean = next(test)
    with torch.no_grad():
        den = net(torch.from_numpy(inp)).numpy()
    for lo, hi in ((0.0, 0.05), (0.05, 0.15), (0.15, 0.25)):
        sel = (inp[:, 1, 0, 0] >= lo) & (inp[:, 1, 0, 0] < hi)
        if sel.any():
            mse_in = float(np.mean((inp[sel, :1] - clean[sel]) ** 2))
            mse_out = float(np.mean((den[sel] - clean[sel]) ** 2))
            check[f"sigma {lo}-{hi}"] = {"psnr_in_db": -10 * np.log10(mse_in),
                                         "psnr_out_db": -10 * np.log10(mse_out)}
    print(json.dumps(check, indent=1))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(net, torch.from_numpy(inp[:1]), str(a.out), input_names=["input"],
                      output_names=["denoised"], opset_version=17, dynamo=False,
                      dynamic_axes={"input": {0: "n", 2: "h", 3: "w"},
                                    "denoised": {0: "n", 2: "h", 3: "w"}})
    meta = {"network": "DnCNN (Zhang et al. 2017), noise-level map input (FFDNet, Zhang, Zuo "
                       "& Zhang 2018), residual learning, no batch normalisation",
            "depth": a.depth, "features": a.features, "patch": a.patch, "batch": a.batch,
            "steps": a.steps, "max_sigma": a.max_sigma, "colored": a.colored,
            "seed": a.seed,
            "images": list(TRAINING_IMAGES), "final_mse": float(np.mean(losses[-200:])),
            "held_back_check": check, "torch": torch.__version__,
            "train_seconds": time.time() - t0, "image_range": [0.0, 1.0]}
    a.out.with_suffix(".json").write_text(json.dumps(meta, indent=1) + "\n")
    print(f"wrote {a.out} ({a.out.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

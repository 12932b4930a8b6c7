"""``scripts/convert_scico_dncnn.py``: scico's flax DnCNN parameters as the ONNX file the
DnCNN prior runs, checked on a small network of random parameters in scico's layout
(the wheel itself is not needed): batch normalisation folded, circular padding, the
input minus the residual's image channel."""

from __future__ import annotations

import numpy as np
import pytest

from recon.priors.dncnn import DncnnPrior
from scripts.convert_scico_dncnn import build_onnx, layers, numpy_reference


def _random_state(depth: int, features: int, rng) -> dict:
    """flax's parameter tree of scico's DnCNNNet (kernels HWIO, 2 channels in and out)."""
    params = {"conv_start": {"kernel": rng.normal(0, 0.3, (3, 3, 2, features))},
              "conv_end": {"kernel": rng.normal(0, 0.1, (3, 3, features, 2))}}
    stats = {}
    for k in range(depth - 2):
        params[f"ConvBNBlock_{k}"] = {
            "Conv_0": {"kernel": rng.normal(0, 0.2, (3, 3, features, features))},
            "BatchNorm_0": {"scale": rng.uniform(0.5, 1.5, features),
                            "bias": rng.normal(0, 0.1, features)}}
        stats[f"ConvBNBlock_{k}"] = {"BatchNorm_0": {"mean": rng.normal(0, 0.2, features),
                                                     "var": rng.uniform(0.2, 2.0, features)}}
    def cast(tree: dict) -> dict:  # flax stores float32
        return {k: cast(v) if isinstance(v, dict) else v.astype(np.float32)
                for k, v in tree.items()}

    return {"params": cast(params), "batch_stats": cast(stats)}


def test_the_onnx_file_computes_the_stored_network(tmp_path):
    onnx = pytest.importorskip("onnx")  # the dev extra installs it
    rng = np.random.default_rng(0)
    # 12 blocks so that the ordering ConvBNBlock_2 < ConvBNBlock_10 matters
    state = _random_state(14, 6, rng)
    path = tmp_path / "net.onnx"
    onnx.save(build_onnx(layers(state), "test"), str(path))
    image = rng.random((17, 23)).astype(np.float32)  # odd sizes: the wrap is per axis
    got = DncnnPrior(path).denoise(image, 0.1)
    ref = numpy_reference(state, image, 0.1)
    assert np.max(np.abs(got - ref)) < 1e-4 * np.max(np.abs(ref))
    # a wrongly ordered block or a zero-padded border would not match
    shuffled = dict(state, params=dict(state["params"]))
    shuffled["params"]["ConvBNBlock_2"], shuffled["params"]["ConvBNBlock_10"] = (
        state["params"]["ConvBNBlock_10"], state["params"]["ConvBNBlock_2"])
    assert np.max(np.abs(numpy_reference(shuffled, image, 0.1) - ref)) > 1e-3

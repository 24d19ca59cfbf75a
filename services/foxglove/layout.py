"""The Foxglove layout of docs/foxglove-layout.json, built with foxglove-sdk's layout types: the scene in a 3D
panel seen from above, the learning curve, the feedback (its values and what each was credited to), the expression
panel (the camera and the expression read from it) and the log. Topics carry no run id, so it fits every session
log and the live bridge.

`python -m services.foxglove layout > docs/foxglove-layout.json` writes it (a test checks it is up to date).
In Foxglove: Layouts -> Import from file.
"""

from __future__ import annotations

import json

import foxglove.layouts as fl

# The default teacher ids: the simulated oracle and the face-video teacher (the expression panel's camera).
TEACHERS = ("oracle", "face")


def _plot(title: str, series: list[tuple[str, str]], x_path: str | None = None) -> fl.PlotPanel:
    config = fl.PlotConfig(paths=[fl.PlotSeries(value=v, label=label) for v, label in series], show_legend=True)
    if x_path:
        config.x_axis_val = "custom"
        config.x_axis_path = fl.PlotXAxisPath(value=x_path, enabled=True)
    return fl.PlotPanel(title=title, config=config)


def layout() -> fl.Layout:
    scene = fl.ThreeDeePanel(
        title="scene",
        config=fl.ThreeDeeConfig(
            fixed_frame="env",
            follow_mode="follow-none",
            camera_state=fl.ThreeDeeCameraState(
                distance=14.0,
                perspective=False,
                phi=0.0,
                target=(4.0, 4.0, 0.0),
                target_offset=(0.0, 0.0, 0.0),
                theta_offset=0.0,
            ),
            topics={
                t: fl.BaseRendererSceneUpdateTopicSettings(visible=True)
                for t in ("/scene/layout", "/scene/agent", "/scene/feedback")
            },
        ),
    )
    curve = _plot(
        "learning curve: return per episode",
        [("/episode.return", "return"), ("/episode.steps", "steps")],
        x_path="/episode.episode",
    )
    feedback = _plot(
        "feedback (+1 / -1) and credit weights",
        [(f"/feedback/{t}.value", f"{t}") for t in TEACHERS]
        + [(f"/credit/{t}.steps[:].weight", f"{t} credit weights") for t in TEACHERS],
    )
    credit = fl.RawMessagesPanel(title="last credit", config=fl.RawMessagesConfig(topic_path="/credit/oracle"))
    camera = fl.ImagePanel(
        title="camera", config=fl.ImageConfig(image_mode=fl.ImageModeConfig(image_topic="/camera/face"))
    )
    expression = _plot(
        "expression read from the face",
        [("/perception/face.probabilities.happy", "happy"), ("/perception/face.confidence", "confidence")],
    )
    weights = _plot("weights (L2 norm of each tensor)", [("/snapshot.tensors[:].norm", "norm")])
    log = fl.LogPanel(title="log")
    split = lambda direction, *items: fl.SplitContainer(  # noqa: E731
        direction=direction, items=[fl.SplitItem(proportion=p, content=c) for p, c in items]
    )
    learning = split("column", (1, curve), (1, feedback), (1, credit))
    expression_tab = split("column", (2, camera), (1, expression))
    right = fl.TabContainer(
        tabs=[
            fl.TabItem(title="learning", content=learning),
            fl.TabItem(title="expression", content=expression_tab),
            fl.TabItem(title="weights and log", content=split("column", (1, weights), (1, log))),
        ]
    )
    return fl.Layout(content=split("row", (3, scene), (2, right)))


def layout_json() -> str:
    return json.dumps(json.loads(layout().to_json()), indent=2) + "\n"


if __name__ == "__main__":
    from common.config import moved

    moved("python -m services.foxglove layout")

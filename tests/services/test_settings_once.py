"""Each setting of a live run is declared once: a field name declared (not inherited, not nested) by two config
classes of the run with different defaults is two copies that drift (issue 31: `oracle_delay` was "steps" in the
learner and "auto" in the launcher). Renamed flags keep working."""

from __future__ import annotations

import dataclasses
import typing

import pytest

from common.config import _default, parse_config

# The same word for settings of different things, each said why (not copies of one setting).
DIFFERENT_SETTINGS = {
    "port": "the router's port (launcher, 0: a free one) is not the console's web port or the Foxglove bridge's",
    "camera": "the console's webcam camera id (none: no panel) is not the perception service's source camera",
    "run": "the launcher's run name (none: a fresh unique one) names the run the services join (`live`)",
    "out": "the launcher's parent directory of runs is not the recorder's MCAP file",
    "teacher_id": "the oracle's id is not the face-video teacher's or the perception service's (`face`)",
    "step_unit": "the oracle's seconds per step (at 10 steps/s) is not face-video's (at its 3 steps/s)",
    "linger": "the recorder keeps recording after the last service; the Foxglove bridge keeps serving",
    "wait_for": "the actor waits for the learner; the perception service for nothing",
}


def run_config_classes() -> list[type]:
    """Every config class of a live run: the launcher's and what it nests, every service it can start, the
    console and its scripted person, and their bases."""
    from services.common.config import ActorConfig, FoxgloveConfig, LearnerConfig, RecorderConfig, TeacherConfig
    from services.console.config import ConsoleConfig
    from services.console.scripted import ScriptedConfig
    from services.launcher.config import UpConfig
    from services.perception.config import PerceptionLiveConfig
    from services.teacher.face_video import FaceVideoConfig

    todo: list[type] = [
        UpConfig,
        ScriptedConfig,
        ConsoleConfig,
        ActorConfig,
        LearnerConfig,
        TeacherConfig,
        RecorderConfig,
        FoxgloveConfig,
        PerceptionLiveConfig,
        FaceVideoConfig,
    ]
    seen: list[type] = []
    while todo:
        cls = todo.pop()
        if cls in seen or not dataclasses.is_dataclass(cls):
            continue
        seen.append(cls)
        todo += [b for b in cls.__mro__[1:] if dataclasses.is_dataclass(b)]
        for hint in typing.get_type_hints(cls).values():
            todo += [a for a in (hint, *typing.get_args(hint)) if isinstance(a, type)]
    return seen


def declarations(classes: list[type] | None = None) -> dict[str, list[tuple[str, object]]]:
    """Setting name -> (class, default) of every class that declares it itself (a nested group is no setting:
    its fields are)."""
    out: dict[str, list[tuple[str, object]]] = {}
    for cls in run_config_classes() if classes is None else classes:
        own, hints = cls.__dict__.get("__annotations__", {}), typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            group = [a for a in (hints[f.name], *typing.get_args(hints[f.name])) if dataclasses.is_dataclass(a)]
            if f.name in own and not group:
                out.setdefault(f.name, []).append((cls.__qualname__, _default(f)))
    return out


def differing(found: dict[str, list[tuple[str, object]]]) -> dict[str, list[tuple[str, object]]]:
    return {
        name: where
        for name, where in found.items()
        if len({repr(d) for _, d in where}) > 1 and name not in DIFFERENT_SETTINGS
    }


def test_the_walk_sees_the_run_s_classes():
    names = {cls.__qualname__ for cls in run_config_classes()}
    assert {
        "UpConfig",
        "ActorSettings",
        "LearnerSettings",
        "AgentConfig",
        "ObserverConfig",
        "Task",
        "ConsoleConfig",
        "ScriptedConfig",
        "LearnerConfig",
        "ActorConfig",
        "ServiceConfig",
    } <= names


def test_no_setting_is_declared_twice_with_different_defaults():
    assert differing(declarations()) == {}


def test_the_settings_issue_31_named_are_declared_once():
    found = declarations()
    for name in (
        "oracle_delay",
        "assumed_delay_probs",
        "rate",
        "episodes",
        "screen_delay",
        "screen_credit",
        "idle_updates",
        "end_grace",
        "weights_every",
        "max_ahead",
        "inbox_size",
        "update_interval",
    ):
        assert len(found[name]) == 1, (name, found[name])


def test_the_check_fails_on_a_copy_with_another_default():
    @dataclasses.dataclass(frozen=True)
    class Copy:
        rate: float = 2.0

    from services.common.config import ActorSettings

    found = differing(declarations([ActorSettings, Copy]))
    assert found == {"rate": [("ActorSettings", 0.0), (Copy.__qualname__, 2.0)]}


def test_the_launcher_gives_each_service_the_one_setting():
    from services.launcher.config import UpConfig

    up = parse_config(UpConfig, ["--rate", "5", "--end-grace", "1.5", "--oracle-delay", "auto", "--episodes", "2"])
    assert (up.actor.rate, up.learner.end_grace, up.actor.episodes) == (5.0, 1.5, 2)
    assert up.learner.resolved_oracle_delay(up.rate) == "learned"
    assert parse_config(UpConfig, []).learner.resolved_oracle_delay(0.0) == "steps"


@pytest.mark.parametrize(
    "old,new,read",
    [
        (["--learner-inbox", "128"], ["--inbox-size", "128"], lambda c: c.learner.inbox_size),
        (
            ["--assumed-delay-probs", "0,0.5,0.5"],
            ["--agent.assumed-delay-probs", "0,0.5,0.5"],
            lambda c: c.agent.assumed_delay_probs,
        ),
        (["--update-interval", "4"], ["--agent.update-interval", "4"], lambda c: c.agent.update_interval),
        (["--console-port", "9123"], ["--console.port", "9123"], lambda c: c.console.port),
    ],
)
def test_old_launcher_flags_keep_working(old, new, read):
    from services.launcher.config import UpConfig

    assert read(parse_config(UpConfig, old)) == read(parse_config(UpConfig, new))


def test_the_console_s_old_flag_keeps_working():
    from services.console.config import ConsoleConfig

    assert parse_config(ConsoleConfig, ["--start-on-first-page", "true"]).start_on_first_page


def test_an_unknown_old_flag_names_the_new_one(capsys):
    from services.launcher.config import UpConfig

    with pytest.raises(SystemExit):
        parse_config(UpConfig, ["--history-steps", "3"])
    assert "--agent.history-steps" in capsys.readouterr().err


def test_the_scripted_person_s_preset_pace_survives_a_given_episode_count():
    from services.console.scripted import ScriptedConfig, group_flags

    cfg = parse_config(ScriptedConfig, ["--episodes", "3", "--screen-delay", "uniform:0.2,4"])
    assert (cfg.episodes, cfg.rate) == (3, 2.0)
    assert group_flags(cfg, "actor") == ["--episodes", "3", "--rate", "2.0"]
    assert group_flags(cfg, "learner") == ["--screen-delay", "uniform:0.2,4", "--screen-credit", "onset"]


def test_python_callers_name_settings_as_their_flags():
    from common.core.task import Task
    from services.launcher.config import UpConfig

    up = UpConfig.flat(task=Task(env="maze", layout=2), seed=3, rate=2.0, update_interval=4, algo="dqn")
    assert up.agent is not None
    assert (up.task.layout, up.task.seed, up.actor.rate, up.agent.update_interval) == (2, 3, 2.0, 4)
    with pytest.raises(ValueError, match="unknown setting 'bogus'"):
        UpConfig.flat(bogus=1)

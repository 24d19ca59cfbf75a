"""compose.yaml: parses, one service per process plus a router, and every module, file and flag it names exists."""
from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = {"services.actor": "ActorConfig", "services.learner": "LearnerConfig", "services.teacher": "TeacherConfig",
           "services.recorder": "RecorderConfig"}


def compose() -> dict:
    return yaml.safe_load((ROOT / "compose.yaml").read_text())


def test_compose_parses_and_has_a_router_and_every_service():
    services = compose()["services"]
    assert {"router", "recorder", "learner", "teacher", "actor"} <= set(services)
    for name, svc in services.items():
        assert svc["command"][:2] == ["python", "-m"], name
        build = svc["build"]
        assert (ROOT / build["context"] / build["dockerfile"]).is_file()


@pytest.mark.parametrize("name", ["router", "recorder", "learner", "teacher", "actor"])
def test_every_command_names_an_existing_module_and_known_flags(name):
    import services.common.config as cfg
    from common.config import ConfigParser, add_config_arguments

    command = compose()["services"][name]["command"]
    module = command[2]
    assert importlib.util.find_spec(module) is not None, module
    flags = [a for a in command[3:] if a.startswith("--")]
    if module in CONFIGS:
        parser = ConfigParser()
        add_config_arguments(parser, getattr(cfg, CONFIGS[module]))
        known = {opt for action in parser._actions for opt in action.option_strings}
        assert set(flags) <= known, set(flags) - known
        # The values parse too (with the compose defaults substituted).
        argv = [a.replace("${HITL_ROUTER:-tcp/router:7447}", "tcp/router:7447").replace("${HITL_RUN:-demo}", "demo")
                for a in command[3:]]
        from common.config import parse_config

        config = parse_config(getattr(cfg, CONFIGS[module]), argv)
        assert dataclasses.is_dataclass(config)
    else:
        assert module == "services" and command[3] == "router"


@pytest.mark.parametrize("module", ["services.actor", "services.learner", "services.teacher", "services.recorder",
                                    "services.replay", "services"])
def test_every_service_has_help(module, capsys):
    import importlib

    cli = importlib.import_module(f"{module}.service" if module != "services" else "services.__main__")
    entry = getattr(cli, "cli", None) or cli.main
    with pytest.raises(SystemExit) as exc:
        entry(["--help"])
    assert exc.value.code == 0
    assert "usage" in capsys.readouterr().out

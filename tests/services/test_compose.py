"""compose.yaml is written from the graph `python -m services up` starts: the file is what `python -m services
compose` writes now, its services are the launcher's processes (plus a router), and each command parses to the
config the launcher gives that process."""

from __future__ import annotations

import importlib
import importlib.util
from pathlib import Path

import pytest
import yaml

from common.config import config_argv, parse_config
from services.launcher.compose import _ROUTER, _RUN, ROUTER, RUN, ComposeLaunch, compose_text, container_config
from services.launcher.config import Launch, UpConfig, build_processes

ROOT = Path(__file__).resolve().parents[2]


def compose() -> dict:
    return yaml.safe_load((ROOT / "compose.yaml").read_text())


def test_compose_yaml_is_what_the_command_writes_now():
    assert (ROOT / "compose.yaml").read_text() == compose_text(UpConfig()), "run: python -m services compose"


def test_its_services_are_the_launcher_s_processes_in_order(tmp_path):
    procs, _ = build_processes(Launch(UpConfig(), "r", tmp_path, "tcp/127.0.0.1:7447"))
    services = compose()["services"]
    assert list(services) == ["router"] + [p.name for p in procs]
    for p in procs:
        assert services[p.name]["command"][:3] == ["python", "-m", p.module]
    for name, svc in services.items():
        assert (ROOT / svc["build"]["context"] / svc["build"]["dockerfile"]).is_file(), name
        assert importlib.util.find_spec(svc["command"][2]) is not None, name


def test_each_command_parses_to_the_launcher_s_config():
    procs, _ = build_processes(ComposeLaunch(UpConfig()))
    services = compose()["services"]
    for spec in procs:
        argv = [a.replace(RUN, _RUN).replace(ROUTER, _ROUTER) for a in services[spec.name]["command"][3:]]
        assert parse_config(type(spec.config), argv) == container_config(spec), spec.name


def test_the_router_command_parses():
    command = compose()["services"]["router"]["command"]
    from common.wire.transport import RouterConfig

    assert command[:4] == ["python", "-m", "services", "router"]
    assert parse_config(RouterConfig, command[4:]).endpoint == "tcp/0.0.0.0:7447"


@pytest.mark.parametrize(
    "flags",
    [
        [],
        ["--teacher", "web", "--algo", "dqn", "--rate", "3", "--screen-delay", "uniform:0.2,4"],
        ["--teacher", "face-video", "--agent.lr", "0.0005", "--episodes", "3"],
    ],
)
def test_every_process_s_flags_give_back_its_config(tmp_path, flags):
    up = parse_config(UpConfig, flags)
    procs, _ = build_processes(Launch(up, "r", tmp_path, "tcp/127.0.0.1:7447"))
    for spec in procs:
        assert parse_config(type(spec.config), config_argv(spec.config)) == spec.config, spec.name


def test_a_changed_graph_is_caught(tmp_path):
    other = compose_text(parse_config(UpConfig, ["--episodes", "7"]))
    assert other != compose_text(UpConfig()) and "--episodes, '7'" in other


@pytest.mark.parametrize(
    "module",
    [
        "services.actor.service",
        "services.learner.start",
        "services.teacher.service",
        "services.recorder.service",
        "services.replay.service",
        "services.__main__",
    ],
)
def test_every_service_has_help(module, capsys):
    cli = importlib.import_module(module)
    entry = getattr(cli, "cli", None) or cli.main
    with pytest.raises(SystemExit) as exc:
        entry(["--help"])
    assert exc.value.code == 0
    assert "usage" in capsys.readouterr().out

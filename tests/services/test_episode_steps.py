"""`--episode-steps`: the actor's cut on episode length, validated at the edge and handed by `services up` to the
actor (the cut itself is what `services.console.compare` runs with)."""

from pathlib import Path

import pytest

from services.common.config import ActorConfig
from services.launcher.config import Launch, UpConfig, build_processes


def test_episode_steps_must_be_positive():
    assert ActorConfig(episode_steps=5).episode_steps == 5
    with pytest.raises(ValueError, match="episode-steps must be >= 1"):
        ActorConfig(episode_steps=0)


def test_services_up_hands_episode_steps_to_the_actor(tmp_path: Path):
    launch = Launch(UpConfig.flat(episode_steps=9), "r", tmp_path, "tcp/127.0.0.1:7447")
    procs, _ = build_processes(launch)
    actor = next(p for p in procs if p.name == "actor")
    assert actor.config.episode_steps == 9

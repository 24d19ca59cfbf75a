"""'Learns it' tests on a tiny maze: the whole loop (env, observer, credit, agent, runner) must learn.

Layout 0's shortest path is 5 steps. "Reaches the shortest path" is judged on the greedy policy after each
episode (no exploration), so a lucky exploratory episode does not count.
"""

import numpy as np
import pytest

from common.agents import agent_config
from common.envs import make_layout
from common.core.observer import ObserverConfig
from experiments.runner import TrialSpec, run_trials

LAYOUT = 0
SEEDS = range(5)
HIGH_FREQUENCY_DELAYED = ObserverConfig(p_feedback=0.5, delay_probs=(0.3, 0.6, 0.1))


def first_optimal_episode(algo: str, episodes: int) -> list[int | None]:
    shortest = make_layout(LAYOUT).shortest_path()
    specs = [
        TrialSpec("maze", agent_config(algo), HIGH_FREQUENCY_DELAYED, seed=s, layout=LAYOUT, episodes=episodes)
        for s in SEEDS
    ]
    firsts = []
    for result in run_trials(specs, greedy_eval=True):
        greedy = [e["greedy_steps"] for e in result.episodes]
        firsts.append(next((k for k, g in enumerate(greedy) if g == shortest), None))
    return firsts


@pytest.mark.slow
def test_dqn_tamer_reaches_the_shortest_path_quickly_and_dqn_more_slowly():
    tamer = first_optimal_episode("dqn-tamer", episodes=25)
    dqn = first_optimal_episode("dqn", episodes=100)
    print("first optimal episode, dqn-tamer:", tamer, "dqn:", dqn)
    assert sum(f is not None for f in tamer) >= 4, tamer
    assert sum(f is not None for f in dqn) >= 3, dqn
    never = 10**6
    assert np.median([f if f is not None else never for f in tamer]) < np.median(
        [f if f is not None else never for f in dqn]
    )

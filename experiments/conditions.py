"""The experimental conditions: the paper's, and ours beyond it (see docs/hyperparameters.md).

Observer settings (DESIGN.md): high / low feedback frequency p_feedback 0.5 / 0.1; "without delay" is a
lag of 0 steps for every reaction, "with delay" the paper's lag distribution (0.3, 0.6, 0.1) over 0, 1, 2
steps; the paper's learner assumes lags uniform over 0..2. Feedback-stop and natural-reaction conditions
use the realistic observer: high frequency, delayed. The teacher rule is the paper's Manhattan rule
except in `maze-sp-*` (rule `shortest-path`: a teacher who knows the maze).

Layouts and trials (common.envs.maze): a maze condition runs on a set of layouts (all 60, or the 30
honest ones), `reps` trials per layout; trial k runs layout k % n on repetition k // n, and its seed is
derived from (layout, repetition), so no two trials share network initialisation, exploration or
observer streams. Trial k is the same (layout, seed) under every arm and condition of the same layout
set (common random numbers), so comparisons are paired. Taxi: Gymnasium's (random passenger and
destination: one "layout", trials are seeds) or `taxi-fixed` (layout = one of 12 fixed passenger /
destination pairs).

An arm is an agent variant: the paper's four (`dqn`, `dqn-rs`, `deep-tamer`, `dqn-tamer`) or ours:
`<algo>/uniform` (lags assumed uniform over the learner's window 0..6), `<algo>/uniform2` (the paper's
assumption, uniform over 0..2; added 28 November 2026), `<algo>/true` (the observer's
true distribution), `<algo>/learned` (the delay learned online in seconds, common.core.delay_model, on the
runner's clock of 0.5 s per step), `dqn-tamer/adaptive` (alpha_h also follows H/Q agreement),
`dqn-tamer/matched` (A1's control: a fixed schedule with the adaptive arm's mean alpha_h),
`dqn-tamer/trusted` (M1: the teacher's reliability lowers alpha_h for a teacher Q keeps contradicting).

Layouts and seeds of the deciding runs (`FULL`) are fresh: layouts 120-179 and seed block 3 (`Scale`);
`QUICK` runs the old layouts 0-59 and seed block 1, so developing never touches a deciding trial.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.agents import ALGOS
from common.envs.maze import LAYOUT_COUNT, layout_kind
from common.envs.taxi import FIXED_TASKS
from common.core.observer import ObserverConfig
from experiments.arms import NO_DELAY, PAPER_DELAY, HIGH, LOW, STOP_EPISODE, FLIP, LATE_DELAY, LONG_DELAY, agent_for
from experiments.runner import TrialSpec

# Default episode counts of a single run or sweep (the earlier reproduction's; sweeps read them).
MAZE_EPISODES = 60
TAXI_EPISODES = 50
# The reproduction's (ours): mazes until the best arm's curve is flat (checked in the report), Taxi until
# DQN has converged (docs/hyperparameters.md "Episode counts"; the report's "Horizons" table measures both).
REPRO_MAZE_EPISODES = 100
"""Maze MDP and POMDP (every maze condition, the learned-delay ones too). 60 at commit 872a531, where the
best arm's curve was not flat in 7 of 12 maze conditions. Chosen on a pilot, before the runs that use it:
`python -m experiments pilot maze --episodes 150` (docs/notes/2026-11-23-reproduction-pilots-and-speed.md,
"Maze horizon pilot"; layouts 44-59 on seeds 9000+, never the reproduction's trials; every arm of the 7
conditions that were not flat).
From episodes 81-100 to 131-150 the best arm's mean ln steps falls by less than ln 1.1 in 5 of the 7
(maze-high-delay -0.03, maze-low-nodelay +0.11, maze-flip -0.09, delay-late -0.01, delay-drift -0.07);
maze-low-delay (-0.44) and delay-long (-0.31) still fall at 150. Environment steps grow 1.53x from 60 to
100 episodes, 1.66x to 110 and 2.14x to 150; with CPU in proportion to steps and the last full run's
figures (Maze and POMDP 485 of 1752 CPU s, 990 s wall) 100 episodes is about 18.6 min on 2 cores, 110 about
19.2 and 150 about 21, over the 20-minute budget: so 100. Measured at 100 (ded26fc): 19.4 min, 2259 CPU s."""
REPRO_TAXI_EPISODES = 100
"""The fixed-task Taxi: DQN converged by episode 79 in the reproduction of commit 5d2c95e."""
REPRO_TAXI_RANDOM_EPISODES = 200
"""Gymnasium's Taxi (random passenger and destination): DQN had not converged at 100 episodes (5d2c95e).
Chosen on a pilot, before the runs that use it: `python -m experiments pilot taxi --env taxi-s --episodes
300 --trials 4` (seeds 9000-9003, never the reproduction's; DQN only, the reproduction's settings) reached
its final level (19 steps, geometric mean) at episode 150 by the report's rule, the 10-episode median of its
trials fell below 100 steps at episodes 76, 95, 117 and 132, and a DQN trial took 77 000 steps to get there.
200 leaves 50 episodes after that for the report's flatness window (the last 20)."""


@dataclass(frozen=True)
class Scale:
    """How big a reproduction is: layouts, repetitions, episodes (full or --quick)."""

    layouts: int = 60
    """Maze layouts used (n from first_layout on: n/2 honest, n/2 misleading; the generator has LAYOUT_COUNT)."""
    first_layout: int = 120
    """The first maze layout. 120: layouts 120-179, fresh for the run re-declared late on 25 November 2026 (every
    run and pilot before 25 November used layouts 0-59, the run of that day 60-119)."""
    seed_block: int = 3
    """The third word of every trial's seed (`trial_seed`): 1 in every run before 25 November 2026, 2 in the
    run of that day, 3 in the re-declared run, so Taxi's trials (whose tasks are the old ones)
    are fresh too."""
    reps: int = 1
    maze_episodes: int = REPRO_MAZE_EPISODES
    taxi_episodes: int = REPRO_TAXI_EPISODES
    """Episodes of the fixed-task Taxi."""
    taxi_random_episodes: int = REPRO_TAXI_RANDOM_EPISODES
    """Episodes of Gymnasium's Taxi (random passenger and destination)."""
    taxi_trials: int = 4
    """Trials of Gymnasium's Taxi (part of C5's primary test). 4 since 26 November 2026 (6 before), declared before
    the run it applies to, for time alone: the run of 25 November 23:46 took 1,395 s against the 1,200 s budget,
    and its 24 Taxi trials took 1,620 of its 2,711 CPU s. Trial k's seed depends on k alone and a trial's numbers
    do not depend on its batch, so these 4 are that run's first 4 Taxi trials, and the maze trials are the same:
    of that run's verdicts only C5 (its Taxi part) can move, and whatever it reads is reported."""
    taxi_fixed_trials: int = 4
    """Trials of the fixed-task Taxi (6 until 25 November 2026; a secondary test of C5 since: its 2 trials fewer
    save about 220 CPU s, a third of its 673 in the run of ded26fc, for the two arms that A1 and M1 add)."""
    delay_layouts: int = 16
    """Honest layouts of the learned-delay conditions."""


FULL = Scale()
QUICK = Scale(
    layouts=8,
    reps=1,
    maze_episodes=40,
    taxi_episodes=40,
    taxi_random_episodes=40,
    taxi_trials=4,
    delay_layouts=4,
    first_layout=0,
    seed_block=1,
)
"""The quick form runs the old layouts and seeds: developing with it never touches a deciding trial."""


@dataclass(frozen=True)
class Condition:
    name: str
    title: str
    env: str
    observer: ObserverConfig
    figure: str
    """Which of the paper's figures the panel belongs to (or 'beyond the paper')."""
    arms: tuple[str, ...] = ALGOS
    layouts: str = "all"
    """all (honest and misleading) or honest; taxi conditions ignore it."""
    true_delay: tuple[float, ...] = PAPER_DELAY
    """What the `/true` arms assume (the observer's distribution; for a drifting one, its average)."""
    teacher_rule: str | None = None
    """None: the paper's rule (`progress`); `shortest-path`: a teacher who knows the maze."""
    full_run: bool = True
    """Run by `reproduce` without `--only` (False: only when named, `--only NAME`)."""

    @property
    def stop_episode(self) -> int | None:
        return self.observer.stop_episode

    @property
    def is_taxi(self) -> bool:
        return self.env.startswith("taxi")

    def episodes(self, scale: Scale) -> int:
        if self.env in RANDOM_TAXI:
            return scale.taxi_random_episodes
        return scale.taxi_episodes if self.is_taxi else scale.maze_episodes


def _obs(p, delay, **kw) -> ObserverConfig:
    return ObserverConfig(p, delay, **kw)


def _mix(a, b) -> tuple[float, ...]:
    n = max(len(a), len(b))
    pa, pb = np.zeros(n), np.zeros(n)
    pa[: len(a)], pb[: len(b)] = a, b
    return tuple(float(x) for x in (pa + pb) / 2)


_DELAY_ARMS = tuple(
    f"{algo}/{how}" for algo in ("deep-tamer", "dqn-tamer") for how in ("uniform", "uniform2", "true", "learned")
)
"""Each declaration runs the arms its claims need (experiments/declarations.py): 25 November `uniform` (0..6 steps),
28 November `uniform2` (the paper's 0..2 steps)."""
_STOP = dict(stop_episode=STOP_EPISODE)

CONDITIONS: tuple[Condition, ...] = (
    Condition(
        "maze-high-nodelay",
        "Maze MDP, high frequency (p=0.5), no delay",
        "maze",
        _obs(HIGH, NO_DELAY),
        "Fig. maze results, upper left",
    ),
    Condition(
        "maze-high-delay",
        "Maze MDP, high frequency (p=0.5), with delay",
        "maze",
        _obs(HIGH, PAPER_DELAY),
        "Fig. maze results, upper right",
        arms=ALGOS + ("dqn-tamer/adaptive", "dqn-tamer/matched", "dqn-tamer/trusted"),
    ),
    Condition(
        "maze-low-nodelay",
        "Maze MDP, low frequency (p=0.1), no delay",
        "maze",
        _obs(LOW, NO_DELAY),
        "Fig. maze results, lower left",
    ),
    Condition(
        "maze-low-delay",
        "Maze MDP, low frequency (p=0.1), with delay",
        "maze",
        _obs(LOW, PAPER_DELAY),
        "Fig. maze results, lower right",
    ),
    Condition(
        "maze-stop",
        "Maze MDP, feedback stops after 30 episodes",
        "maze",
        _obs(HIGH, PAPER_DELAY, **_STOP),
        "Fig. feedback stop, left",
    ),
    Condition(
        "pomdp-stop",
        "Maze POMDP, feedback stops after 30 episodes",
        "maze-pomdp",
        _obs(HIGH, PAPER_DELAY, **_STOP),
        "Fig. feedback stop, right",
    ),
    Condition(
        "taxi-stop",
        "Taxi (random passenger and destination), feedback stops after 30 episodes",
        "taxi-s",
        _obs(HIGH, PAPER_DELAY, **_STOP),
        "Fig. taxi",
    ),
    Condition(
        "taxi-fixed-stop",
        "Taxi (passenger and destination fixed per initial condition), feedback stops after 30 episodes",
        "taxi-fixed-s",
        _obs(HIGH, PAPER_DELAY, **_STOP),
        "Fig. taxi (fixed task)",
        full_run=False,
    ),  # a secondary test of C5, outside the 20-minute budget (FULL_RUN_NOTE)
    Condition(
        "maze-flip",
        "Maze MDP, delayed feedback with 15% polarity flips",
        "maze",
        _obs(HIGH, PAPER_DELAY, p_flip=FLIP),
        "natural reaction (Sec. V-C)",
    ),
    Condition(
        "maze-sp-high-delay",
        "Maze MDP, shortest-path observer, high frequency, with delay",
        "maze",
        _obs(HIGH, PAPER_DELAY),
        "beyond the paper: a teacher who knows the maze",
        teacher_rule="shortest-path",
    ),
    Condition(
        "delay-paper",
        "Learned delay: the paper's observer (lags 0.3/0.6/0.1)",
        "maze",
        _obs(HIGH, PAPER_DELAY),
        "beyond the paper: learned delay",
        _DELAY_ARMS,
        "honest",
        PAPER_DELAY,
    ),
    Condition(
        "delay-late",
        "Learned delay: observer skewed late (mode 3 steps)",
        "maze",
        _obs(HIGH, LATE_DELAY),
        "beyond the paper: learned delay",
        _DELAY_ARMS,
        "honest",
        LATE_DELAY,
    ),
    Condition(
        "delay-long",
        "Learned delay: observer with long lags (0-6 steps)",
        "maze",
        _obs(HIGH, LONG_DELAY),
        "beyond the paper: learned delay",
        _DELAY_ARMS,
        "honest",
        LONG_DELAY,
    ),
    Condition(
        "delay-drift",
        "Learned delay: observer drifting from the paper's lags to late ones",
        "maze",
        _obs(HIGH, PAPER_DELAY, late_delay_probs=LATE_DELAY, drift_episodes=REPRO_MAZE_EPISODES),
        "beyond the paper: learned delay",
        _DELAY_ARMS,
        "honest",
        _mix(PAPER_DELAY, LATE_DELAY),
    ),
)
BY_NAME = {c.name: c for c in CONDITIONS}
RANDOM_TAXI = ("taxi", "taxi-s")
"""Taxi environments with a random passenger and destination (one "layout"; trials are seeds)."""
DELAY_CONDITIONS = ("delay-paper", "delay-late", "delay-long", "delay-drift")


def layout_set(cond: Condition, scale: Scale) -> list[int]:
    """The layouts (or taxi tasks) a condition's trials cycle through."""
    if cond.env in RANDOM_TAXI:
        return [0]
    if cond.is_taxi:
        return list(range(len(FIXED_TASKS)))
    first = scale.first_layout
    if cond.layouts == "honest":
        return [L for L in range(first, LAYOUT_COUNT) if layout_kind(L) == "honest"][: scale.delay_layouts]
    return list(range(first, min(first + scale.layouts, LAYOUT_COUNT)))


def n_trials(cond: Condition, scale: Scale) -> int:
    if cond.is_taxi:
        return scale.taxi_trials if cond.env in RANDOM_TAXI else scale.taxi_fixed_trials
    return len(layout_set(cond, scale)) * scale.reps


def trial_seed(layout: int, rep: int, block: int = 1) -> int:
    """The seed of repetition `rep` on `layout`: derived from both, so trials never share streams; `block`
    (Scale.seed_block) sets the runs declared on 25 November 2026 (block 2) apart from all earlier ones."""
    return int(np.random.SeedSequence([int(layout), int(rep), int(block)]).generate_state(1, np.uint32)[0] % (2**31))


def trial_layout(cond: Condition, scale: Scale, k: int) -> tuple[int, int]:
    """(layout, repetition) of trial k."""
    layouts = layout_set(cond, scale)
    return layouts[k % len(layouts)], k // len(layouts)


def trial_spec(cond: Condition, arm: str, k: int, scale: Scale = FULL) -> TrialSpec:
    layout, rep = trial_layout(cond, scale, k)
    return TrialSpec(
        cond.env,
        agent_for(arm, cond.env, cond.true_delay),
        cond.observer,
        seed=trial_seed(layout, rep, scale.seed_block),
        layout=layout,
        episodes=cond.episodes(scale),
        teacher_rule=cond.teacher_rule,
    )


def cluster_of(cond: Condition, scale: Scale, k: int) -> int:
    """The resampling cluster of trial k: its layout (Gymnasium's Taxi: its seed)."""
    layout, rep = trial_layout(cond, scale, k)
    return rep if cond.env in RANDOM_TAXI else layout


FULL_RUN_NOTE = """The fixed-task Taxi (`taxi-fixed-stop`, our variant; the paper's Taxi draws the passenger and the
destination at random) is run only when named: `python -m experiments reproduce --only taxi-fixed-stop`.
Re-declared late on 25 November 2026, before the run it applies to, for time alone: in the run of 25 November its
24 trials took 930 of 2800 CPU s, and the full reproduction must fit 1,200 s on 2 cores. Its test was a
secondary test of C5 (the primary, C5 as the paper states it, keeps Gymnasium's Taxi)."""


def select(names: list[str] | None) -> list[Condition]:
    """The named conditions, or those of the full run (`Condition.full_run`)."""
    if not names:
        return [c for c in CONDITIONS if c.full_run]
    unknown = [n for n in names if n not in BY_NAME]
    if unknown:
        raise ValueError(f"unknown condition {', '.join(unknown)}; choose from {', '.join(BY_NAME)}")
    return [BY_NAME[n] for n in names]


__all__ = [
    "ALGOS",
    "CONDITIONS",
    "BY_NAME",
    "Condition",
    "Scale",
    "FULL",
    "QUICK",
    "agent_for",
    "trial_spec",
    "select",
    "layout_set",
    "n_trials",
    "trial_layout",
    "cluster_of",
    "trial_seed",
]

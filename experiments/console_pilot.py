"""`python -m experiments pilot console`: the console comparison's setting simulated in process, on pilot seeds.

What it is for: choosing what a next declared browser comparison (`services/console/compare.py`) should test,
without spending its pairs. The browser runs take 17 minutes each at 2 steps/s; the same setting in process
takes seconds. It is an approximation of the console, on the step clock:

- the scripted person (paper's rule, presses on half the steps, 0.3-1.5 s after the paint) at 2 steps/s lags
  0.6-3 steps: on the step clock lag 0, 1, 2 with probabilities 0.4/2.4, 1/2.4, 1/2.4 (`PERSON_LAGS`);
- the console's learner runs 8 idle-time minibatch steps after each step's update (`services/console/launch.py`);
- episodes are cut at 200 steps, 15 episodes, honest layouts.

Trials run layouts `PILOT_LAYOUTS` on seeds 9000 + k (`experiments.taxi_pilot.PILOT_SEED0`): never a browser
comparison's seed (2-51). No claim is computed from it. Each arm's measures are those of the browser designs:
the episode of the 10th goal (short of 10: 15 + goals missing), the first episode within twice the shortest
path (never: 16), and steps over the 15 episodes; every arm is compared with DQN on the same (layout, seed).

    python -m experiments pilot console --trials 48

With `--person SHAPE` the person reacts in seconds with a lag shape of `services/console/lags.py` (the runner's
observer, `delay_s`; a `drift:` shape's quantiles move over the episodes), on the layouts given (odd ones are
misleading): the unknown-teacher design's pilot (docs/notes/2026-11-25-unknown-teacher.md).

    python -m experiments pilot console --trials 48 --arms dqn-tamer/learned --person drift:0.5,2,0.2
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from common.config import option, parse_config
from common.envs.maze import LAYOUT_COUNT, MazeEnv, make_layout
from common.envs.registry import ENVS
from common.core.observer import ObserverConfig
from experiments.arms import ADAPT_RATE, agent_for
from experiments.taxi_pilot import PILOT_SEED0

PILOT_LAYOUTS = tuple(range(0, 60, 2))
"""Every honest layout (the browser designs reuse them too, but never the pilot's seeds)."""
PERSON_LAGS = (0.4 / 2.4, 1 / 2.4, 1 / 2.4)
INTERVAL_KERNEL = (0.033, 0.342, 0.417, 0.208)
"""What the console's interval credit (Deep TAMER's) with the matched uniform 0.3-1.5 s does on the step clock: a
press at t = m + L (L ~ U(0.6, 3) steps after step m's onset) gives step j the mass of D in (t - j - 1, t - j];
averaged over L's fraction, over lags 0..3 from the newest step. The person's true lags are `PERSON_LAGS`: the
interval reading credits about half a step too early (mean lag 1.8 against 1.25). The `dqn-tamer/matched` arm is what
onset credit does here (the true step is always among the steps appearing within 0.3-1.5 s, each equally likely)."""
EPISODES, EPISODE_STEPS, IDLE_UPDATES, GOALS = 15, 200, 8, 10
ARMS = {
    "dqn": lambda: agent_for("dqn"),
    "dqn-tamer/matched": lambda: replace(agent_for("dqn-tamer"), assumed_delay_probs=(1 / 3,) * 3),
    "dqn-tamer/interval": lambda: replace(agent_for("dqn-tamer"), assumed_delay_probs=INTERVAL_KERNEL),
    "dqn-tamer/0.2-4s": lambda: agent_for("dqn-tamer/uniform"),
    "dqn-tamer/adaptive": lambda: replace(
        agent_for("dqn-tamer"), assumed_delay_probs=(1 / 3,) * 3, alpha_h_adapt=ADAPT_RATE
    ),
    "dqn-tamer/learned": lambda: agent_for("dqn-tamer/learned"),
}


def _register_cut_maze() -> str:
    name = "maze-cut200"
    ENVS[name] = replace(
        ENVS["maze"], name=name, factory=lambda layout=0: MazeEnv(layout, "mdp", max_steps=EPISODE_STEPS)
    )
    return name


def _with_idle_updates(idle: int):
    """The console learner's schedule: after every step's update, `idle` more minibatch steps."""
    from common.agents.agent import TrialBatchAgent

    plain = TrialBatchAgent.update

    def update(self, active=None):
        plain(self, active)
        for _ in range(idle):
            self.idle_update()

    TrialBatchAgent.update = update


def measures(steps: list[int], reached: list[bool], shortest: int) -> dict:
    goals = np.flatnonzero(reached)
    tenth = int(goals[GOALS - 1]) + 1 if len(goals) >= GOALS else EPISODES + GOALS - len(goals)
    good = [i + 1 for i, (s, r) in enumerate(zip(steps, reached)) if r and s <= 2 * shortest]
    return {"goals": tenth, "first_good": good[0] if good else EPISODES + 1, "steps": int(sum(steps))}


def observer_for(person: str | None) -> ObserverConfig:
    """The scripted person: the browser designs' uniform 0.3-1.5 s on the step clock (`PERSON_LAGS`), or a lag
    shape in seconds (services/console/lags.py) from each step's onset, a `drift:START,END,SIGMA` one as a
    lognormal whose quantiles move from the first episode's to the last's."""
    if person is None:
        return ObserverConfig(p_feedback=0.5, delay_probs=PERSON_LAGS)
    from services.console.lags import check_lag_spec

    check_lag_spec(person)
    name, _, args = person.partition(":")
    if name == "drift":
        start, end, sigma = args.split(",")
        return ObserverConfig(
            p_feedback=0.5,
            delay_s=f"lognorm:{sigma},0,{start}",
            late_delay_s=f"lognorm:{sigma},0,{end}",
            drift_episodes=EPISODES - 1,
        )
    return ObserverConfig(p_feedback=0.5, delay_s=person)


def run(
    arms: list[str], trials: int, layouts: tuple[int, ...] = PILOT_LAYOUTS, person: str | None = None
) -> dict[str, list[dict]]:
    from experiments.runner import TrialSpec, run_trials

    env = _register_cut_maze()
    observer = observer_for(person)
    pairs = [(layouts[k % len(layouts)], PILOT_SEED0 + k) for k in range(trials)]
    specs = [
        (arm, L, TrialSpec(env, ARMS[arm](), observer, seed=s, layout=L, episodes=EPISODES))
        for arm in arms
        for L, s in pairs
    ]
    results = run_trials([s for _, _, s in specs])
    out: dict[str, list[dict]] = {arm: [] for arm in arms}
    for (arm, L, _), res in zip(specs, results):
        steps = [int(e["steps"]) for e in res.episodes]
        reached = [s < EPISODE_STEPS for s in steps]  # an episode cut at 200 steps did not reach it
        out[arm].append(measures(steps, reached, make_layout(L).shortest_path()))
    return out


def summary(out: dict[str, list[dict]]) -> None:
    from scipy import stats

    base = out["dqn"]
    print(f"{'arm':<20} {'10th goal':>9} {'first good':>10} {'steps':>7}   vs DQN (10th goal): mean, W/T/L, p")
    for arm, rows in out.items():
        g = np.array([r["goals"] for r in rows])
        line = (
            f"{arm:<20} {g.mean():9.2f} {np.mean([r['first_good'] for r in rows]):10.2f} "
            f"{np.mean([r['steps'] for r in rows]):7.0f}"
        )
        if arm != "dqn":
            d = np.array([b["goals"] for b in base]) - g
            nz = d[d != 0]
            p = stats.wilcoxon(nz, alternative="greater").pvalue if len(nz) else 1.0
            line += f"   {d.mean():+.2f}, {(d > 0).sum()}/{(d == 0).sum()}/{(d < 0).sum()}, {p:.3f}"
        print(line)


@dataclass(frozen=True)
class ConsolePilotConfig:
    """The console comparison simulated in process on pilot seeds: each arm against DQN."""

    trials: int = option(48, "(layout, seed) pairs per arm")
    idle_updates: int = option(IDLE_UPDATES, "idle-time minibatch steps after each step (the console's learner: 8)")
    layouts: tuple[int, ...] = option(
        PILOT_LAYOUTS, "maze layouts, cycled over the pairs (every honest one; odd ones are misleading)"
    )
    person: str | None = option(
        None,
        "the person's lag shape in seconds (services/console/lags.py, e.g. "
        "drift:0.5,2,0.2; the runner's virtual clock is 2 steps/s); none: uniform "
        "0.3-1.5 s on the step clock",
    )
    arms: tuple[str, ...] = option(
        tuple(ARMS),
        "arms besides dqn (always run): dqn-tamer/matched (credit on the "
        "true candidates: onset credit), /interval (the interval reading's "
        "kernel), /0.2-4s (lags uniform 0-6), /adaptive (adaptive alpha_h, "
        "matched), /learned (delay learned online)",
    )

    def __post_init__(self):
        unknown = [a for a in self.arms if a not in ARMS]
        if unknown:
            raise ValueError(f"unknown arm(s) {unknown}; choose from {list(ARMS)}")
        if self.person is not None:
            from services.console.lags import check_lag_spec

            check_lag_spec(self.person)
        if self.trials < 1 or self.idle_updates < 0 or not self.layouts:
            raise ValueError("trials must be >= 1, idle-updates >= 0, and some layout given")
        bad = [L for L in self.layouts if not 0 <= L < LAYOUT_COUNT]
        if bad:
            raise ValueError(f"layouts must be in 0..{LAYOUT_COUNT - 1}, got {bad}")


def main(cfg: ConsolePilotConfig) -> int:
    arms = ["dqn"] + [a for a in cfg.arms if a != "dqn"]
    if cfg.idle_updates:
        _with_idle_updates(cfg.idle_updates)
    t0 = time.time()
    summary(run(arms, cfg.trials, cfg.layouts, cfg.person))
    print(f"({cfg.trials} pairs per arm, idle updates {cfg.idle_updates}, {time.time() - t0:.0f} s)")
    return 0


def cli(argv: list[str] | None = None) -> int:
    return main(parse_config(ConsolePilotConfig, argv, prog="python -m experiments pilot console"))


if __name__ == "__main__":
    from common.config import moved

    moved("python -m experiments pilot console")

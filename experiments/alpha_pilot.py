"""`python -m experiments pilot alpha`: who should decide, H or Q? Arms that set alpha_h differently, on
pilot layouts and seeds, to fix two declared choices WITHOUT the trials that decide them:

- A1's control: the fixed alpha_h schedule matched on the adaptive arm's mean. The match: k = mean alpha_h
  of `dqn-tamer/adaptive` / mean alpha_h of `dqn-tamer` (alpha_h at each episode's end, averaged over
  episodes and trials, honest and misleading pilot layouts pooled); the control runs the paper's schedule
  times k (`alpha_h` = k at step 0, the same decay).
- M1's mechanism: the teacher's reliability (`alpha_h_trust*`, common/agents/explorer.py), candidate
  settings given as `--variants`, each judged on misleading pilot layouts against DQN (ln steps and mean
  return) and on honest ones against the paper's DQN-TAMER.

Trials run `experiments.maze_pilot.PILOT_LAYOUTS` (layouts 44-59: 8 honest, 8 misleading; never a deciding
run's layout: those are 60-119) on seeds `seed0 + k + 100 r` for repetition r, never a reproduction seed.

    python -m experiments pilot alpha --episodes 100 --reps 2 \\
        --variants "trust:alpha_h_trust=0.01,alpha_h_trust_after=2000,alpha_h_trust_ref=0.5"
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace

import numpy as np

from common.config import option, parse_config
from experiments.conditions import BY_NAME, agent_for
from experiments.maze_pilot import PILOT_LAYOUTS
from experiments.taxi_pilot import PILOT_SEED0

BASE_ARMS = ("dqn", "dqn-tamer", "dqn-tamer/adaptive")


def parse_variants(text: str) -> dict[str, dict]:
    """ "name:field=v,field=v;name2:..." -> {name: {field: value}} (values as float, int where integral)."""
    out: dict[str, dict] = {}
    for part in filter(None, (p.strip() for p in text.split(";"))):
        name, _, body = part.partition(":")
        fields = {}
        for item in filter(None, body.split(",")):
            key, _, value = item.partition("=")
            number = float(value)
            fields[key.strip()] = int(number) if number.is_integer() and "." not in value else number
        out[name.strip()] = fields
    return out


def summarise(steps: np.ndarray, returns: np.ndarray, alpha: np.ndarray, layouts: np.ndarray) -> dict:
    out: dict = {}
    for kind, mask in (("honest", layouts % 2 == 0), ("misleading", layouts % 2 == 1)):
        out[kind] = {
            "ln_steps": float(np.log(np.maximum(steps[mask], 1)).mean()),
            "return": float(returns[mask].mean()),
            "alpha_h_mean": float(alpha[mask].mean()),
            "alpha_h_end": float(alpha[mask][:, -1].mean()),
        }
    out["alpha_h_mean"] = float(alpha.mean())
    return out


@dataclass(frozen=True)
class AlphaPilotConfig:
    """alpha_h arms on the pilot layouts and seeds of maze-high-delay."""

    condition: str = option("maze-high-delay", "maze MDP condition whose observer the pilot uses")
    episodes: int = option(100, "episodes per trial")
    reps: int = option(2, "seeds per pilot layout")
    seed0: int = option(PILOT_SEED0, f"first pilot seed (>= {PILOT_SEED0})")
    variants: str = option("", "extra DQN-TAMER arms: 'name:field=v,...;name2:...' (AgentConfig fields)")
    out: str | None = option(None, "write the summary as JSON here")

    def __post_init__(self):
        if self.seed0 < PILOT_SEED0:
            raise ValueError(f"seed0 must be >= {PILOT_SEED0}: lower seeds may be the reproduction's")
        if self.condition not in BY_NAME or BY_NAME[self.condition].env != "maze":
            raise ValueError(f"not a maze MDP condition: {self.condition}")
        parse_variants(self.variants)


def main(cfg: AlphaPilotConfig) -> int:
    from experiments.runner import TrialSpec, run_trials

    cond = BY_NAME[cfg.condition]
    arms = {a: agent_for(a, cond.env, cond.true_delay) for a in BASE_ARMS}
    for name, fields in parse_variants(cfg.variants).items():
        arms[name] = replace(agent_for("dqn-tamer", cond.env), **fields)
    plan = [
        (arm, L, cfg.seed0 + k + 100 * r) for arm in arms for r in range(cfg.reps) for k, L in enumerate(PILOT_LAYOUTS)
    ]
    specs = [
        TrialSpec(
            cond.env, arms[arm], cond.observer, seed=s, layout=L, episodes=cfg.episodes, teacher_rule=cond.teacher_rule
        )
        for arm, L, s in plan
    ]
    results = run_trials(specs)
    summary = {}
    for arm in arms:
        rs = [(r, L) for (a, L, _), r in zip(plan, results) if a == arm]
        steps = np.array([[e["steps"] for e in r.episodes] for r, _ in rs], np.float64)
        rets = np.array([[e["return"] for e in r.episodes] for r, _ in rs], np.float64)
        alpha = np.array([[e["alpha_h"] for e in r.episodes] for r, _ in rs], np.float64)
        summary[arm] = summarise(steps, rets, alpha, np.array([L for _, L in rs]))
        s = summary[arm]
        print(
            f"{arm}: honest ln steps {s['honest']['ln_steps']:.3f} return {s['honest']['return']:+.3f}; "
            f"misleading ln steps {s['misleading']['ln_steps']:.3f} return {s['misleading']['return']:+.3f}; "
            f"alpha_h mean {s['alpha_h_mean']:.3f} (end honest {s['honest']['alpha_h_end']:.2f}, "
            f"misleading {s['misleading']['alpha_h_end']:.2f})",
            flush=True,
        )
    k = summary["dqn-tamer/adaptive"]["alpha_h_mean"] / summary["dqn-tamer"]["alpha_h_mean"]
    print(f"A1 match: k = {k:.4f} (mean alpha_h adaptive / paper)")
    if cfg.out:
        with open(cfg.out, "w") as fh:
            json.dump({"config": cfg.__dict__, "arms": summary, "match_k": k}, fh, indent=1)
    return 0


def cli(argv: list[str] | None = None) -> int:
    return main(parse_config(AlphaPilotConfig, argv, prog="python -m experiments pilot alpha"))


if __name__ == "__main__":
    from common.config import moved

    moved("python -m experiments pilot alpha")

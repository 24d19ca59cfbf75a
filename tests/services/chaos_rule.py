"""The learning measure of `test_chaos_sigkill_each_service_in_turn_loses_nothing` (no bound under load), and its runs.

The measure is the chaos report's `chaos_last10_mean`: the mean return of the last 10 finished episodes (fewer when
the run finished fewer) of the 1000-step chaos run (maze layout 0, DQN-TAMER, oracle teacher, seed 0, 40 steps/s).
Each kill costs learning time: the learner is down 4-13 s, 180-500 of the run's 1000 steps, so a run whose learner
is killed before the agent has learnt the maze may not learn it before the run ends. Honest runs are bimodal:

    python -m tests.services.chaos_rule live 6     # honest runs, one at a time, with the test's config

  25 November 2026, load 4-11 on 2 shared cores, ten runs (`python -m services chaos --seed 0 --rate 40
  --max-steps 1000 --first-kill 3 --gap 2`): with the undisturbed run alongside (`--alongside true`, as the test
  ran before) 0.95, 0.93, 0.26, 0.95; alone (`--baseline false`, as the test runs now) 0.95, 0.96, 0.95, 0.95,
  0.81, 0.95. The old bound (> 0.8 and within 0.05 of the undisturbed run) had also failed honest runs at 0.62
  (6 episodes) and 0.78 (31 episodes).

What a policy that learnt nothing reaches on the same 1000 steps (uniformly random actions, in process):

    python -m tests.services.chaos_rule random 300

  300 seeds: median -0.62, 90% quantile 0.06, 99% 0.45, max 0.74; 1.7% finish no episode.

25-26 November 2026, later, in the full suite under three workers (load about 5 on 2 cores): honest runs reached
-0.046 (8 episodes) and -0.268 (5 episodes), their learner down for longer, and 0.936 (18) and 0.934 (85). The
bound went from 0.8 to 0.0 to -0.2 as each loaded run fell below it; at -0.268 an honest run is where 29% of
random-policy runs are (300 seeds: above -0.3 29.3%, above -0.2 23.3%, above 0.0 13.0%). Under load the measure
does not tell an agent that learnt from one that did not, so the test asserts no bound on it
(`MIN_LAST10_MEAN` is None); the chaos command still prints it, and `python -m tests.services.chaos_rule live N`
measures its spread. The run must still finish an episode.
What the run learns is checked by the test's other assertions: every step and feedback learned, and the final
weights reproduced bit for bit by retraining through the restored learner.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

MIN_LAST10_MEAN: float | None = None  # no bound under load: see above
STEPS = 1000  # the chaos run's steps (the test's ChaosConfig.max_steps)


def random_policy_last10(seed: int, steps: int = STEPS) -> float:
    """The measure for uniformly random actions on the maze over `steps` steps (nan: no episode finished)."""
    from common.envs import make_env

    env, _ = make_env("maze")
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    returns, ret = [], 0.0
    for _ in range(steps):
        _, reward, terminated, truncated, _ = env.step(int(rng.integers(4)))
        ret += float(reward)
        if terminated or truncated:
            if terminated:
                returns.append(ret)
            ret = 0.0
            env.reset()
    return float(np.mean(returns[-10:])) if returns else float("nan")


def honest_run(out: Path) -> float:
    """One chaos run with the test's config; its measure."""
    from services.chaos import ChaosConfig, chaos

    cfg = ChaosConfig(out=str(out), seed=0, rate=40.0, max_steps=STEPS, first_kill=3.0, gap=2.0, baseline=False)
    if chaos(cfg) != 0:
        raise RuntimeError(f"chaos run failed: see {out}")
    return json.loads(next(out.glob("chaos-*.json")).read_text())["returns"]["chaos_last10_mean"]


def main(argv: list[str]) -> None:
    kind, count = argv[0], int(argv[1])
    if kind == "random":
        m = np.array([random_policy_last10(s) for s in range(count)])
        q = np.nanquantile(m, [0.5, 0.9, 0.99, 1.0])
        print(
            f"random policy, {count} seeds: no episode {np.isnan(m).mean():.1%}; quantiles 50/90/99/max "
            f"{q.round(3).tolist()}; above -0.2 {(m > -0.2).mean():.1%}, above 0 {(m > 0).mean():.1%}"
        )
    elif kind == "live":
        for i in range(count):
            with tempfile.TemporaryDirectory(prefix="chaos-rule-") as tmp:
                print(f"honest run {i}: {honest_run(Path(tmp)):.3f}", flush=True)
    else:
        raise SystemExit("usage: python -m tests.services.chaos_rule random N | live N")


if __name__ == "__main__":
    main(sys.argv[1:])

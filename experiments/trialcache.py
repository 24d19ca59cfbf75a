"""The reproduction's trial cache and work plan.

Caching: each trial's result is a JSON file `cache/<condition>/<arm>/<trial>-<key>.json`, written
atomically by the worker the moment the trial finishes, where key hashes everything that determines the
result (environment, layout, seed, episodes, agent config, observer config, RESULTS_VERSION). An
interrupted run therefore resumes with only the missing trials, and a second run only re-plots. A trial
whose agent ignores feedback (DQN) does not depend on the observer or the teacher rule, so its key leaves
them out and the Maze MDP conditions share one set of DQN trials (run once, stored under each condition).

Batching: all missing trials of one environment family (same observation and action spaces), whatever
their condition and arm, go into the same lockstep batches, split over the workers, so the stragglers
of one condition share ticks with those of others. Results do not depend on the batching
(tests/experiments/test_batching.py).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import json
import os
from dataclasses import dataclass, field

from experiments.conditions import Condition, Scale, n_trials, trial_spec
from experiments.runner import TrialResult, TrialSpec

RESULTS_VERSION = 3
"""Bump when a change to the core changes results, so cached trials are recomputed."""

# Environments that can share a lockstep batch (same observation and action spaces).
FAMILY = {
    "maze": "maze",
    "maze-pomdp": "maze-pomdp",
    "taxi": "taxi",
    "taxi-fixed": "taxi",
    "taxi-s": "taxi-s",
    "taxi-fixed-s": "taxi-s",
}


def _record(obj) -> dict:
    return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}


def trial_key(spec: TrialSpec) -> str:
    agent = spec.agent
    uses_feedback = agent.train_h or agent.reward_shaping
    payload = {
        "version": RESULTS_VERSION,
        "env": spec.env,
        "layout": spec.layout,
        "seed": spec.seed,
        "episodes": spec.episodes,
        "agent": _record(agent),
        "observer": _record(spec.observer) if uses_feedback else None,
        "teacher_rule": spec.teacher_rule if uses_feedback else None,
    }
    return hashlib.sha1(json.dumps(payload, sort_keys=True, default=list).encode()).hexdigest()[:16]


@dataclass
class Slot:
    cond: str
    algo: str
    trial: int
    path: str


@dataclass
class Task:
    key: str
    spec: TrialSpec
    slots: list[Slot] = field(default_factory=list)


def result_record(key: str, result: TrialResult) -> dict:
    eps = result.episodes
    return {
        "key": key,
        "version": RESULTS_VERSION,
        "spec": {
            "env": result.spec.env,
            "layout": result.spec.layout,
            "seed": result.spec.seed,
            "episodes": result.spec.episodes,
            "agent": _record(result.spec.agent),
            "observer": _record(result.spec.observer),
        },
        "total_steps": result.total_steps,
        "return": [e["return"] for e in eps],
        "steps": [e["steps"] for e in eps],
        **{name: [e[name] for e in eps] for name in EXTRA_FIELDS},
    }


EXTRA_FIELDS = ("feedback_given", "feedback_credited", "alpha_h", "h_decided", "greedy", "mean_lag")


def write_json_atomic(path: str, obj) -> None:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        json.dump(obj, fh)
    os.replace(tmp, path)


def read_json_or_none(path: str):
    """The JSON in `path`, or None when it is missing or unreadable (a previous run's timing, claims)."""
    try:
        with open(path) as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


def read_cached(path: str, key: str) -> dict | None:
    try:
        with open(path) as fh:
            rec = json.load(fh)
    except (OSError, ValueError):
        return None
    return rec if rec.get("key") == key else None


def plan(conds: list[Condition], scale: Scale, cache_dir: str) -> tuple[dict, list[Task], int]:
    """(cached records by (cond, arm, trial), tasks to run, number of slots reused from another
    condition's identical trial)."""
    cached: dict[tuple[str, str, int], dict] = {}
    by_key: dict[str, Task] = {}
    for c in conds:
        for algo in c.arms:
            for k in range(n_trials(c, scale)):
                spec = trial_spec(c, algo, k, scale)
                key = trial_key(spec)
                path = os.path.join(cache_dir, c.name, algo.replace("/", "-"), f"{k:03d}-{key}.json")
                rec = read_cached(path, key)
                if rec is not None:
                    cached[(c.name, algo, k)] = rec
                    continue
                by_key.setdefault(key, Task(key, spec)).slots.append(Slot(c.name, algo, k, path))
    # A trial that only lacks its own file but exists under another condition (same key) is copied.
    reused = 0
    todo = []
    known = {rec["key"]: rec for rec in cached.values()}
    for key, task in by_key.items():
        if key in known:
            for s in task.slots:
                write_json_atomic(s.path, known[key])
                cached[(s.cond, s.algo, s.trial)] = known[key]
                reused += 1
        else:
            todo.append(task)
    return cached, todo, reused


# Rough CPU cost of an episode (arbitrary units), by environment: environment steps per episode averaged
# over a run times the relative cost of a step, to balance jobs between workers. Checked against the jobs
# of full runs (timing.json: each job's env, trials and cpu_s).
EPISODE_COST = {
    "maze": 150.0,
    "maze-pomdp": 80.0,
    "taxi": 1000.0 * 0.6,
    "taxi-fixed": 300.0,
    # the reproduction's Taxi: 519 inputs and b = 1 cost about ten times a Maze step (commit 5d2c95e:
    # its 48 trials x 100 episodes took about 1080 CPU s, the Maze's 1764 x 60 and the POMDP's 240
    # about 500). Steps per episode: DQN's pilot and 5d2c95e's trials (Gymnasium's Taxi over 200
    # episodes: about 85 000 steps per learning trial, 1000 per episode for a collapsed Deep TAMER).
    "taxi-s": 560.0 * 10,
    "taxi-fixed-s": 450.0 * 10,
}
ALGO_COST = {"dqn-tamer": 1.5}
"""DQN-TAMER trains Q and H every step; the other agents one network."""
JOBS_PER_WORKER = 4
"""Jobs are cut so that there are about this many per worker: small enough that the workers, taking the
next job as they finish one (longest first), end within a small job of each other."""
MIN_PART_TRIALS = {"maze": 100, "maze-pomdp": 100}
"""A Maze batch is not cut below this many trials (beyond one part per worker): its steps are cheap (about 30 us of
arithmetic per trial), so each part's own tail (a few trials stuck in 1000-step episodes, ticking with a per-tick
overhead of several trials' arithmetic) would cost more than the balance gains. A Taxi step costs about ten times more,
so a few trials per part lose little."""
MAX_PART_TRIALS = {"maze": 1024, "maze-pomdp": 1024}
"""Nor above this many: a Maze trial-step costs the same from 64 to 1,024 trials in a batch (30 us) and more beyond
(4,096 trials: 16% slower, its [n, 32, 100] temporaries leave the cache), and a part holds up to 0.85 MB of replay
and D_global per trial, copied when finished trials are dropped: the declaration of 28 November's 30,000 Maze
trials would otherwise be cut into 5 parts of 6,000 (docs/notes/2026-11-28-runner-speed.md)."""


def trial_cost(spec: TrialSpec) -> float:
    return spec.episodes * EPISODE_COST.get(spec.env, 300.0) * ALGO_COST.get(spec.agent.algo, 1.0)


def job_cost(tasks: list[Task]) -> float:
    return sum(trial_cost(t.spec) for t in tasks)


def _batch_group(spec: TrialSpec) -> tuple:
    """Trials that can share a lockstep batch: same observation and action spaces, same structural settings."""
    from common.agents.build import SHARED_FIELDS

    return (FAMILY.get(spec.env, spec.env),) + tuple(getattr(spec.agent, f) for f in SHARED_FIELDS)


def make_jobs(tasks: list[Task], workers: int, per_worker: int = JOBS_PER_WORKER) -> list[list[Task]]:
    """Batches for the workers, in the order they are handed out: longest (estimated) first.

    Trials that can share a lockstep batch (`_batch_group`) are cut into interleaved parts, each with a
    similar mix of conditions and agents (so parts of one group cost about the same even where the
    estimate is off), of about total / (workers x per_worker) estimated cost each. The pool hands the next
    job to whichever worker is free (longest-processing-time-first list scheduling), so the workers finish
    within about one small job of each other instead of one running a whole environment kind alone. Larger
    batches amortise more per-tick overhead, so a Maze part keeps at least MIN_PART_TRIALS trials, and at most
    MAX_PART_TRIALS."""
    groups: dict[tuple, list[Task]] = {}
    for t in tasks:
        groups.setdefault(_batch_group(t.spec), []).append(t)
    total = sum(job_cost(ts) for ts in groups.values())
    target = total / max(workers * per_worker, 1) if workers > 1 else float("inf")
    jobs = []
    for ts in groups.values():
        ts = sorted(
            ts,
            key=lambda t: (
                t.spec.agent.algo,
                t.slots[0].cond if t.slots else "",
                t.slots[0].trial if t.slots else 0,
                t.key,
            ),
        )
        # up to one part per worker always (so a lone group still uses every worker), more only while each
        # part keeps MIN_PART_TRIALS
        most = max(min(workers, len(ts)), len(ts) // MIN_PART_TRIALS.get(FAMILY.get(ts[0].spec.env, ts[0].spec.env), 1))
        parts = max(1, min(most, int(math.ceil(job_cost(ts) / max(target, 1e-9) - 1e-9))))
        parts = max(parts, -(-len(ts) // MAX_PART_TRIALS.get(FAMILY.get(ts[0].spec.env, ts[0].spec.env), len(ts))))
        jobs.extend([ts[i::parts] for i in range(parts)])
    jobs.sort(key=lambda j: -job_cost(j))
    return jobs

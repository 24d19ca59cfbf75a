"""The in-process runner: the core's step loop on a virtual clock, many trials stepped in lockstep.

Virtual time: trial i's k-th action is taken at t = k (one unit per step), which is k * `step_seconds` seconds
(0.5 s: 2 steps/s), the clock of a delay learned in seconds. The observer's reactions land between steps (see
`common.core.observer.REACTION_OFFSET`), or after a delay in seconds (`ObserverConfig.delay_s`). Per tick, in
`common.agents.agent.StepLoop`'s order (Algorithm 2 of the paper): credit the feedback that arrived since the previous
action, act, step the env, record the step and run the every-b-steps updates; the observer watches the step and
its reaction is delivered on the tick after it lands.

Trials batched together only share arithmetic: each has its own env, observer, agent state and random
streams, so a trial's actions and returns do not depend on which other trials run beside it. Every
per-tick operation is vectorised over the running trials (the agent's row methods, `envbatch` tables, the
batched observer), and finished trials are dropped from the batch (`TrialBatchAgent.select`), so a batch
costs what its running trials cost.
"""

from __future__ import annotations

import ctypes
import functools
import time
from collections.abc import Callable

import numpy as np
from threadpoolctl import threadpool_limits

from common.agents import AgentConfig, TrialBatchAgent, make_agent
from common.agents.agent import CREDITED, STALE, StepLoop
from common.envs import make_env, obs_shape
from common.core.delay_model import FixedDelay
from common.core.observer import MAX_REACTION_S, REACTION_OFFSET, ObserverBatch
from common.core.seeding import derive_seed
from experiments.envbatch import LoopEnvs, TableEnvs
from experiments.trial_types import TrialSpec, TrialResult

# glibc's malloc options (mallopt(3)): keep this much freed memory at the top of the heap, and grow it by this much.
M_TRIM_THRESHOLD, M_TOP_PAD = -1, -2
HEAP_KEPT_BYTES, HEAP_PAD_BYTES = 256 << 20, 64 << 20


@functools.cache  # process-wide options: set once, not at every run_trials
def hold_freed_heap() -> bool:
    """Keep freed memory in this process's heap instead of handing it back to the system at once.

    Why: by default glibc trims the heap as soon as 128 KB lie free at its top, and the next step's numpy temporaries
    fault the same pages back in, zero-filled. On the reproduction's Taxi (519 inputs, an update every step) that was
    4.1 million page faults and a quarter of a trial's CPU (docs/notes/2026-11-26-reproduction-time.md); the Maze's
    small arrays never reached the threshold. The allocator holds memory, not arithmetic: results are bit for bit the
    same (tested). Returns whether the options took (False where the C library has no mallopt)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    return mallopt(M_TRIM_THRESHOLD, HEAP_KEPT_BYTES) == 1 and mallopt(M_TOP_PAD, HEAP_PAD_BYTES) == 1


def greedy_steps(agent: TrialBatchAgent, i: int, spec: TrialSpec, limit: int = 100) -> int | None:
    """Steps the greedy policy of trial (row) i needs to finish an episode on a fresh copy of its env
    (None if it does not within `limit`). Learning and random streams are untouched."""
    env, _ = make_env(spec.env, spec.layout, spec.teacher_rule)
    obs = env.reset(seed=derive_seed(spec.seed, "greedy-eval") % (2**31))[0]
    for k in range(1, limit + 1):
        obs, _, term, trunc, _ = env.step(agent.greedy_action(i, obs))
        if term:
            return k
        if trunc:
            return None
    return None


def fixed_delay_summary(spec: TrialSpec, feedbacks: int) -> dict:
    """The assumed step lags of a trial that does not learn its teacher's delay, in seconds on its clock, and
    the feedbacks credited with them."""
    probs = ",".join(repr(float(p)) for p in spec.agent.assumed_delay_probs)
    return {
        **FixedDelay(f"steps:{probs}", unit=spec.step_seconds).summary(),
        "feedbacks": int(feedbacks),
        "learned": False,
    }


def _bucket(n: int) -> str:
    return "1" if n <= 1 else "2-4" if n <= 4 else "5-16" if n <= 16 else "17-64" if n <= 64 else "65+"


def _train_group(agent: AgentConfig) -> int:
    return {(True, False): 0, (True, True): 1, (False, True): 2}.get((agent.train_q, agent.train_h), 3)


class _Batch:
    """The running batch: per-row state (rows are renumbered when finished trials are dropped)."""

    def __init__(
        self,
        specs: list[TrialSpec],
        use_tables: bool,
        record_actions: bool,
        greedy_eval: bool,
        on_episode,
        on_trial_done,
        on_input,
    ):
        B = len(specs)
        # Rows are ordered by what the agents train (Q only, Q and H, H only), so the trials due for a Q or
        # an H update are consecutive rows (updated in place, without copies). Results and callbacks use the
        # caller's indices.
        perm = sorted(range(B), key=lambda i: _train_group(specs[i].agent))
        rows_specs = [specs[i] for i in perm]
        envs, rules = zip(*(make_env(s.env, s.layout, s.teacher_rule) for s in rows_specs))
        obs_dim, n_actions = envs[0].observation_space.shape[0], envs[0].action_space.n
        if any(e.observation_space.shape[0] != obs_dim or e.action_space.n != n_actions for e in envs):
            raise ValueError("trials batched together must share observation and action spaces")
        env_seeds = [derive_seed(s.seed, "env") % (2**31) for s in rows_specs]
        EnvBatch = TableEnvs if use_tables and TableEnvs.supports(envs) else LoopEnvs
        self.world = EnvBatch(
            list(envs), list(rules), [(s.env, s.layout, s.teacher_rule) for s in rows_specs], env_seeds
        )
        self.observers = ObserverBatch(
            [s.observer for s in rows_specs], [derive_seed(s.seed, "observer") for s in rows_specs]
        )
        self.agent = make_agent(
            [s.agent for s in rows_specs],
            obs_shape(envs[0]),
            n_actions,
            [s.seed for s in rows_specs],
            hot_inputs=getattr(envs[0].unwrapped, "hot_inputs", None),  # (Taxi's one-hot observations: kept as codes)
        )
        self.loop = StepLoop(self.agent)
        self.specs, self.results = specs, [TrialResult(s) for s in specs]
        self.n_episodes = np.array([s.episodes for s in specs], np.int64)
        self.record_actions, self.greedy_eval = record_actions, greedy_eval
        self.on_episode, self.on_trial_done, self.on_input = on_episode, on_trial_done, on_input
        step_s = np.array([s.step_seconds for s in rows_specs], np.float64)
        if not np.all(step_s > 0):
            raise ValueError("step_seconds must be positive")
        self.learns_delay = any(s.agent.learn_delay for s in rows_specs)
        self.R = self.observers.max_lag + 1  # a reaction lands within R ticks of its step
        if self.observers.in_seconds:
            self.R = max(self.R, int(np.ceil(MAX_REACTION_S / step_s.min())) + 1)
        self.st = {
            "orig": np.array(perm, np.int64),
            "active": np.array([s.episodes > 0 for s in rows_specs]),
            "obs": np.zeros((B, obs_dim), np.float32),
            "episode": np.zeros(B, np.int64),
            "ep_return": np.zeros(B),
            "ep_steps": np.zeros(B, np.int64),
            "ep_given": np.zeros(B, np.int64),
            "ep_credited": np.zeros(B, np.int64),
            "ep_stale": np.zeros(B, np.int64),
            # inbox[row, landing tick % R, R - 1 - lag]: value of the reaction to step (landing - lag), 0 = none;
            # along the last axis reactions are in the order they were emitted (oldest step first).
            "inbox": np.zeros((B, self.R, self.R), np.int64),
            "inbox_t": np.zeros((B, self.R, self.R), np.float64),  # its stamp in steps (delays in seconds)
            "step_s": step_s,
        }
        for k in range(B):
            self.st["obs"][k] = self.world.reset(k)
        self.finished_rows = 0

    def deliver(self, rows: np.ndarray, step: np.ndarray) -> None:
        """Credit what landed after each trial's previous action (at step - 1 + REACTION_OFFSET), in emission
        order, one reaction per trial per round."""
        st, R = self.st, self.R
        slot = (step - 1) % R
        due = st["inbox"][rows, slot]
        if not np.count_nonzero(due):  # (the per-tick test: a C call, cheaper than .any())
            return
        st["inbox"][rows, slot] = 0
        has = due != 0
        counts = has.sum(axis=1)
        k = (counts > 0).nonzero()[0]
        if self.observers.in_seconds:
            self.deliver_stamped(rows[k], due[k], st["inbox_t"][rows[k], slot[k]], counts[k])
            return
        order = np.argsort(~has[k], axis=1, kind="stable")
        values = np.take_along_axis(due[k], order, axis=1)  # each trial's reactions, oldest step first
        t_f = (step[k] - 1).astype(np.float64) + REACTION_OFFSET
        if self.on_input is not None:
            for row, t, n, v in zip(rows[k], t_f, counts[k], values):
                for value in v[:n]:
                    self.on_input(int(st["orig"][row]), "feedback", {"t": float(t), "value": int(value)})
        out = self.loop.credit(
            rows[k], t_f, values, counts[k], t_f * st["step_s"][rows[k]] if self.learns_delay else None
        )
        self.count_outcomes(rows[k], counts[k], out)

    def deliver_stamped(self, rk, due, stamps, counts) -> None:
        """Reactions each with its own stamp (delays in seconds) for trials rk: credited one round at a time,
        each trial's in the order of their stamps."""
        st = self.st
        stamps = np.where(due != 0, stamps, np.inf)
        order = np.argsort(stamps, axis=1, kind="stable")
        stamps = np.take_along_axis(stamps, order, axis=1)
        values = np.take_along_axis(due, order, axis=1)
        for rnd in range(int(counts.max())):
            g = (counts > rnd).nonzero()[0]
            if self.on_input is not None:
                for row, t, v in zip(rk[g], stamps[g, rnd], values[g, rnd]):
                    self.on_input(int(st["orig"][row]), "feedback", {"t": float(t), "value": int(v)})
            out = self.loop.credit(rk[g], stamps[g, rnd], values[g, rnd], None, stamps[g, rnd] * st["step_s"][rk[g]])
            self.count_outcomes(rk[g], np.ones(len(g), np.int64), out)

    def count_outcomes(self, rk, counts, out) -> None:
        """Per trial rk: `counts` feedbacks given, credited or stale as `out` says."""
        st = self.st
        st["ep_given"][rk] += counts
        st["ep_credited"][rk] += np.where(out.status == CREDITED, counts, 0)
        st["ep_stale"][rk] += np.where(out.status == STALE, counts, 0)

    def tick(self) -> np.ndarray:
        """One step of every running trial; returns the rows whose episode ended."""
        st, agent = self.st, self.agent
        rows = st["active"].nonzero()[0]
        sel = slice(None) if len(rows) == len(st["active"]) else rows  # every row (the usual case): views
        step = agent.steps[sel].copy()  # this action's virtual time, in steps
        self.deliver(rows, step)
        a = agent.act(st["obs"], st["active"])[sel]
        nxt, rew, term, trunc, intended = self.world.step(rows, a)
        if self.on_input is not None:
            self.trace_steps(rows, step, a, rew, nxt, term, trunc, intended)
        episode = st["episode"][sel]
        t = step.astype(np.float64)
        # (seconds and the rule's polarity are kept only where a delay is learned in seconds: the paper's
        # step-clock credit needs neither, and the per-tick path stays as fast as it was)
        seconds = (t * st["step_s"][sel], intended) if self.learns_delay else (None, None)
        self.loop.step(rows, st["obs"][sel], a, rew, nxt, term, t, episode, *seconds)
        give, value, lag = self.observers.react(rows, intended, episode, step)
        if self.observers.in_seconds:
            self.post_timed(rows, sel, t, give, value, lag)
        else:
            g = give.nonzero()[0]
            st["inbox"][rows[g], (step[g] + lag[g]) % self.R, self.R - 1 - lag[g]] = value[g]
        if self.record_actions:
            for i, act in zip(st["orig"][rows], a):
                self.results[i].actions.append(int(act))
        st["ep_return"][sel] += rew
        st["ep_steps"][sel] += 1
        st["obs"][sel] = nxt
        return rows[term | trunc]

    def post_timed(self, rows, sel, t, give, value, lag) -> None:
        """Reactions with a delay in seconds: each its own stamp (steps), landing after whole steps."""
        st = self.st
        stamp = t + lag + REACTION_OFFSET
        delay = self.observers.last_delay_s / st["step_s"][sel]
        timed = np.isfinite(delay)
        stamp = np.where(timed, t + np.where(timed, delay, 0.0), stamp)
        lag = np.where(timed, np.floor(stamp - t).astype(np.int64), lag)
        g, step = give.nonzero()[0], t.astype(np.int64)
        at = (rows[g], (step[g] + lag[g]) % self.R, self.R - 1 - lag[g])
        st["inbox"][at], st["inbox_t"][at] = value[g], stamp[g]

    def trace_steps(self, rows, step, a, rew, nxt, term, trunc, intended) -> None:
        st = self.st
        for k, row in enumerate(rows):
            self.on_input(
                int(st["orig"][row]),
                "step",
                {
                    "t": float(step[k]),
                    "episode": int(st["episode"][row]),
                    "obs": st["obs"][row].copy(),
                    "action": int(a[k]),
                    "reward": float(rew[k]),
                    "next_obs": np.array(nxt[k]),
                    "terminated": bool(term[k]),
                    "truncated": bool(trunc[k]),
                    "polarity": int(intended[k]),
                },
            )

    def end_episodes(self, ended: np.ndarray) -> None:
        st, agent = self.st, self.agent
        eps_now, alpha_now = agent.epsilons(ended), agent.alpha_h(ended)
        delay_now = agent.median_delay_s(ended)
        # mean_lag in steps; for a learned delay its mean in seconds as a lag (a lag-d reaction comes d + 0.5
        # steps after its step), comparable with the observer's true mean lag
        learned_lag = agent.median_delay_s(ended, mean=True) / st["step_s"][ended] - REACTION_OFFSET
        lag_now = np.where(np.isnan(learned_lag), agent.mean_lag(ended), learned_lag)
        for j, row in enumerate(ended):
            i = int(st["orig"][row])
            record = {
                "episode": int(st["episode"][row]),
                "return": float(st["ep_return"][row]),
                "steps": int(st["ep_steps"][row]),
                "feedback_given": int(st["ep_given"][row]),
                "feedback_credited": int(st["ep_credited"][row]),
                "feedback_stale": int(st["ep_stale"][row]),
                "epsilon": float(eps_now[j]),
                "alpha_h": float(alpha_now[j]),
                # who decides: greedy actions this episode, and those where H overruled argmax Q
                "h_decided": int(agent.h_decided_count[row]),
                "greedy": int(agent.greedy_count[row]),
                "mean_lag": float(lag_now[j]),  # mean of the lag distribution credit uses now (steps)
                # the learned delay's median in seconds (None: not learned)
                "delay_median_s": None if np.isnan(delay_now[j]) else float(delay_now[j]),
            }
            agent.h_decided_count[row] = agent.greedy_count[row] = 0
            if self.greedy_eval:
                record["greedy_steps"] = greedy_steps(agent, int(row), self.specs[i])
            self.results[i].episodes.append(record)
            if self.on_episode is not None:
                self.on_episode(i, record)
            st["episode"][row] += 1
            st["ep_return"][row] = 0.0
            st["ep_steps"][row] = st["ep_given"][row] = st["ep_credited"][row] = st["ep_stale"][row] = 0
            if st["episode"][row] >= self.n_episodes[i]:
                self.finish(int(row), i)
            else:
                st["obs"][row] = self.world.reset(int(row))
        # Drop finished trials once they are an eighth of the batch (or the batch is small).
        if self.finished_rows and self.finished_rows >= max(1, len(st["orig"]) // 8) and st["active"].any():
            keep = st["active"].nonzero()[0]
            for part in (self.agent, self.world, self.observers):
                part.select(keep)
            self.st = {k: v[keep] for k, v in st.items()}
            self.finished_rows = 0

    def finish(self, row: int, i: int) -> None:
        """Trial i (at `row`) has run its episodes; reactions still in flight are never delivered."""
        self.st["active"][row] = False
        self.st["inbox"][row] = 0
        self.results[i].total_steps = int(self.agent.steps[row])
        self.results[i].weights = self.agent.policy_weights(row)
        credited = sum(e["feedback_credited"] for e in self.results[i].episodes)
        self.results[i].delay = self.agent.delay_summary(row) or fixed_delay_summary(self.specs[i], credited)
        self.finished_rows += 1
        if self.on_trial_done is not None:
            self.on_trial_done(i, self.results[i])


def run_trials(
    specs: list[TrialSpec],
    on_episode: Callable[[int, dict], None] | None = None,
    record_actions: bool = False,
    greedy_eval: bool = False,
    on_trial_done: Callable[[int, TrialResult], None] | None = None,
    use_tables: bool = True,
    profile: dict | None = None,
    on_input: Callable[[int, str, dict], None] | None = None,
) -> list[TrialResult]:
    """Run every trial to its episode count; trials must share observation and action spaces.

    `on_episode(i, record)` is called after each episode of trial i (the index into `specs`),
    `on_trial_done(i, result)` when trial i has run all its episodes. `greedy_eval` adds `greedy_steps`
    to each episode record: the length of the greedy policy's path after that episode (None if it does not
    reach the goal in 100 steps). `use_tables=False` steps the real environments one by one instead of
    the compiled tables (same results, slower; for tests and for environments without tables).
    `profile`, if given, receives per batch-size bucket ("1", "2-4", "5-16", "17-64", "65+" running
    trials) the ticks run and the CPU seconds they took. `on_input(i, kind, record)`, if given, sees every
    input of trial i's step loop in the order it is consumed ("feedback": t, value; "step": t, episode, obs,
    action, reward, next_obs, terminated, truncated, and the teacher rule's polarity): what a live learner would
    be sent.
    """
    if not specs:
        return []
    import torch  # (here, not at the top: `python -m experiments --help` and its argument errors stay quick)

    torch.set_num_threads(1)  # one thread: the same arithmetic whatever the batch, and room for workers
    # numpy's OpenBLAS too: above about 10^5 multiply-adds it starts threads, which on a loaded 2-core
    # machine made Taxi's 520-input forward pass 370x slower (13.6 ms against 37 us, measured).
    threadpool_limits(1, user_api="blas")
    hold_freed_heap()
    assert 0 < REACTION_OFFSET < 1, "delivery assumes reactions land strictly between two steps"
    for s in specs:
        if s.episodes < 0:
            raise ValueError(f"episodes must be >= 0, got {s.episodes}")
    batch = _Batch(specs, use_tables, record_actions, greedy_eval, on_episode, on_trial_done, on_input)
    tick_start = time.process_time()
    while np.count_nonzero(batch.st["active"]):
        running = int(batch.st["active"].sum()) if profile is not None else 0
        ended = batch.tick()
        if profile is not None:
            now = time.process_time()
            bucket = profile.setdefault(_bucket(running), {"ticks": 0, "cpu_s": 0.0, "trial_steps": 0})
            bucket["ticks"] += 1
            bucket["cpu_s"] += now - tick_start
            bucket["trial_steps"] += running
            tick_start = now
        if len(ended):
            batch.end_episodes(ended)
    for i, s in enumerate(specs):
        if s.episodes == 0 and on_trial_done is not None:
            on_trial_done(i, batch.results[i])
    return batch.results

"""DQN, DQN+RS, Deep TAMER and DQN-TAMER as one agent of parts over a batch of independent trials.

The parts (`AgentParts`, built by `build_parts` from the configs, or passed in), each small and tested alone:
  q, q_target      value networks (`networks.ValueNetworks`) with their optimiser; Q learns from replay;
  h                H's value network with its optimiser; learns from feedback;
  replay           `TransitionReplay`: the transitions Q samples (and shaping rewrites);
  feedback_memory  `FeedbackMemory`: D_global, every credited (step, feedback, weight);
  history          `BatchStepHistory`: the recent steps that credit (`common.core.credit`) weighs;
  feedback         `FeedbackDoor` (`feedback.py`, inherited): the one way feedback comes in;
  explorer, mixture  epsilon-greedy on alpha_q Q + alpha_h H (`explorer.py`; its acting methods, `Acting`,
                   inherited).
The four algorithms are ways of assembling them (`AgentConfig` presets: which parts learn, the mixture
weights, shaping), so a batch may mix them.

One step of Algorithm 2 of the paper (`StepLoop`), written once for every driver: the in-process runner
(batched, on the virtual clock), the live learner (one trial, from Zenoh inputs) and `replay retrain` (from a
log). For each step of each trial, in this order: 1. `credit`: the feedback that arrived before this step's
action, through the agent's one door (`feedback_rounds`: by timestamp over the intervals the held steps were
shown, whatever their episode, with its teacher's delay from the agent's registry); 2. `step`: the step's
transition is recorded (replay, the step history that credit reads); 3. the every-b-steps updates (a Q minibatch
from replay, an H minibatch from D_global), then the target network's sync when due. The live learner cannot
know of a feedback before the next step's action has arrived (its stamp must be placed between two actions), so
this is the order in which every driver can see its inputs; given the same ordered inputs they end with the same
weights (tests/experiments/test_one_loop.py). Acting is not part of it: it changes no learning state (exploration
draws are counter-based).

How it stays fast and batch-independent:
  * every per-trial quantity has a leading trial axis and every method works on a set of trial rows at
    once (the single-trial methods `record_step`, `give_feedback` wrap the row versions);
  * random draws are counter-based (`explorer.UniformBlocks`): exploration at step t of trial i and the u-th replay
    minibatch of trial i are pure functions of (trial key, t or u), never of other trials;
  * gradient steps run only on the trial rows that are due; with the numpy MLP (`networks.StackedMLP`) in
    float32 with a hand-written backward (no autograd graph, low per-call overhead), Q's and H's steps
    stacked into one computation when their networks have one shape (`networks.fit_together`);
  * `select(rows)` drops finished trials, so a batch costs what its running trials cost.
A trial run alone (B = 1) and the same trial run among others give the same actions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.agents.build import SHARED_FIELDS, AgentParts, build_parts
from common.agents.config import AgentConfig
from common.agents.feedback import (
    Screen,
    CREDITED,  # noqa: F401
    IGNORED,  # noqa: F401
    STALE,  # noqa: F401
    STATUS_NAMES,  # noqa: F401
    FeedbackDoor,  # noqa: F401
    FeedbackOutcome,  # noqa: F401
)
from common.agents.explorer import Acting, RowConstants, to_integers
from common.agents.memory import BatchCredit
from common.agents.mlp import row_max
from common.agents.networks import HUBER_MEAN, SQUARED_MEAN, FitJob, fit_together

# At most this many due rows run the Q and H minibatch steps as one stacked computation (above it,
# copying the weights together costs more than the saved calls).
MERGE_ROWS = 16


class TrialBatchAgent(Acting, FeedbackDoor):
    # Per-trial arrays that `select` slices (the parts slice their own).
    _ROW_ARRAYS = (
        "train_q",
        "train_h",
        "shaping",
        "steps",
        "q_updates",
        "h_updates",
        "greedy_count",
        "h_decided_count",
    )

    def __init__(
        self,
        configs: list[AgentConfig],
        obs_dim: int,
        n_actions: int,
        seeds: list[int],
        step_unit: float = 1.0,
        parts: AgentParts | None = None,
    ):
        if len(configs) != len(seeds) or not configs:
            raise ValueError("need one config per seed, at least one")
        base = configs[0]
        for c in configs[1:]:
            for name in SHARED_FIELDS:
                if getattr(c, name) != getattr(base, name):
                    raise ValueError(f"trials batched together must share {name}")
        self.configs, self.base = list(configs), base
        self.obs_dim, self.n_actions = obs_dim, n_actions
        self.seeds = [int(s) for s in seeds]
        p = parts if parts is not None else build_parts(self.configs, obs_dim, n_actions, self.seeds, step_unit)
        self.parts = p
        self.q, self.q_target, self.h = p.q, p.q_target, p.h
        self.replay, self.feedback_memory, self.history = p.replay, p.feedback_memory, p.history
        self.explorer, self.mixture = p.explorer, p.mixture
        self.delays = p.delays
        self.hot = p.hot  # observations kept and fed to Q and H as codes (`mlp.HotCodes`), or None: dense
        # At most one held step per point mass of the assumed delay can be credited by one feedback.
        self.local_width = min(self.delays.width, base.history_steps)
        self.train_q = np.array([c.train_q for c in configs])
        self.train_h = np.array([c.train_h for c in configs])
        self.shaping = np.array([c.reward_shaping for c in configs])
        B = len(configs)
        self.steps = np.zeros(B, dtype=np.int64)  # steps taken so far, per trial
        self.q_updates, self.h_updates = np.zeros(B, dtype=np.int64), np.zeros(B, dtype=np.int64)
        # Who decides (read and reset by the runner per episode): steps of trials with Q and H, and those
        # where the mixture's greedy action differed from Q's own (H overruled Q).
        self.greedy_count = np.zeros(B, dtype=np.int64)
        self.h_decided_count = np.zeros(B, dtype=np.int64)
        # The latest feedback round's credit (`credited`): what the live learner reports in Credit messages, so it
        # never computes a feedback's credit twice.
        self.last_credit: tuple[np.ndarray, BatchCredit] | None = None  # its step-clock trials: (indices, credit)
        self.last_timed: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # its trials in seconds: index -> positions, w
        # Rows that train both Q and H (whose choices `act` compares), and whether there is one, per row set.
        self._learns_both = RowConstants(
            lambda rows: (
                self.train_q[rows] & self.train_h[rows],
                bool((self.train_q[rows] & self.train_h[rows]).any()),
            )
        )

    # ---------------------------------------------------------------------------------- observing
    def record_steps(
        self,
        rows: np.ndarray,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
        t_actions: np.ndarray,
        episodes: np.ndarray,
        seconds: np.ndarray | None = None,
        polarity: np.ndarray | None = None,
    ) -> None:
        """Trials `rows` (distinct) took `actions` at times `t_actions` in episodes `episodes`: store transitions,
        remember steps. Where a delay is learned in seconds the driver also gives `seconds` (the teacher's clock)
        and the task rule's `polarity` of each (+-1, 0 unknown: the model of the rated event it is fitted on)."""
        rows = np.asarray(rows, np.int64)
        obs = self._kept(np.asarray(obs, np.float32).reshape(len(rows), self.obs_dim))
        actions = np.asarray(actions, np.int64)
        slots = self.replay.add_rows(
            rows,
            obs=obs,
            action=actions,
            reward=np.asarray(rewards, np.float32),
            next_obs=self._kept(np.asarray(next_obs, np.float32).reshape(len(rows), self.obs_dim)),
            terminated=np.asarray(terminated, np.float32),
        )
        self.history.push(
            rows,
            np.asarray(t_actions, np.float64),
            obs,
            actions,
            slots,
            np.asarray(episodes, np.int64),
            seconds,
            polarity,
        )
        self.steps[rows] += 1

    def record_step(
        self, i: int, obs, action: int, reward: float, next_obs, terminated: bool, t_action: float, episode: int = 0
    ) -> None:
        """Trial i took `action` at time t_action: store the transition and remember the step."""
        self.record_steps(
            np.array([i]),
            obs,
            np.array([action]),
            np.array([reward]),
            next_obs,
            np.array([float(terminated)]),
            np.array([t_action]),
            np.array([episode]),
        )

    def forget_history(self, i: int) -> None:
        """Drop trial i's held steps (e.g. the actor restarted: nothing before may be credited)."""
        self.history.clear(i)

    # ---------------------------------------------------------------------------------- learning
    def update(self, active: np.ndarray | None = None) -> None:
        """Every b steps: a Q minibatch update and a D_global minibatch update (where they apply), then the
        target network's sync when due. When few rows are due (the per-call overhead dominates) both
        minibatch steps run together (`fit_together`)."""
        c = self.base
        started = self.steps > 0
        due = started if c.update_interval == 1 else started & (self.steps % c.update_interval == 0)
        if active is not None:
            due = due & active
        q_rows = (due & self.train_q & (self.replay.size >= max(c.replay_start, 1))).nonzero()[0]
        h_rows = (due & self.train_h & (self.feedback_memory.size > 0)).nonzero()[0]
        jobs = ([self._q_job(q_rows)] if len(q_rows) else []) + ([self._h_job(h_rows)] if len(h_rows) else [])
        if len(q_rows) + len(h_rows) <= MERGE_ROWS:
            fit_together(jobs)
        else:
            for job in jobs:
                fit_together([job])
        if len(q_rows):
            self.q_updates[q_rows] += 1
        if len(h_rows):
            self.h_updates[h_rows] += 1
        sync = self.train_q & (self.steps % c.target_update_interval == 0) & started
        sync = (sync if active is None else sync & active).nonzero()[0]
        if len(sync):
            self.q_target.sync_from(self.q, sync)

    def idle_update(self) -> None:
        """One more Q and D_global minibatch step between two steps (a paced run's idle time; the learner records
        it in its Ingest order so `replay retrain` repeats it). No target sync: that stays on the step count."""
        c = self.base
        q_rows = (self.train_q & (self.steps > 0) & (self.replay.size >= max(c.replay_start, 1))).nonzero()[0]
        h_rows = (self.train_h & (self.feedback_memory.size > 0)).nonzero()[0]
        jobs = ([self._q_job(q_rows)] if len(q_rows) else []) + ([self._h_job(h_rows)] if len(h_rows) else [])
        if jobs:
            fit_together(jobs)
        self.q_updates[q_rows] += 1
        self.h_updates[h_rows] += 1

    def _q_job(self, rows: np.ndarray) -> FitJob:
        """Q's TD step on a replay minibatch: target r + gamma (1 - terminated) max_a Q_target(s', a)."""
        m = self.replay
        u = self.parts.q_draws.get(rows, self.q_updates[rows])
        b = m.gather_records(rows, to_integers(u, m.size[rows][:, None]))
        col, at, ones = m.columns, m.at, m.with_ones  # (each observation is stored with its bias input)
        q_next = row_max(self.q_target.values(rows, b[:, :, col["next_obs"]], b[:, :, ones["next_obs"]]))
        gamma, done = np.float32(self.base.gamma), b[:, :, at["terminated"]]
        target = b[:, :, at["reward"]] + gamma * (np.float32(1) - done) * q_next
        return FitJob(
            self.q,
            rows,
            b[:, :, col["obs"]],
            b[:, :, at["action"]].astype(np.int64),
            target,
            None,
            HUBER_MEAN,
            b[:, :, ones["obs"]],
        )

    def _h_job(self, rows: np.ndarray) -> FitJob:
        """H's weighted squared-error step on a D_global minibatch."""
        m = self.feedback_memory
        u = self.parts.h_draws.get(rows, self.h_updates[rows])
        b = m.gather_records(rows, to_integers(u, m.size[rows][:, None]))
        col, at = m.columns, m.at
        return FitJob(
            self.h,
            rows,
            b[:, :, col["obs"]],
            b[:, :, at["action"]].astype(np.int64),
            b[:, :, at["feedback"]],
            b[:, :, at["weight"]],
            SQUARED_MEAN,
            b[:, :, m.with_ones["obs"]],
        )

    # -------------------------------------------------------------------------- batch bookkeeping
    def select(self, rows: np.ndarray) -> None:
        """Keep only trials `rows` (in that order): row k of the batch becomes what row rows[k] was.

        Used to drop finished trials; a kept trial continues exactly as it would have."""
        rows = np.asarray(rows, np.int64)
        self.parts.select(rows)
        for name in self._ROW_ARRAYS:
            setattr(self, name, getattr(self, name)[rows])
        self._learns_both.clear()
        self.configs = [self.configs[k] for k in rows]
        self.seeds = [self.seeds[k] for k in rows]

    def state_dict(self) -> dict:
        """Everything that changes while learning (configs and seeds are given at construction)."""
        return {
            **self.parts.state_dict(),
            "steps": self.steps.copy(),
            "q_updates": self.q_updates.copy(),
            "h_updates": self.h_updates.copy(),
        }

    def load_state_dict(self, state: dict) -> None:
        self.parts.load_state_dict(state)
        for name in ("steps", "q_updates", "h_updates"):
            getattr(self, name)[...] = state[name]

    # ------------------------------------------------------------------------------- weights I/O
    def policy_weights(self, i: int = 0) -> dict[str, np.ndarray]:
        """What an actor needs to act for trial i: Q and H weights, as named float32 arrays."""
        out = {f"q.{k}": v for k, v in self.q.policy_state(i).items()}
        out.update({f"h.{k}": v for k, v in self.h.policy_state(i).items()})
        return out

    def load_policy_weights(self, weights: dict, i: int = 0) -> None:
        self.q.load_policy_state(i, {k[2:]: v for k, v in weights.items() if k.startswith("q.")})
        self.h.load_policy_state(i, {k[2:]: v for k, v in weights.items() if k.startswith("h.")})


@dataclass
class FeedbackRound:
    """Per trial asked about: status code (`agent.STATUS_NAMES`), steps credited, mass lost."""

    status: np.ndarray
    steps: np.ndarray
    lost: np.ndarray


class StepLoop:
    """One step of Algorithm 2, as every driver calls it (the module's doc): `credit` what arrived before the step's
    action, then `step` (record it, then the every-b-steps updates)."""

    def __init__(self, agent: TrialBatchAgent):
        self.agent = agent

    def credit(
        self,
        rows: np.ndarray,
        t_feedback: np.ndarray,
        values: np.ndarray,
        counts: np.ndarray | None = None,
        seconds: np.ndarray | None = None,
        teachers: list[str] | None = None,
        screens: list[Screen | None] | None = None,
    ) -> FeedbackRound:
        """Feedback that arrived before the next action: values[k, r] (+-1) for trial rows[k], stamped
        t_feedback[k] on the step clock (`seconds[k]` on the teacher's clock, for a delay in seconds), for
        r < counts[k] (rounds in arrival order; values may be 1-d for one round each), from `teachers[k]` (default:
        the trial's one teacher), seen on `screens[k]` (a person's; None: none)."""
        values = np.asarray(values, np.int64)
        if values.ndim == 1:
            values = values[:, None]
        if counts is None:
            counts = np.ones(len(rows), np.int64)
        return FeedbackRound(
            *self.agent.feedback_rounds(
                np.asarray(rows, np.int64),
                np.asarray(t_feedback, np.float64),
                values,
                counts,
                None if seconds is None else np.asarray(seconds, np.float64),
                teachers,
                screens,
            )
        )

    def step(
        self,
        rows: np.ndarray,
        obs,
        actions,
        rewards,
        next_obs,
        terminated,
        t_action,
        episodes,
        seconds=None,
        polarity=None,
    ) -> None:
        """Trials `rows` (distinct) took a step at t_action (`seconds` on the teacher's clock; the task rule says
        `polarity` of it): record it, then the every-b-steps updates."""
        agent = self.agent
        agent.record_steps(rows, obs, actions, rewards, next_obs, terminated, t_action, episodes, seconds, polarity)
        if len(rows) == agent.B:
            agent.update()
        else:
            active = np.zeros(agent.B, bool)
            active[rows] = True
            agent.update(active)

"""DQN, DQN+RS, Deep TAMER and DQN-TAMER as one agent over a batch of independent trials.

Each trial has its own networks, optimiser state, replay, D_global, step history and random streams;
the batch only shares the arithmetic. A trial run alone (B = 1) and the same trial run among others give
the same actions. The four algorithms differ only in their `AgentConfig` (which parts train, the
mixture weights, shaping), so a batch may mix them.

The pieces (Algorithm 2 of the paper):
  Q learner   - StackedMLP + target copy + TransitionReplay, Huber TD loss, every b steps;
  H learner   - StackedMLP + FeedbackMemory (D_global); on each feedback, credit by timestamp gives
                D_local, updated at once, and D_global is sampled every b steps;
  explorer    - epsilon-greedy on alpha_q Q + alpha_h H (schedules are functions of the step count).

How it stays fast and batch-independent:
  * every per-trial quantity is an array with a leading trial axis and every method works on a set of
    trial rows at once (the single-trial methods `record_step`, `give_feedback` wrap the row versions);
  * random draws are counter-based (`streams`): exploration at step t of trial i and the u-th replay
    minibatch of trial i are pure functions of (trial key, t or u), never of other trials;
  * gradient steps run only on the trial rows that are due (gathered, stepped, scattered back), in numpy
    float32 with the hand-written backward of `networks.mlp_backward` (no autograd graph, low per-call
    overhead); weights go in and out as torch tensors (`policy_weights`, `load_policy_weights`);
  * `select(rows)` drops finished trials, so a batch costs what its running trials cost.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from common.agents.config import AgentConfig
from common.agents.history import BatchStepHistory
from common.agents.networks import StackedMLP, mlp_backward, mlp_forward, row_max, views
from common.agents.optim import FlatRMSProp
from common.agents.replay import FeedbackMemory, TransitionReplay
from common.agents.schedules import AlphaSchedule, EpsilonSchedule
from common.agents.streams import UniformBlocks, to_integers
from common.credit import credit_weights
from common.delay import DelayModel
from common.seeding import derive_seed
from common.util import nz

# Structural settings must agree across a batch; the rest may differ per trial.
SHARED_FIELDS = ("hidden", "lr", "rmsprop_alpha", "rmsprop_eps", "gamma", "batch_size", "replay_size",
                 "replay_start", "target_update_interval", "update_interval", "h_batch_size",
                 "feedback_memory_size", "assumed_delay_probs", "history_steps")

# At most this many due rows run the Q and H minibatch steps as one stacked computation (above it,
# copying the weights together costs more than the saved calls).
MERGE_ROWS = 16

# Status codes of `feedback_round` (the strings of FeedbackOutcome.status, in this order).
IGNORED, CREDITED, STALE = 0, 1, 2
STATUS_NAMES = ("ignored", "credited", "stale")


@dataclass
class FeedbackOutcome:
    """What became of one feedback: credited to `steps` held steps, stale (all mass lost), or ignored."""

    status: str  # "credited" | "stale" | "ignored"
    steps: int = 0
    lost_mass: float = 0.0


def _pick(values: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """values[i, j, actions[i, j, 0]] for values [n, N, A]: [n, N]."""
    n, N, A = values.shape
    return values.reshape(n * N, A)[np.arange(n * N), actions.reshape(-1)].reshape(n, N)


def _key_array(seeds, purpose: str) -> np.ndarray:
    return np.array([derive_seed(s, purpose) for s in seeds], dtype=np.uint64)


class TrialBatchAgent:
    # Per-trial arrays that `select` slices (everything else per trial lives in the learners' objects).
    _ROW_ARRAYS = ("seeds_arr", "explore_key", "q_key", "h_key", "eps_start", "eps_decay", "eps_floor",
                   "alpha_q", "alpha_h0", "alpha_h_decay", "train_q", "train_h", "shaping", "uses_feedback",
                   "steps", "q_updates", "h_updates")

    def __init__(self, configs: list[AgentConfig], obs_dim: int, n_actions: int, seeds: list[int],
                 step_unit: float = 1.0):
        if len(configs) != len(seeds) or not configs:
            raise ValueError("need one config per seed, at least one")
        base = configs[0]
        for c in configs[1:]:
            for name in SHARED_FIELDS:
                if getattr(c, name) != getattr(base, name):
                    raise ValueError(f"trials batched together must share {name}")
        self.configs = list(configs)
        self.base = base
        self.obs_dim, self.n_actions = obs_dim, n_actions
        self.seeds = [int(s) for s in seeds]
        self.assumed_delay = DelayModel(base.assumed_delay_probs, step_unit)
        B = len(configs)

        self.q = StackedMLP(obs_dim, base.hidden, n_actions, [derive_seed(s, "q-init") for s in seeds])
        self.h = StackedMLP(obs_dim, base.hidden, n_actions, [derive_seed(s, "h-init") for s in seeds])
        self.q_target_flat = self.q.flat.copy()
        self.q_opt = FlatRMSProp(self.q, base.lr, base.rmsprop_alpha, base.rmsprop_eps)
        self.h_opt = FlatRMSProp(self.h, base.lr, base.rmsprop_alpha, base.rmsprop_eps)
        self.replay = TransitionReplay(B, base.replay_size, obs_dim)
        self.feedback_memory = FeedbackMemory(B, base.feedback_memory_size, obs_dim)
        self.history = BatchStepHistory(B, base.history_steps, obs_dim)
        # At most one held step per assumed lag can be credited by one feedback.
        self.local_width = min(len(base.assumed_delay_probs), base.history_steps)

        self.seeds_arr = np.array(self.seeds, dtype=np.int64)
        self.explore_key = _key_array(seeds, "explore")
        self.q_key = _key_array(seeds, "q-replay")
        self.h_key = _key_array(seeds, "h-replay")
        # Draws served in blocks (same numbers as one `uniforms` call per step or minibatch).
        self._explore_u = UniformBlocks(self.explore_key, 2)
        self._q_u = UniformBlocks(self.q_key, base.batch_size)
        self._h_u = UniformBlocks(self.h_key, base.h_batch_size)
        self.epsilon = [EpsilonSchedule(c.epsilon_start, c.epsilon_decay, c.epsilon_floor) for c in configs]
        self.alpha = [AlphaSchedule(c.alpha_q, c.alpha_h, c.alpha_h_decay) for c in configs]
        self.eps_start = np.array([c.epsilon_start for c in configs], np.float64)
        self.eps_decay = np.array([c.epsilon_decay for c in configs], np.float64)
        self.eps_floor = np.array([c.epsilon_floor for c in configs], np.float64)
        self.alpha_q = np.array([c.alpha_q for c in configs], np.float64)
        self.alpha_h0 = np.array([c.alpha_h for c in configs], np.float64)
        self.alpha_h_decay = np.array([c.alpha_h_decay for c in configs], np.float64)
        self.train_q = np.array([c.train_q for c in configs])
        self.train_h = np.array([c.train_h for c in configs])
        self.shaping = np.array([c.reward_shaping for c in configs])
        self.uses_feedback = self.train_h | self.shaping
        self.steps = np.zeros(B, dtype=np.int64)  # steps taken so far, per trial
        self.q_updates = np.zeros(B, dtype=np.int64)
        self.h_updates = np.zeros(B, dtype=np.int64)

    @property
    def B(self) -> int:
        return len(self.seeds_arr)

    def _rows_index(self, rows: np.ndarray):
        """How to address trials `rows` (ascending): None for all of them, a slice when they are
        consecutive (numpy views, no copies), else the index array."""
        if len(rows) == self.B:
            return None
        if len(rows) and rows[-1] - rows[0] + 1 == len(rows):
            return slice(int(rows[0]), int(rows[-1]) + 1)
        return rows

    # ----------------------------------------------------------------------------------- acting
    def epsilons(self, rows: np.ndarray | None = None) -> np.ndarray:
        rows = np.arange(self.B) if rows is None else rows
        return np.maximum(self.eps_floor[rows], self.eps_start[rows] - self.eps_decay[rows] * self.steps[rows])

    def alpha_h(self, rows: np.ndarray | None = None) -> np.ndarray:
        rows = np.arange(self.B) if rows is None else rows
        return self.alpha_h0[rows] * self.alpha_h_decay[rows] ** self.steps[rows].astype(np.float64)

    def mixture_weights(self, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(alpha_q, alpha_h) per trial as float32 [n, 1, 1] (alpha_h at each trial's current step)."""
        rows = np.arange(self.B) if rows is None else rows
        aq = self.alpha_q[rows].astype(np.float32).reshape(-1, 1, 1)
        ah = self.alpha_h(rows).astype(np.float32).reshape(-1, 1, 1)
        return aq, ah

    def _scores(self, rows: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """alpha_q Q + alpha_h H for trials `rows`, one observation each (obs: [len(rows), obs_dim])."""
        x = np.asarray(obs, np.float32).reshape(len(rows), 1, self.obs_dim)
        r = self._rows_index(rows)
        aq, ah = self.mixture_weights(rows)
        q = mlp_forward(self.q.rows(r), x)[1]
        h = mlp_forward(self.h.rows(r), x)[1]
        return (aq * q + ah * h)[:, 0, :]

    def scores(self, obs: np.ndarray) -> torch.Tensor:
        """alpha_q Q + alpha_h H for one observation per trial: [B, n_actions]."""
        return torch.from_numpy(self._scores(np.arange(self.B), np.asarray(obs, np.float32).reshape(self.B, self.obs_dim)))

    def greedy_action(self, i: int, obs: np.ndarray) -> int:
        """Trial i's greedy action for one observation, touching no random stream (for evaluation)."""
        return int(self._scores(np.array([i]), np.asarray(obs, np.float32).reshape(1, -1))[0].argmax())

    def preferences(self, i: int, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Trial i's Q and H per action for one observation, with alpha_q and alpha_h now (what the console
        shows a person)."""
        x = np.asarray(obs, np.float32).reshape(1, 1, self.obs_dim)
        r = np.array([i])
        q = mlp_forward(self.q.rows(r), x)[1][0, 0]
        h = mlp_forward(self.h.rows(r), x)[1][0, 0]
        return q.copy(), h.copy(), float(self.alpha_q[i]), float(self.alpha_h(r)[0])

    def act(self, obs: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
        """Epsilon-greedy actions for the active trials (-1 for the others). obs: [B, obs_dim].

        Step t of trial i explores when u(i, 2t) < epsilon(t), with action floor(u(i, 2t + 1) * n_actions).
        """
        rows = np.arange(self.B) if active is None else nz(active)
        actions = np.full(self.B, -1, dtype=np.int64)
        if len(rows) == 0:
            return actions
        obs = np.asarray(obs, np.float32).reshape(self.B, self.obs_dim)
        greedy = self._scores(rows, obs[rows]).argmax(axis=1)
        u = self._explore_u.get(rows, self.steps[rows])
        explore = u[:, 0] < self.epsilons(rows)
        random_action = np.minimum((u[:, 1] * self.n_actions).astype(np.int64), self.n_actions - 1)
        actions[rows] = np.where(explore, random_action, greedy)
        return actions

    # ---------------------------------------------------------------------------------- observing
    def record_steps(self, rows: np.ndarray, obs: np.ndarray, actions: np.ndarray, rewards: np.ndarray,
                     next_obs: np.ndarray, terminated: np.ndarray, t_actions: np.ndarray,
                     episodes: np.ndarray) -> None:
        """Trials `rows` (distinct) took `actions` at times `t_actions` in episodes `episodes`: store
        transitions, remember steps (credit never crosses an episode boundary)."""
        rows = np.asarray(rows, np.int64)
        obs = np.asarray(obs, np.float32).reshape(len(rows), self.obs_dim)
        actions = np.asarray(actions, np.int64)
        slots = self.replay.add_rows(rows, obs=obs, action=actions,
                                     reward=np.asarray(rewards, np.float32),
                                     next_obs=np.asarray(next_obs, np.float32).reshape(len(rows), self.obs_dim),
                                     terminated=np.asarray(terminated, np.float32))
        self.history.push(rows, np.asarray(t_actions, np.float64), obs, actions, slots, np.asarray(episodes, np.int64))
        self.steps[rows] += 1

    def record_step(self, i: int, obs, action: int, reward: float, next_obs, terminated: bool,
                    t_action: float, episode: int = 0) -> None:
        """Trial i took `action` at time t_action: store the transition and remember the step."""
        self.record_steps(np.array([i]), obs, np.array([action]), np.array([reward]), next_obs,
                          np.array([float(terminated)]), np.array([t_action]), np.array([episode]))

    def forget_history(self, i: int) -> None:
        """Drop trial i's held steps (e.g. the actor restarted: nothing before may be credited)."""
        self.history.clear(i)

    def give_feedback(self, events: list[tuple[int, float, int]]) -> list[FeedbackOutcome]:
        """One round of feedback, at most one event per trial: (trial, t_feedback, value +-1).

        Shaping trials add the value to the newest step's reward; H trials credit it by timestamp,
        grow D_global and update H on D_local at once (one batched update for the round).
        """
        seen = set()
        for i, _, value in events:
            if i in seen:
                raise ValueError(f"trial {i} has two feedbacks in one round")
            seen.add(i)
            if value not in (-1, 1):
                raise ValueError(f"feedback must be -1 or +1, got {value!r}")
        if not events:
            return []
        rows = np.array([e[0] for e in events], np.int64)
        status, steps, lost = self.feedback_round(rows, np.array([e[1] for e in events], np.float64),
                                                  np.array([e[2] for e in events], np.int64))
        return [FeedbackOutcome(STATUS_NAMES[s], int(n), float(m)) for s, n, m in zip(status, steps, lost)]

    def feedback_round(self, rows: np.ndarray, t_feedback: np.ndarray,
                       values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`give_feedback` on arrays (rows distinct, values +-1, not checked): (status, steps, lost mass)."""
        return self.feedback_rounds(rows, t_feedback, np.asarray(values)[:, None], np.ones(len(rows), np.int64))

    def feedback_rounds(self, rows: np.ndarray, t_feedback: np.ndarray, values: np.ndarray,
                        counts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Several rounds of feedback stamped at the same times: round r gives values[k, r] to trial
        rows[k] if counts[k] > r. The same as one `feedback_round` per round (nothing is recorded in
        between, so each trial's credit is the same in every round and is computed once); every round
        is still its own D_local update, in order. Returns (status, steps, lost mass) per trial, the
        same in each of its rounds."""
        n = len(rows)
        status = np.full(n, IGNORED, np.int64)
        steps = np.zeros(n, np.int64)
        lost = np.zeros(n, np.float64)
        shaping = self.shaping[rows]
        if shaping.any():
            k = nz(shaping)
            r = rows[k]
            pos = self.history.latest_at(r, t_feedback[k])
            hit = pos >= 0
            status[k] = np.where(hit, CREDITED, STALE)
            steps[k] = hit.astype(np.int64)
            lost[k] = np.where(hit, 0.0, 1.0)
            for rnd in range(values.shape[1]):
                g = hit & (counts[k] > rnd)
                self.replay.add_reward(r[g], self.history.slot[r[g], pos[g]], values[k[g], rnd].astype(np.float32))
        learn = self.train_h[rows] & ~shaping
        if learn.any():
            k = nz(learn)
            r = rows[k]
            credit = self.history.credit(r, t_feedback[k], self.assumed_delay, self.local_width)
            ok = credit.counts > 0
            status[k] = np.where(ok, CREDITED, STALE)
            steps[k] = credit.counts
            lost[k] = credit.lost
            if ok.any():
                k, r, pos, w, cnt = k[ok], r[ok], credit.positions[ok], credit.weights[ok], credit.counts[ok]
                obs = self.history.obs[r[:, None], pos]
                act = self.history.action[r[:, None], pos]
                w32 = w.astype(np.float32)
                for rnd in range(values.shape[1]):
                    g = nz(counts[k] > rnd)
                    if not len(g):
                        break
                    fb = np.repeat(values[k[g], rnd].astype(np.float32)[:, None], pos.shape[1], axis=1)
                    self.feedback_memory.add_many(r[g], cnt[g], obs=obs[g], action=act[g], feedback=fb, weight=w32[g])
                    self._h_step(r[g], obs[g], act[g], fb, w32[g], reduce="sum")
        return status, steps, lost

    def give_screen_feedback(self, i: int, t_feedback: float, value: int, step_times, starts, ends,
                             delay) -> tuple[FeedbackOutcome, np.ndarray]:
        """Feedback from a person who watched the steps on a screen (the console): the held steps recorded at
        `step_times` were on screen during [starts, ends) seconds, oldest first; credit them in seconds with
        `delay` (any distribution with a CDF), by the same credit function. Mass on steps no longer held is
        lost. Returns the outcome and the weight given to each listed step."""
        if value not in (-1, 1):
            raise ValueError(f"feedback must be -1 or +1, got {value!r}")
        step_times = np.asarray(step_times, np.float64)
        weights = np.zeros(len(step_times), np.float64)
        row = np.array([i], np.int64)
        pos, times = self.history._chronological(row)
        held = {float(t): int(p) for t, p in zip(times[0], pos[0]) if np.isfinite(t)}
        at = np.array([held.get(float(t), -1) for t in step_times], np.int64)
        if self.shaping[i]:  # naive shaping: the newest step shown at or before the feedback, if still held
            on = np.flatnonzero((np.asarray(starts) <= t_feedback) & (at >= 0))
            if not len(on):
                return FeedbackOutcome("stale", 0, 1.0), weights
            weights[on[-1]] = 1.0
            self.replay.add_reward(row, self.history.slot[row, at[on[-1:]]], np.array([value], np.float32))
            return FeedbackOutcome("credited", 1, 0.0), weights
        if not self.train_h[i]:
            return FeedbackOutcome("ignored"), weights
        if not len(step_times):
            return FeedbackOutcome("stale", 0, 1.0), weights
        episodes = np.where(at >= 0, self.history.episode[i, np.maximum(at, 0)], -1)
        w, _ = credit_weights(t_feedback, starts, delay, ends=ends, episodes=episodes)
        weights = np.where(at >= 0, w, 0.0)
        k = np.flatnonzero(weights > 0)
        lost = max(0.0, 1.0 - float(weights.sum()))
        if not len(k):
            return FeedbackOutcome("stale", 0, lost), weights
        p = at[k][None, :]
        obs, act = self.history.obs[row[:, None], p], self.history.action[row[:, None], p]
        w32 = weights[k][None, :].astype(np.float32)
        fb = np.full((1, len(k)), value, np.float32)
        self.feedback_memory.add_many(row, np.array([len(k)]), obs=obs, action=act, feedback=fb, weight=w32)
        self._h_step(row, obs, act, fb, w32, reduce="sum")
        return FeedbackOutcome("credited", int(len(k)), lost), weights

    # ---------------------------------------------------------------------------------- learning
    def update(self, active: np.ndarray | None = None) -> None:
        """Every b steps: a Q minibatch update and a D_global minibatch update (where they apply).

        Q and H are separate networks of the same shape; when few rows are due (the per-call overhead
        dominates) both minibatch steps run as one stacked computation over the Q rows and the H rows.
        Each row's arithmetic is its own either way, so this changes speed only."""
        active = np.ones(self.B, bool) if active is None else active
        c = self.base
        due = active & (self.steps > 0) & (self.steps % c.update_interval == 0)
        q_rows = nz(due & self.train_q & (self.replay.size >= max(c.replay_start, 1)))
        h_rows = nz(due & self.train_h & (self.feedback_memory.size > 0))
        if c.batch_size == c.h_batch_size and len(q_rows) + len(h_rows) <= MERGE_ROWS:
            if len(q_rows) or len(h_rows):
                self._minibatch_step(q_rows, h_rows)
        else:
            if len(q_rows):
                self._minibatch_step(q_rows, h_rows[:0])
            if len(h_rows):
                self._minibatch_step(q_rows[:0], h_rows)
        sync = nz(active & self.train_q & (self.steps % c.target_update_interval == 0) & (self.steps > 0))
        if len(sync):
            self.q_target_flat[sync] = self.q.flat[sync]

    def _minibatch_step(self, q_rows: np.ndarray, h_rows: np.ndarray) -> None:
        """Q: one Huber-loss TD step (mean over its minibatch) on trials `q_rows`; H: one weighted
        squared-error step (mean over its minibatch from D_global) on trials `h_rows`."""
        c, d = self.base, self.obs_dim
        nq, nh = len(q_rows), len(h_rows)
        xs, flats = [], []
        if nq:
            rq = self._rows_index(q_rows)
            idx = to_integers(self._q_u.get(q_rows, self.q_updates[q_rows]), self.replay.size[q_rows][:, None])
            bq = self.replay.gather_records(q_rows, idx)  # obs, action, reward, next_obs, terminated
            act_q = bq[:, :, d].astype(np.int64)[:, :, None]
            target_flat = self.q_target_flat if rq is None else self.q_target_flat[rq]
            q_next = row_max(mlp_forward(views(target_flat, self.q.shapes), bq[:, :, d + 2:2 * d + 2])[1])
            target = bq[:, :, d + 1] + np.float32(c.gamma) * (np.float32(1) - bq[:, :, 2 * d + 2]) * q_next
            xs.append(bq[:, :, :d])
            flats.append(self.q.flat if rq is None else self.q.flat[rq])
        if nh:
            rh = self._rows_index(h_rows)
            m = self.feedback_memory
            idx = to_integers(self._h_u.get(h_rows, self.h_updates[h_rows]), m.size[h_rows][:, None])
            bh = m.gather_records(h_rows, idx)  # obs, action, feedback, weight
            act_h = bh[:, :, d].astype(np.int64)[:, :, None]
            xs.append(bh[:, :, :d])
            flats.append(self.h.flat if rh is None else self.h.flat[rh])
        x = xs[0] if len(xs) == 1 else np.concatenate(xs)
        params = views(flats[0] if len(flats) == 1 else np.concatenate(flats), self.q.shapes)
        hidden, out = mlp_forward(params, x)
        d_out = np.empty_like(out)
        arange_a = np.arange(self.n_actions)
        if nq:
            q_sa = _pick(out[:nq], act_q)
            # d/dq_sa of mean Huber(q_sa - target): the error clipped to [-1, 1], over the batch size.
            d_q_sa = np.clip(q_sa - target, -1.0, 1.0) / np.float32(c.batch_size)
            d_out[:nq] = np.where(act_q == arange_a, d_q_sa[:, :, None], np.float32(0))
        if nh:
            h_sa = _pick(out[nq:], act_h)
            d_h_sa = np.float32(2) * bh[:, :, d + 2] * (h_sa - bh[:, :, d + 1]) / np.float32(c.h_batch_size)
            d_out[nq:] = np.where(act_h == arange_a, d_h_sa[:, :, None], np.float32(0))
        grad = mlp_backward(params, x, hidden, d_out)
        if nq:
            self.q_opt.step_rows(rq, grad[:nq])
            self.q_updates[q_rows] += 1
        if nh:
            self.h_opt.step_rows(rh, grad[nq:])
            self.h_updates[h_rows] += 1

    def _h_step(self, rows: np.ndarray, obs, act, fb, wts, reduce: str) -> None:
        """Weighted squared error w (H(s, a) - f)^2: summed over D_local, averaged over a minibatch."""
        r = self._rows_index(rows)
        x = np.asarray(obs, np.float32)
        a = np.asarray(act).astype(np.int64)[:, :, None]
        params = self.h.rows(r)
        hidden, h = mlp_forward(params, x)
        h_sa = _pick(h, a)
        d_h_sa = np.float32(2) * np.asarray(wts, np.float32) * (h_sa - np.asarray(fb, np.float32))
        if reduce == "mean":
            d_h_sa /= np.float32(x.shape[1])
        d_out = np.where(a == np.arange(self.n_actions), d_h_sa[:, :, None], np.float32(0))
        self.h_opt.step_rows(r, mlp_backward(params, x, hidden, d_out))
        self.h_updates[rows] += 1

    # -------------------------------------------------------------------------- batch bookkeeping
    def select(self, rows: np.ndarray) -> None:
        """Keep only trials `rows` (in that order): row k of the batch becomes what row rows[k] was.

        Used to drop finished trials; a kept trial continues exactly as it would have."""
        rows = np.asarray(rows, np.int64)
        self.q.select(rows)
        self.h.select(rows)
        self.q_target_flat = self.q_target_flat[rows]
        self.q_opt.select(rows)
        self.h_opt.select(rows)
        self.replay.select(rows)
        self.feedback_memory.select(rows)
        self.history.select(rows)
        for blocks in (self._explore_u, self._q_u, self._h_u):
            blocks.select(rows)
        for name in self._ROW_ARRAYS:
            setattr(self, name, getattr(self, name)[rows])
        self.configs = [self.configs[k] for k in rows]
        self.seeds = [self.seeds[k] for k in rows]
        self.epsilon = [self.epsilon[k] for k in rows]
        self.alpha = [self.alpha[k] for k in rows]

    def state_dict(self) -> dict:
        """Everything that changes while learning (configs and seeds are given at construction)."""
        return {
            "q": self.q.flat.copy(), "h": self.h.flat.copy(), "q_target": self.q_target_flat.copy(),
            "q_opt": self.q_opt.state_dict(), "h_opt": self.h_opt.state_dict(),
            "replay": self.replay.state_dict(), "feedback_memory": self.feedback_memory.state_dict(),
            "history": self.history.state_dict(),
            "steps": self.steps.copy(), "q_updates": self.q_updates.copy(), "h_updates": self.h_updates.copy(),
        }

    def load_state_dict(self, state: dict) -> None:
        self.q.flat[...] = state["q"]
        self.h.flat[...] = state["h"]
        self.q_target_flat[...] = state["q_target"]
        self.q_opt.load_state_dict(state["q_opt"])
        self.h_opt.load_state_dict(state["h_opt"])
        self.replay.load_state_dict(state["replay"])
        self.feedback_memory.load_state_dict(state["feedback_memory"])
        self.history.load_state_dict(state["history"])
        for name in ("steps", "q_updates", "h_updates"):
            getattr(self, name)[...] = state[name]

    # ------------------------------------------------------------------------------- weights I/O
    def policy_weights(self, i: int = 0) -> dict[str, torch.Tensor]:
        """What an actor needs to act for trial i: Q and H weights, as named tensors."""
        out = {f"q.{k}": v for k, v in self.q.trial_state(i).items()}
        out.update({f"h.{k}": v for k, v in self.h.trial_state(i).items()})
        return out

    def load_policy_weights(self, weights: dict[str, torch.Tensor], i: int = 0) -> None:
        self.q.load_trial_state(i, {k[2:]: v for k, v in weights.items() if k.startswith("q.")})
        self.h.load_trial_state(i, {k[2:]: v for k, v in weights.items() if k.startswith("h.")})

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
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from common.agents.config import AgentConfig
from common.agents.networks import StackedMLP
from common.agents.optim import MaskedRMSProp
from common.agents.replay import FeedbackMemory, TransitionReplay
from common.agents.schedules import AlphaSchedule, EpsilonSchedule
from common.credit import StepHistory
from common.delay import DelayModel
from common.seeding import derive_seed, stream

# Structural settings must agree across a batch; the rest may differ per trial.
SHARED_FIELDS = ("hidden", "lr", "rmsprop_alpha", "rmsprop_eps", "gamma", "batch_size", "replay_size",
                 "replay_start", "target_update_interval", "update_interval", "h_batch_size",
                 "feedback_memory_size", "assumed_delay_probs", "history_steps")


@dataclass
class FeedbackOutcome:
    """What became of one feedback: credited to `steps` held steps, stale (all mass lost), or ignored."""

    status: str  # "credited" | "stale" | "ignored"
    steps: int = 0
    lost_mass: float = 0.0


@dataclass
class _HeldStep:
    slot: int
    obs: np.ndarray
    action: int


class TrialBatchAgent:
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
        self.B = len(configs)
        self.obs_dim, self.n_actions = obs_dim, n_actions
        self.seeds = [int(s) for s in seeds]
        self.assumed_delay = DelayModel(base.assumed_delay_probs, step_unit)

        self.q = StackedMLP(obs_dim, base.hidden, n_actions, [derive_seed(s, "q-init") for s in seeds])
        self.h = StackedMLP(obs_dim, base.hidden, n_actions, [derive_seed(s, "h-init") for s in seeds])
        self.q_target = self.q.detached_copy()
        self.q_opt = MaskedRMSProp(self.q.params, base.lr, base.rmsprop_alpha, base.rmsprop_eps)
        self.h_opt = MaskedRMSProp(self.h.params, base.lr, base.rmsprop_alpha, base.rmsprop_eps)
        self.replay = TransitionReplay(self.B, base.replay_size, obs_dim)
        self.feedback_memory = FeedbackMemory(self.B, base.feedback_memory_size, obs_dim)
        self.history = [StepHistory(base.history_steps) for _ in range(self.B)]

        self.explore_rng = [stream(s, "explore") for s in seeds]
        self.q_rng = [stream(s, "q-replay") for s in seeds]
        self.h_rng = [stream(s, "h-replay") for s in seeds]
        self.epsilon = [EpsilonSchedule(c.epsilon_start, c.epsilon_decay, c.epsilon_floor) for c in configs]
        self.alpha = [AlphaSchedule(c.alpha_q, c.alpha_h, c.alpha_h_decay) for c in configs]
        self.train_q = np.array([c.train_q for c in configs])
        self.train_h = np.array([c.train_h for c in configs])
        self.shaping = np.array([c.reward_shaping for c in configs])
        self.uses_feedback = self.train_h | self.shaping
        self.steps = np.zeros(self.B, dtype=np.int64)  # steps taken so far, per trial
        self.q_updates = np.zeros(self.B, dtype=np.int64)
        self.h_updates = np.zeros(self.B, dtype=np.int64)
        self.local_width = len(base.assumed_delay_probs)  # at most one held step per assumed lag

    # ----------------------------------------------------------------------------------- acting
    def mixture_weights(self) -> tuple[torch.Tensor, torch.Tensor]:
        aq = torch.tensor([a.alpha_q for a in self.alpha], dtype=torch.float32).view(-1, 1, 1)
        ah = torch.tensor([a.alpha_h_at(int(t)) for a, t in zip(self.alpha, self.steps)],
                          dtype=torch.float32).view(-1, 1, 1)
        return aq, ah

    @torch.no_grad()
    def scores(self, obs: np.ndarray) -> torch.Tensor:
        """alpha_q Q + alpha_h H for one observation per trial: [B, n_actions]."""
        x = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32)).view(self.B, 1, self.obs_dim)
        aq, ah = self.mixture_weights()
        return (aq * self.q(x) + ah * self.h(x))[:, 0, :]

    @torch.no_grad()
    def greedy_action(self, i: int, obs: np.ndarray) -> int:
        """Trial i's greedy action for one observation, touching no random stream (for evaluation)."""
        x = torch.from_numpy(np.asarray(obs, dtype=np.float32)).view(1, 1, self.obs_dim)
        qp = {k: v[i:i + 1] for k, v in self.q.params.items()}
        hp = {k: v[i:i + 1] for k, v in self.h.params.items()}
        a = self.alpha[i]
        s = a.alpha_q * self.q(x, qp) + a.alpha_h_at(int(self.steps[i])) * self.h(x, hp)
        return int(s[0, 0].argmax())

    def act(self, obs: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
        """Epsilon-greedy actions for the active trials (-1 for the others)."""
        active = np.ones(self.B, bool) if active is None else active
        greedy = self.scores(obs).argmax(dim=1).numpy()
        actions = np.full(self.B, -1, dtype=np.int64)
        for i in np.flatnonzero(active):
            rng = self.explore_rng[i]
            if rng.random() < self.epsilon[i](int(self.steps[i])):
                actions[i] = int(rng.integers(self.n_actions))
            else:
                actions[i] = int(greedy[i])
        return actions

    # ---------------------------------------------------------------------------------- observing
    def record_step(self, i: int, obs, action: int, reward: float, next_obs, terminated: bool,
                    t_action: float) -> None:
        """Trial i took `action` at time t_action: store the transition and remember the step."""
        slot = self.replay.add(i, obs=obs, action=action, reward=reward, next_obs=next_obs,
                               terminated=float(terminated))
        self.history[i].push(t_action, _HeldStep(slot, np.asarray(obs, dtype=np.float32), int(action)))
        self.steps[i] += 1

    def forget_history(self, i: int) -> None:
        """Drop trial i's held steps (e.g. the actor restarted: nothing before may be credited)."""
        self.history[i].clear()

    def give_feedback(self, events: list[tuple[int, float, int]]) -> list[FeedbackOutcome]:
        """One round of feedback, at most one event per trial: (trial, t_feedback, value +-1).

        Shaping trials add the value to the newest step's reward; H trials credit it by timestamp,
        grow D_global and update H on D_local at once (one masked batched update for the round).
        """
        outcomes: list[FeedbackOutcome] = []
        L = self.local_width
        obs = np.zeros((self.B, L, self.obs_dim), np.float32)
        act = np.zeros((self.B, L), np.int64)
        wts = np.zeros((self.B, L), np.float32)
        fb = np.zeros((self.B, 1), np.float32)
        mask = np.zeros(self.B, bool)
        seen = set()
        for i, t_f, value in events:
            if i in seen:
                raise ValueError(f"trial {i} has two feedbacks in one round")
            seen.add(i)
            if value not in (-1, 1):
                raise ValueError(f"feedback must be -1 or +1, got {value!r}")
            if not self.uses_feedback[i]:
                outcomes.append(FeedbackOutcome("ignored"))
                continue
            if self.shaping[i]:
                held = self.history[i].latest_at(t_f)
                if held is None:
                    outcomes.append(FeedbackOutcome("stale", 0, 1.0))
                else:
                    self.replay.add_reward(i, held.slot, float(value))
                    outcomes.append(FeedbackOutcome("credited", 1, 0.0))
                continue
            result = self.history[i].credit(t_f, self.assumed_delay)
            if not result.credited:
                outcomes.append(FeedbackOutcome("stale", 0, result.lost_mass))
                continue
            for j, (held, w) in enumerate(result.entries):
                obs[i, j], act[i, j], wts[i, j] = held.obs, held.action, w
                self.feedback_memory.add(i, obs=held.obs, action=held.action, feedback=float(value), weight=w)
            fb[i, 0] = value
            mask[i] = True
            outcomes.append(FeedbackOutcome("credited", len(result.entries), result.lost_mass))
        if mask.any():
            self._h_step(obs, act, fb.repeat(L, axis=1), wts, mask, reduce="sum")
        return outcomes

    # ---------------------------------------------------------------------------------- learning
    def update(self, active: np.ndarray | None = None) -> None:
        """Every b steps: a Q minibatch update and a D_global minibatch update (where they apply)."""
        active = np.ones(self.B, bool) if active is None else active
        c = self.base
        due = active & (self.steps > 0) & (self.steps % c.update_interval == 0)
        q_mask = due & self.train_q & (self.replay.size >= max(c.replay_start, 1))
        if q_mask.any():
            self._q_step(q_mask)
        h_mask = due & self.train_h & (self.feedback_memory.size > 0)
        if h_mask.any():
            idx = self.feedback_memory.sample_indices(self.h_rng, h_mask, c.h_batch_size)
            g = self.feedback_memory.gather
            self._h_step(g("obs", idx), g("action", idx), g("feedback", idx), g("weight", idx), h_mask,
                         reduce="mean")
        sync = active & self.train_q & (self.steps % c.target_update_interval == 0) & (self.steps > 0)
        if sync.any():
            with torch.no_grad():
                m = torch.from_numpy(sync)
                for k, v in self.q.params.items():
                    mm = m.view(-1, *([1] * (v.dim() - 1)))
                    self.q_target[k].copy_(torch.where(mm, v, self.q_target[k]))

    def _q_step(self, mask: np.ndarray) -> None:
        c = self.base
        idx = self.replay.sample_indices(self.q_rng, mask, c.batch_size)
        g = self.replay.gather
        obs = torch.from_numpy(g("obs", idx))
        act = torch.from_numpy(g("action", idx))
        rew = torch.from_numpy(g("reward", idx))
        nxt = torch.from_numpy(g("next_obs", idx))
        term = torch.from_numpy(g("terminated", idx))
        with torch.no_grad():
            q_next = self.q(nxt, self.q_target).max(dim=2).values
            target = rew + c.gamma * (1.0 - term) * q_next
        q_sa = self.q(obs).gather(2, act.unsqueeze(2)).squeeze(2)
        loss = F.smooth_l1_loss(q_sa, target, reduction="none").mean(dim=1)
        self.q_opt.zero_grad()
        loss.sum().backward()
        self.q_opt.step(torch.from_numpy(mask))
        self.q_updates += mask

    def _h_step(self, obs, act, fb, wts, mask: np.ndarray, reduce: str) -> None:
        """Weighted squared error w (H(s, a) - f)^2: summed over D_local, averaged over a minibatch."""
        h_sa = self.h(torch.from_numpy(obs)).gather(2, torch.from_numpy(act).unsqueeze(2)).squeeze(2)
        err = torch.from_numpy(wts) * (h_sa - torch.from_numpy(fb)) ** 2
        loss = err.sum(dim=1) if reduce == "sum" else err.mean(dim=1)
        self.h_opt.zero_grad()
        loss.sum().backward()
        self.h_opt.step(torch.from_numpy(mask))
        self.h_updates += mask

    # ------------------------------------------------------------------------------- weights I/O
    def policy_weights(self, i: int = 0) -> dict[str, torch.Tensor]:
        """What an actor needs to act for trial i: Q and H weights, as named tensors."""
        out = {f"q.{k}": v for k, v in self.q.trial_state(i).items()}
        out.update({f"h.{k}": v for k, v in self.h.trial_state(i).items()})
        return out

    def load_policy_weights(self, weights: dict[str, torch.Tensor], i: int = 0) -> None:
        self.q.load_trial_state(i, {k[2:]: v for k, v in weights.items() if k.startswith("q.")})
        self.h.load_trial_state(i, {k[2:]: v for k, v in weights.items() if k.startswith("h.")})

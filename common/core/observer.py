"""The simulated human observer with the paper's five characteristics.

binary (a rule per environment: +1/-1), delay (true lag drawn from `delay_probs` in steps, or from
`delay_s`, a distribution in seconds on the runner's clock of `step_seconds` per step), stochasticity (a step
gets feedback with probability `p_feedback`), unsustainability (silent from episode `stop_episode` or
global step `stop_step` on), natural reaction (polarity flipped with probability `p_flip`).

It is deterministic for a seed and draws the same three numbers for every step, so two observers with the
same seed but different settings make the same underlying choices (common random numbers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from collections.abc import Callable, Mapping

import numpy as np

from common.config import option
from common.core.delay import DelayModel, delay_from_spec, parse_probs
from common.agents.explorer import RowConstants

# A reaction lands half a step after its lag: between two actions, never on one.
REACTION_OFFSET = 0.5
# A delay in seconds is cut here (the learned density's range: a later press has nothing left to refer to).
MAX_REACTION_S = 6.0


# A delay in seconds is drawn by its quantile function, tabulated here (scipy's ppf per draw costs milliseconds).
QUANTILE_GRID = np.linspace(0.0, 1.0, 4097)


def _quantiles(spec: str) -> np.ndarray:
    """The quantiles of a delay in seconds at QUANTILE_GRID (the ends cut to 0..MAX_REACTION_S)."""
    q = np.asarray(delay_from_spec(spec).ppf(QUANTILE_GRID), np.float64)
    return np.clip(np.nan_to_num(q, nan=0.0, posinf=MAX_REACTION_S, neginf=0.0), 0.0, MAX_REACTION_S)


@dataclass(frozen=True)
class ObserverConfig:
    """The simulated observer: how often, how late and how reliably it gives feedback."""

    p_feedback: float = option(0.5, "probability that a step gets any feedback (stochasticity)")
    delay_probs: tuple[float, ...] = option((0.3, 0.6, 0.1), "true lag distribution over 0, 1, 2, ... steps (delay)")
    p_flip: float = option(0.0, "probability that the polarity is flipped (natural reaction, a misread face)")
    stop_episode: int | None = option(
        None, "no feedback for steps of this episode (0-based) and later (unsustainability); none = never"
    )
    stop_step: int | None = option(None, "no feedback for this global step (0-based) and later; none = never")
    late_delay_probs: tuple[float, ...] = option(
        (),
        "if given, the lag distribution drifts: at episode e it is "
        "(1 - w) delay_probs + w late_delay_probs, "
        "w = min(1, e / drift_episodes)",
    )
    drift_episodes: int = option(1, "episodes over which a drifting lag distribution moves to late_delay_probs")
    delay_s: str = option(
        "",
        "if given, the delay in seconds instead of delay_probs: a distribution NAME:ARGS "
        "(common.core.delay, e.g. gamma:4,0,0.25), from the step's onset to the feedback",
    )
    late_delay_s: str = option(
        "",
        "if given with delay_s, the delay drifts: at episode e each reaction's quantile of "
        "delay_s and of this one are mixed (1 - w, w), w = min(1, e / drift_episodes)",
    )
    drift_steps: int = option(
        0, "if > 0, a delay in seconds drifts over this many steps instead (w = min(1, global step / drift_steps))"
    )

    def lag_cdf(self, episode: int) -> np.ndarray:
        """Cumulative lag distribution at `episode` over 0..max lag (drift included)."""
        n = max(len(self.delay_probs), len(self.late_delay_probs))
        start = np.zeros(n)
        start[: len(self.delay_probs)] = self.delay_probs
        if not self.late_delay_probs:
            return np.cumsum(start)
        late = np.zeros(n)
        late[: len(self.late_delay_probs)] = self.late_delay_probs
        w = min(1.0, episode / self.drift_episodes)
        return np.cumsum((1 - w) * start + w * late)

    def __post_init__(self):
        object.__setattr__(self, "delay_probs", parse_probs(self.delay_probs, "delay-probs"))
        late = parse_probs(self.late_delay_probs, "late-delay-probs") if len(self.late_delay_probs) else ()
        object.__setattr__(self, "late_delay_probs", late)
        for spec in (self.delay_s, self.late_delay_s):
            if spec:
                delay_from_spec(spec)  # a one-line ValueError if malformed
                if spec.strip().startswith("steps"):
                    raise ValueError(f"delay-s must be a distribution in seconds, got {spec!r}")
        if self.late_delay_s and not self.delay_s:
            raise ValueError("late-delay-s needs delay-s")
        if self.drift_steps < 0:
            raise ValueError(f"drift-steps must be >= 0, got {self.drift_steps}")
        if self.drift_episodes < 1:
            raise ValueError(f"drift-episodes must be >= 1, got {self.drift_episodes}")
        for name in ("p_feedback", "p_flip"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise ValueError(f"{name.replace('_', '-')} must be in [0, 1], got {value}")
        for name in ("stop_episode", "stop_step"):
            value = getattr(self, name)
            if value is not None and value < 0:
                raise ValueError(f"{name.replace('_', '-')} must be >= 0, got {value}")


@dataclass(frozen=True)
class FeedbackEvent:
    """One reaction: stamped with the time it happens (t_reaction), not the time of the step."""

    t_reaction: float
    value: int
    intended: int
    step_ref: int
    lag_steps: int


class ObserverBatch:
    """The simulated observer of many trials at once: the one implementation of the observer's rule.

    Each trial's observer draws three uniforms per step it watches (give, lag, flip) from its own
    generator; here they are drawn `block` steps at a time from that generator (numpy gives the same numbers
    either way, so a trial reacts the same alone, batched, or through `SimulatedObserver`), and the rule is
    applied to arrays: silent after the stop, feedback with probability p_feedback, the lag by inverse CDF
    over `delay_probs` (a running sum of `delay_probs`), polarity flipped with probability p_flip.
    """

    def __init__(self, configs: list[ObserverConfig], seeds: list[int], block: int = 1024):
        self.rngs = [np.random.default_rng(s) for s in seeds]
        self.block = block
        big = np.iinfo(np.int64).max
        self.p_feedback = np.array([c.p_feedback for c in configs], np.float64)
        self.p_flip = np.array([c.p_flip for c in configs], np.float64)
        self.stop_episode = np.array([big if c.stop_episode is None else c.stop_episode for c in configs], np.int64)
        self.stop_step = np.array([big if c.stop_step is None else c.stop_step for c in configs], np.int64)
        self.n_lags = np.array([max(len(c.delay_probs), len(c.late_delay_probs)) for c in configs], np.int64)
        self.max_lag = int(self.n_lags.max()) - 1
        # Lag CDFs at the start and at the end of a drift (the same when the observer does not drift).
        self.cum = np.zeros((len(configs), self.max_lag + 1), np.float64)
        self.cum_late = np.zeros_like(self.cum)
        for k, c in enumerate(configs):
            for target, cdf in ((self.cum, c.lag_cdf(0)), (self.cum_late, c.lag_cdf(c.drift_episodes))):
                target[k, : len(cdf)] = cdf
                target[k, len(cdf) :] = cdf[-1]
        self.drift_episodes = np.array([c.drift_episodes for c in configs], np.float64)
        # Delays in seconds (rows whose config has delay_s): distributions at the start and end of a drift.
        self.seconds = [
            (_quantiles(c.delay_s), _quantiles(c.late_delay_s or c.delay_s)) if c.delay_s else None for c in configs
        ]
        self.in_seconds = any(d is not None for d in self.seconds)
        self.drift_steps = np.array([c.drift_steps for c in configs], np.float64)
        self.drifts = bool(np.any(self.cum != self.cum_late))
        self.u = np.zeros((len(configs), block, 3), np.float64)
        self.watched = np.zeros(len(configs), np.int64)  # steps watched so far (draws used)
        self.drawn = np.zeros(len(configs), np.int64)  # steps' worth of uniforms drawn so far
        self._constants = RowConstants(self._pick_constants)

    def react(self, rows: np.ndarray, intended: np.ndarray, episode: np.ndarray, global_step: np.ndarray):
        """Trials `rows` (distinct) each watched one step whose rule says `intended`: (gives feedback, value,
        lag in steps)."""
        n = self.watched[rows]
        for k in rows[n >= self.drawn[rows]]:
            self.u[k] = self.rngs[k].random((self.block, 3))
            self.drawn[k] += self.block
        u = self.u[rows, n % self.block]
        self.watched[rows] = n + 1
        stop_episode, stop_step, p_feedback, cum, last_lag, p_flip, cum_late, drift_episodes = self._constants(rows)
        silent = (episode >= stop_episode) | (global_step >= stop_step)
        give = ~silent & (u[:, 0] < p_feedback)
        if self.drifts:
            w = np.minimum(1.0, episode / drift_episodes)[:, None]
            cum = (1 - w) * cum + w * cum_late
        lag = np.minimum((u[:, 1:2] >= cum).sum(axis=1), last_lag)
        value = np.where(u[:, 2] < p_flip, -intended, intended)
        self.last_delay_s = self._delays_s(rows, u[:, 1], episode, global_step) if self.in_seconds else None
        return give, value, lag

    def _delays_s(self, rows: np.ndarray, u: np.ndarray, episode: np.ndarray, step: np.ndarray) -> np.ndarray:
        """Each row's delay in seconds for the lag draw u (nan for rows counted in steps): the quantile u of its
        distribution, mixed between the start and end of a drift."""
        out = np.full(len(rows), np.nan)
        for j, r in enumerate(rows):
            if self.seconds[r] is None:
                continue
            early, late = self.seconds[r]
            w = min(1.0, step[j] / self.drift_steps[r] if self.drift_steps[r] else episode[j] / self.drift_episodes[r])
            d = (1 - w) * float(np.interp(u[j], QUANTILE_GRID, early)) + w * float(np.interp(u[j], QUANTILE_GRID, late))
            out[j] = min(max(d, 0.0), MAX_REACTION_S)
        return out

    def _pick_constants(self, rows: np.ndarray) -> tuple:
        return (
            self.stop_episode[rows],
            self.stop_step[rows],
            self.p_feedback[rows],
            self.cum[rows],
            self.n_lags[rows] - 1,
            self.p_flip[rows],
            self.cum_late[rows],
            self.drift_episodes[rows],
        )

    def select(self, rows: np.ndarray) -> None:
        """Keep only trials `rows` (in that order)."""
        for name in (
            "p_feedback",
            "p_flip",
            "stop_episode",
            "stop_step",
            "n_lags",
            "cum",
            "cum_late",
            "drift_episodes",
            "u",
            "watched",
            "drawn",
        ):
            setattr(self, name, getattr(self, name)[rows])
        self.rngs = [self.rngs[k] for k in rows]
        self.seconds = [self.seconds[k] for k in rows]
        self.drift_steps = self.drift_steps[rows]
        self._constants.clear()


class SimulatedObserver:
    """One observer watching steps one at a time (the live teachers): an `ObserverBatch` of one."""

    def __init__(
        self, config: ObserverConfig, rule: Callable[[Mapping[str, float]], int], seed: int, step_unit: float = 1.0
    ):
        self.config = config
        self.rule = rule
        self.delay = DelayModel(config.delay_probs, step_unit)
        self.step_unit = step_unit
        self._batch = ObserverBatch([config], [seed], block=64)  # (the same draws as one at a time, fewer calls)
        self._row = np.zeros(1, np.int64)
        self.emitted = 0
        self.flipped = 0

    def react(
        self, t_action: float, info: Mapping[str, float], episode: int, global_step: int, step_ref: int | None = None
    ) -> FeedbackEvent | None:
        """The observer watches the step whose action was taken at t_action; maybe reacts later."""
        intended = int(self.rule(info))
        give, value, lag = self._batch.react(
            self._row, np.array([intended]), np.array([episode]), np.array([global_step])
        )
        if not give[0]:
            return None
        value, lag = int(value[0]), int(lag[0])
        self.emitted += 1
        self.flipped += value != intended
        t_reaction = t_action + (lag + REACTION_OFFSET) * self.step_unit
        delays = self._batch.last_delay_s
        if delays is not None:  # a delay in seconds (t_action is on a clock of seconds)
            delay = float(delays[0])
            t_reaction, lag = t_action + delay, int(delay // self.step_unit)
        return FeedbackEvent(t_reaction, value, intended, global_step if step_ref is None else step_ref, lag)

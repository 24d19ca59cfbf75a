"""Credit assignment by timestamp (Deep TAMER's rule): the one function both runners and the console use.

Each step k was shown during an interval [start_k, end_k) on some clock (the runner's virtual step clock,
the live learner's step clock, or seconds on a person's screen). A feedback stamped t_f was caused by what
was shown at t_f - d, where d is the person's delay, distributed as the assumed delay D. Step k therefore
receives the probability mass of t_f - D that falls in its interval, integrated over it:

    w_k = P(start_k <= t_f - D < end_k) = P(t_f - end_k < D <= t_f - start_k).

D may be any distribution with a CDF: a scipy.stats frozen distribution (Deep TAMER's uniform 0.2-4 s,
`uniform(loc=0.2, scale=3.8)`, or a gamma fitted to reaction times) or the paper's step-counted model, a
`DelayModel` of point masses at 0, 1, 2, ... steps (on the step clock, where step k is [k, k+1), this is
exactly "lag i refers to step k - i"). Steps may last unequal times.

That is Deep TAMER's reading of a screen: the rated event may lie anywhere in the step's interval. A person who
rates a change (a move in a maze) reacts to the moment it appeared, so the cause of a feedback at t_f is the
onset of some step, t_f - D = start_k; `onset_weights` credits that: each step shown before t_f gets the density
of D at t_f - start_k, normalised over those steps (the posterior of "which step was rated" under a uniform
prior). On the step clock with point-mass lags the two readings coincide.

A feedback's candidates are the steps shown before it, whatever their episode: a reaction to the move that
reached the goal often lands after the reset, and it refers to that move (the terminal transition is
creditable). Nothing shown after the stamp gets credit. The mass that falls before the oldest step still held
or between intervals is lost (returned, so the caller can count it). Weights and lost mass sum to 1.
"""

from __future__ import annotations

from typing import Protocol, overload

import numpy as np

SCREEN_CREDIT = ("interval", "onset")
"""How a step's time on a person's screen enters credit: its whole interval (`credit_weights`) or its onset
(`onset_weights`)."""


class DelayDistribution(Protocol):
    """What credit needs of a delay distribution: its CDF P(D <= x), vectorised (scipy.stats has it)."""

    def cdf(self, x): ...


def interval_mass(delay, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """P(low < D <= high), elementwise. Uses the distribution's own `mass_between` where it has one
    (exact sums of point masses for `DelayModel`), else the difference of its CDF."""
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    if hasattr(delay, "mass_between"):
        return delay.mass_between(low, high)
    return np.clip(np.asarray(delay.cdf(high), np.float64) - np.asarray(delay.cdf(low), np.float64), 0.0, 1.0)


@overload
def credit_weights(t_feedback: float, starts, delay, ends=None) -> tuple[np.ndarray, float]: ...
@overload
def credit_weights(t_feedback: np.ndarray, starts, delay, ends=None) -> tuple[np.ndarray, np.ndarray]: ...
def credit_weights(t_feedback, starts, delay, ends=None) -> tuple[np.ndarray, np.ndarray | float]:
    """Weights of each held step for a feedback at `t_feedback`, and the mass lost.

    Batched over leading axes: t_feedback [...], starts [..., K] ascending along K (held steps, oldest first;
    +inf pads rows with fewer steps). `ends` defaults to the next step's start (the newest step is still
    shown: +inf). Returns (weights [..., K], lost [...]); a scalar t_feedback with 1-d starts gives a 1-d
    weights and a float lost.
    """
    t_f = np.asarray(t_feedback, np.float64)
    starts = np.asarray(starts, np.float64)
    if starts.shape[-1] == 0:
        return np.zeros(starts.shape), np.ones(t_f.shape) if t_f.ndim else 1.0
    if np.count_nonzero(starts[..., 1:] < starts[..., :-1]):  # (a C call: a quarter of np.any's cost)
        raise ValueError("step start times must be ascending")
    if ends is not None:
        ends = np.asarray(ends, np.float64)
        if np.count_nonzero(ends < starts):
            raise ValueError("a step cannot end before it starts")
    t = t_f[..., None]
    shown_before = starts <= t  # steps already on screen at t_f (a reaction cannot precede its cause)
    mass = _point_mass_on_steps(delay, t - starts) if ends is None else None
    if mass is None:
        if ends is None:
            ends = np.concatenate([starts[..., 1:], np.full(starts.shape[:-1] + (1,), np.inf)], axis=-1)
        mass = interval_mass(delay, t - ends, t - starts)
    weights = np.where(shown_before, mass, 0.0)
    lost = np.maximum(0.0, 1.0 - weights.sum(axis=-1))
    return weights, (float(lost) if lost.ndim == 0 else lost)


def _point_mass_on_steps(delay, since_start: np.ndarray) -> np.ndarray | None:
    """The fast path of `interval_mass` for steps that last until the next one starts (ends None) and a
    point-mass delay (`point_masses()`: lags [L], probs [..., L]; the step clock's `DelayModel`): the same
    numbers with a third of the array operations. None where it does not apply (the general path then).

    since_start = t_f - start_k [..., K]. The general path asks, of lag d and step k, t_f - end_k < d <=
    t_f - start_k, where t_f - end_k is t_f - start_(k+1), the same subtraction (-inf for the newest step): so
    "d <= t_f - start_k, and not d <= t_f - start_(k+1)" is the same test of the same numbers, and the masses
    are summed over the same [..., K, L] array in the same order (bit for bit; tests/core/test_credit.py)."""
    point_masses = getattr(delay, "point_masses", None)
    if point_masses is None:
        return None
    lags, probs = point_masses()
    if probs.ndim > 1 and probs.shape[:-1] != since_start.shape[:-1]:
        return None
    inside = lags <= since_start[..., None]  # [..., K, L]: the lag reaches back to step k's start
    inside[..., :-1, :] &= ~inside[..., 1:, :]  # ... but not to the next step's
    return np.where(inside, probs[..., None, :], 0.0).sum(axis=-1)


def onset_weights(t_feedback: float, starts, delay) -> tuple[np.ndarray, float]:
    """Weights of each held step (1-d `starts`, ascending) for a feedback at `t_feedback` from a person reacting
    to each step's onset, and the mass lost (all of it when no onset lies where the delay has density). `delay`
    needs a density (`pdf`: a scipy.stats distribution)."""
    pdf = getattr(delay, "pdf", None)
    if pdf is None:
        raise ValueError("onset credit needs a delay with a density (a distribution in seconds, not steps:...)")
    starts = np.asarray(starts, np.float64)
    if np.any(starts[1:] < starts[:-1]):
        raise ValueError("step start times must be ascending")
    shown_before = starts <= t_feedback
    density = np.where(shown_before, np.asarray(pdf(np.where(shown_before, t_feedback - starts, 0.0)), np.float64), 0.0)
    total = float(density.sum())
    if not total > 0:
        return np.zeros(len(starts)), 1.0
    weights = density / total
    return weights, max(0.0, 1.0 - float(weights.sum()))

"""The parts a claim is declared with (experiments/claims.py): effects as signed combinations of (condition, arm)
metrics, the tests over them, and the claims."""

from __future__ import annotations

from dataclasses import dataclass, field

AGENT_NAMES = {
    "dqn": "DQN",
    "dqn-rs": "DQN+RS",
    "deep-tamer": "Deep TAMER",
    "dqn-tamer": "DQN-TAMER",
    "dqn-tamer/adaptive": "DQN-TAMER (adaptive alpha_h)",
    "dqn-tamer/matched": "DQN-TAMER (fixed alpha_h matched on the adaptive mean)",
    "dqn-tamer/trusted": "DQN-TAMER (teacher's reliability)",
    "deep-tamer/uniform": "Deep TAMER (uniform lags)",
    "deep-tamer/true": "Deep TAMER (true lags)",
    "deep-tamer/learned": "Deep TAMER (learned lags)",
    "dqn-tamer/uniform": "DQN-TAMER (uniform lags)",
    "deep-tamer/uniform2": "Deep TAMER (the paper's uniform lags 0..2)",
    "dqn-tamer/uniform2": "DQN-TAMER (the paper's uniform lags 0..2)",
    "dqn-tamer/true": "DQN-TAMER (true lags)",
    "dqn-tamer/learned": "DQN-TAMER (learned lags)",
}
Term = tuple[float, str, str]  # (coefficient, condition, arm) of the metric


@dataclass(frozen=True)
class Effect:
    label: str
    terms: tuple[Term, ...]


def better(cond: str, good: str, other: str, cond_other: str | None = None) -> Effect:
    """`good` does better than `other` (fewer steps, more return): metric(other) - metric(good), the metric
    oriented so that lower is better."""
    co = cond_other or cond
    return Effect(
        f"{AGENT_NAMES.get(other, other)} ({co}) - {AGENT_NAMES.get(good, good)} ({cond})",
        ((1.0, co, other), (-1.0, cond, good)),
    )


def degradation_gap(low: str, high: str, robust: str, other: str) -> Effect:
    """`robust` loses less than `other` from `high` to `low`: [m(low,o)-m(high,o)] - [m(low,r)-m(high,r)]."""
    return Effect(
        f"loss {high}->{low}: {AGENT_NAMES[other]} - {AGENT_NAMES[robust]}",
        ((1.0, low, other), (-1.0, high, other), (-1.0, low, robust), (1.0, high, robust)),
    )


def averaged(label: str, effects: list[Effect]) -> Effect:
    n = len(effects)
    return Effect(label, tuple((c / n, cond, arm) for e in effects for c, cond, arm in e.terms))


@dataclass(frozen=True)
class Test:
    claim: str
    text: str
    effects: tuple[Effect, ...]
    """All must hold (intersection-union when more than one)."""
    layouts: str = "honest"
    """honest | misleading | pooled: the primary population (Taxi: all its trials under honest or pooled)."""
    window: str = "all"
    """all | after-stop | before-stop | last: which episodes the metric averages."""
    kind: str = "greater"
    """greater (H1: effect > 0) | noninferior (H1: effect > -margin)."""


@dataclass(frozen=True)
class Claim:
    cid: str
    family: str
    text: str
    primary: Test
    secondary: tuple[Test, ...] = field(default_factory=tuple)

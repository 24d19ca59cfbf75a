"""The claims and their tests, declared before the runs that decide them (commit order is the evidence).

Primary metric (robust, bounded): per trial, the mean over an episode window of ln(steps in the
episode) - the log of the geometric-mean episode length. A stuck 1000-step episode counts ln 1000 = 6.9
against ln 5 = 1.6 for the maze's optimum, so one stuck episode cannot dominate as its -10 return does.
Lower is better; every effect below is signed so that positive means "as the paper claims".

An effect is a linear combination of (condition, arm) metrics, paired by trial (same layout and seed);
per layout the trials' effects are averaged (the cluster), and:
  estimate  mean over trials; interval: 95% percentile bootstrap resampling whole layouts (stats.py)
  p-value   one-sided t-test over the layouts' means (scipy.stats.ttest_1samp, H1: effect > 0; for a
            `noninferior` test H1: effect > -MARGIN); a test of several effects that must all hold
            (intersection-union) reports the smallest effect and the largest p-value
  Holm      across the primary tests of one family (the paper's claims; ours beyond the paper)
Verdict of a claim, from its ONE primary test (secondary tests are shown, never deciding):
  reproduced      Holm-adjusted p < ALPHA
  not reproduced  the interval's upper end is below MARGIN (greater) or below -MARGIN (noninferior):
                  the effect is confidently smaller than the smallest effect that matters
  inconclusive    otherwise
  fragile         added when the reproduced / not-reproduced decision flips under another reasonable
                  rule: Wilcoxon instead of t, per-trial median instead of mean of ln steps, or mean
                  return instead of ln steps (same Holm factor)
MARGIN = ln 1.1: 10% fewer steps per episode (geometric mean) is the smallest effect we call real.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

ALPHA = 0.05
MARGIN = math.log(1.1)
AGENT_NAMES = {"dqn": "DQN", "dqn-rs": "DQN+RS", "deep-tamer": "Deep TAMER", "dqn-tamer": "DQN-TAMER",
               "dqn-tamer/adaptive": "DQN-TAMER (adaptive alpha_h)",
               "deep-tamer/uniform": "Deep TAMER (uniform lags)", "deep-tamer/true": "Deep TAMER (true lags)",
               "deep-tamer/learned": "Deep TAMER (learned lags)", "dqn-tamer/uniform": "DQN-TAMER (uniform lags)",
               "dqn-tamer/true": "DQN-TAMER (true lags)", "dqn-tamer/learned": "DQN-TAMER (learned lags)"}
Term = tuple[float, str, str]  # (coefficient, condition, arm) of the metric (ln steps: lower is better)


@dataclass(frozen=True)
class Effect:
    label: str
    terms: tuple[Term, ...]


def better(cond: str, good: str, other: str, cond_other: str | None = None) -> Effect:
    """`good` needs fewer steps than `other`: metric(other) - metric(good)."""
    co = cond_other or cond
    return Effect(f"{AGENT_NAMES.get(other, other)} ({co}) - {AGENT_NAMES.get(good, good)} ({cond})",
                  ((1.0, co, other), (-1.0, cond, good)))


def degradation_gap(low: str, high: str, robust: str, other: str) -> Effect:
    """`robust` loses less than `other` from `high` to `low`: [m(low,o)-m(high,o)] - [m(low,r)-m(high,r)]."""
    return Effect(f"loss {high}->{low}: {AGENT_NAMES[other]} - {AGENT_NAMES[robust]}",
                  ((1.0, low, other), (-1.0, high, other), (-1.0, low, robust), (1.0, high, robust)))


def averaged(label: str, effects: list[Effect]) -> Effect:
    n = len(effects)
    return Effect(label, tuple((c / n, cond, arm) for e in effects for c, cond, arm in e.terms))


@dataclass(frozen=True)
class Test:
    claim: str
    text: str
    effects: tuple[Effect, ...]
    """All must hold (intersection-union when more than one)."""
    layouts: str = "pooled"
    """pooled | honest | misleading: which layouts' trials enter."""
    window: str = "all"
    """all | after-stop | before-stop | last: which episodes the metric averages."""
    kind: str = "greater"
    """greater (H1: effect > 0) | noninferior (H1: effect > -MARGIN)."""


@dataclass(frozen=True)
class Claim:
    cid: str
    family: str
    text: str
    primary: Test
    secondary: tuple[Test, ...] = field(default_factory=tuple)


def _paper_claims() -> list[Claim]:
    hnd, hd, lnd, ld = "maze-high-nodelay", "maze-high-delay", "maze-low-nodelay", "maze-low-delay"
    fb = ("dqn-rs", "deep-tamer", "dqn-tamer")
    out = [
        Claim("C1", "paper", "Without delay, DQN+RS learns faster than DQN (Maze).",
              Test("C1", "high frequency, no delay: DQN+RS needs fewer steps than DQN",
                   (better(hnd, "dqn-rs", "dqn"),)),
              (Test("C1", "low frequency, no delay: DQN+RS fewer steps than DQN", (better(lnd, "dqn-rs", "dqn"),)),)),
        Claim("C2", "paper", "With delay, DQN+RS degrades and falls back to about DQN.",
              Test("C2", "high frequency: DQN+RS needs more steps with delay than without",
                   (better(hnd, "dqn-rs", "dqn-rs", hd),)),
              (Test("C2", "low frequency: DQN+RS needs more steps with delay than without",
                    (better(lnd, "dqn-rs", "dqn-rs", ld),)),
               Test("C2", "high frequency, with delay: DQN+RS not worse than DQN by more than the margin",
                    (better(hd, "dqn-rs", "dqn"),), kind="noninferior"))),
        Claim("C3", "paper", "More frequent feedback speeds every feedback-using method up.",
              Test("C3", "with delay: each of DQN+RS, Deep TAMER, DQN-TAMER needs fewer steps at p=0.5 than at p=0.1",
                   tuple(better(hd, a, a, ld) for a in fb)),
              (Test("C3", "no delay: each feedback method fewer steps at p=0.5 than at p=0.1",
                    tuple(better(hnd, a, a, lnd) for a in fb)),)),
        Claim("C4", "paper", "At low feedback frequency Deep TAMER is particularly poor; DQN-TAMER is the most robust.",
              Test("C4", "with delay: DQN-TAMER loses fewer steps than DQN+RS and than Deep TAMER from p=0.5 to p=0.1",
                   (degradation_gap(ld, hd, "dqn-tamer", "dqn-rs"),
                    degradation_gap(ld, hd, "dqn-tamer", "deep-tamer"))),
              (Test("C4", "p=0.1 with delay: Deep TAMER needs more steps than each other agent",
                    tuple(better(ld, a, "deep-tamer") for a in ("dqn", "dqn-rs", "dqn-tamer"))),
               Test("C4", "p=0.1 with delay: DQN-TAMER needs fewer steps than each other agent",
                    tuple(better(ld, "dqn-tamer", a) for a in ("dqn", "dqn-rs", "deep-tamer"))),
               Test("C4", "p=0.1 no delay: DQN-TAMER fewer steps than each other agent",
                    tuple(better(lnd, "dqn-tamer", a) for a in ("dqn", "dqn-rs", "deep-tamer"))))),
    ]
    stop_tests = []
    for cond, label in (("pomdp-stop", "Maze POMDP"), ("taxi-fixed-stop", "Taxi, fixed task"), ("taxi-stop", "Taxi")):
        stop_tests.append(Test("C5", f"{label}, after the stop: DQN-TAMER fewer steps than each other agent",
                               tuple(better(cond, "dqn-tamer", a) for a in ("dqn", "dqn-rs", "deep-tamer")),
                               window="after-stop"))
    stop_tests.append(Test("C5", "Maze MDP: Deep TAMER stagnates: its steps after the stop not below those before "
                           "by more than the margin", (Effect("Deep TAMER after - before the stop",
                                                              ((1.0, "maze-stop", "deep-tamer@after"),
                                                               (-1.0, "maze-stop", "deep-tamer@before"))),),
                           kind="noninferior"))
    out.append(Claim("C5", "paper", "When feedback stops after 30 episodes, DQN-TAMER beats all others (Maze MDP, "
                     "Maze POMDP, Taxi); Deep TAMER stagnates.",
                     Test("C5", "Maze MDP, after the stop: DQN-TAMER needs fewer steps than each other agent",
                          tuple(better("maze-stop", "dqn-tamer", a) for a in ("dqn", "dqn-rs", "deep-tamer")),
                          window="after-stop"), tuple(stop_tests)))
    out.append(Claim("C6", "paper", "With about 15% misread (flipped) feedback, DQN-TAMER still learns.",
                     Test("C6", "15% flips: DQN-TAMER needs fewer steps than DQN (misread feedback still helps)",
                          (better("maze-flip", "dqn-tamer", "dqn"),)),
                     (Test("C6", "15% flips: DQN-TAMER's last 10 episodes shorter than its first 10",
                           (Effect("first 10 - last 10", ((1.0, "maze-flip", "dqn-tamer@first"),
                                                          (-1.0, "maze-flip", "dqn-tamer@last"))),)),)))
    return out


def _beyond_claims() -> list[Claim]:
    from experiments.conditions import DELAY_CONDITIONS as D

    def pooled(algo: str, good: str, other: str) -> Effect:
        return averaged(f"{other} - {good} ({algo}), mean over the 4 observers",
                        [better(c, f"{algo}/{good}", f"{algo}/{other}") for c in D])

    def per_observer(algo: str, good: str, other: str, kind: str = "greater") -> tuple[Test, ...]:
        return tuple(Test("", f"{c}: {AGENT_NAMES[f'{algo}/{good}']} vs {AGENT_NAMES[f'{algo}/{other}']}",
                          (better(c, f"{algo}/{good}", f"{algo}/{other}"),), "honest", kind=kind) for c in D)

    return [
        Claim("D1", "beyond", "Deep TAMER with the delay distribution learned online needs fewer steps than with "
              "lags assumed uniform (honest layouts, 4 observers).",
              Test("D1", "Deep TAMER: learned minus uniform lags, averaged over the 4 observers",
                   (pooled("deep-tamer", "learned", "uniform"),), "honest"),
              per_observer("deep-tamer", "learned", "uniform")),
        Claim("D2", "beyond", "DQN-TAMER with the delay learned online needs fewer steps than with uniform lags.",
              Test("D2", "DQN-TAMER: learned minus uniform lags, averaged over the 4 observers",
                   (pooled("dqn-tamer", "learned", "uniform"),), "honest"),
              per_observer("dqn-tamer", "learned", "uniform")),
        Claim("D3", "beyond", "Learning the delay online is not worse than knowing the true distribution "
              "(Deep TAMER; by more than the margin).",
              Test("D3", "Deep TAMER: learned vs true lags, averaged over the 4 observers (non-inferiority)",
                   (pooled("deep-tamer", "learned", "true"),), "honest", kind="noninferior"),
              per_observer("deep-tamer", "learned", "true", "noninferior")
              + per_observer("dqn-tamer", "learned", "true", "noninferior")
              + per_observer("deep-tamer", "true", "uniform")),
        Claim("A1", "beyond", "An alpha_h that follows H/Q agreement rescues DQN-TAMER from the misleading observer.",
              Test("A1", "misleading layouts, high frequency with delay: adaptive alpha_h needs fewer steps than "
                   "the paper's schedule", (better("maze-high-delay", "dqn-tamer/adaptive", "dqn-tamer"),),
                   "misleading"),
              (Test("A1", "honest layouts: adaptive alpha_h not worse than the paper's schedule",
                    (better("maze-high-delay", "dqn-tamer/adaptive", "dqn-tamer"),), "honest", kind="noninferior"),)),
    ]


CLAIMS: tuple[Claim, ...] = tuple(_paper_claims() + _beyond_claims())
FAMILIES = ("paper", "beyond")

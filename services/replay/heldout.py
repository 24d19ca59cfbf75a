"""`replay LOG retrain --screen-delay S [--screen-delay S2 ...] [--screen-credit onset|interval ...]`: which
credit setting predicts a person's presses best, scored on presses it was not fitted on.

Every console press in the log (a Feedback that lists the steps its person's screen showed, `shown`) is a
candidate set: the steps shown before it, each from its appearance to the next one's (the newest until the
press). A credit setting is a delay model (`common.core.delay_model.delay_estimate`: `learned`, `learned:PRIOR`,
`uniform:0.2,4`, any `NAME:ARGS`) and a reading of a step's time (its onset, or its whole interval). Under a
setting, the press at t with value v has the density

    p(t, v) = (1 - e) * mean_k g_k(t) P(v | step k rated) + e * 1/6 * 1/2

  g_k(t)          the delay's density at t - onset_k (onset), or averaged over step k's interval (interval)
  P(v | k rated)  the task's teacher rule (`common.envs.rules`, read from the recorded Step's info) agreed with
                  with probability `reliability` (0.9; 1/2 where the rule cannot tell)
  e               0.01: a press that is about no step (any time in 0-6 s, either value), so that no setting
                  scores minus infinity on one stray press

Each teacher's presses are split in time: the first `fit_share` (70%) fit the setting (a learned delay observes
them in order; a fixed one learns nothing), the rest are scored: their mean log-density in nats per press (higher
predicts better). With `folds` K, forward chaining in time: the presses are cut into K blocks, and block k is
scored by a setting fitted on the blocks before it (k = 1 .. K-1), so all but the first block are scored. Every
setting sees the same candidates and the same presses, so the numbers compare.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import os

import numpy as np

from common.core.delay_model import LearnedDelay, delay_estimate, polarity_likelihood
from common.envs.rules import auto_rule
from common.logs.mcap_log import read_log
from common.protocol import Feedback, Step

STRAY = 0.01  # share of presses about no step (the mixture's floor)
SPAN_S = 6.0  # the delay models' support (s)


@dataclasses.dataclass(frozen=True)
class Press:
    t: float
    value: int
    starts: np.ndarray  # the candidates' appearance times (s), oldest first
    ends: np.ndarray
    polarity: np.ndarray  # the task rule's +1/-1 per candidate (0: unknown)


def presses_from_log(path: str | os.PathLike) -> dict[str, list[Press]]:
    """Each teacher's screen presses (Feedback with `shown`), in the order of their press times."""
    steps, feedback = {}, []
    for rec in read_log(path):
        m = rec.message
        if isinstance(m, Step):
            steps[(m.incarnation, m.seq)] = m
        elif isinstance(m, Feedback) and m.shown and m.actor is not None:
            feedback.append(m)
    out: dict[str, list[Press]] = {}
    for fb in sorted(feedback, key=lambda f: (f.teacher_id, f.t_reaction, f.seq)):
        shown = [s for s in fb.shown or () if s.t <= fb.t_reaction]
        if not shown:
            continue
        starts = np.array([s.t for s in shown], np.float64)
        ends = np.append(starts[1:], fb.t_reaction)
        polarity = np.array([_polarity(steps.get((fb.actor or "", s.seq))) for s in shown], np.float64)
        out.setdefault(fb.teacher_id, []).append(Press(float(fb.t_reaction), int(fb.value), starts, ends, polarity))
    return out


def _polarity(step: Step | None) -> int:
    if step is None:
        return 0
    try:
        return auto_rule(dict(step.info or {}, reward=step.reward))
    except (KeyError, TypeError, ValueError):
        return 0


def _binned(model, reference: str) -> LearnedDelay:
    """The model's density over 0-6 s as a frozen `LearnedDelay` (its bin matrix reads either setting alike)."""
    if isinstance(model, LearnedDelay):
        return model
    _, probs = model.density()
    return LearnedDelay.from_state({"kind": "learned", "config": {"reference": reference}, "probs": probs.tolist()})


def log_density(binned: LearnedDelay, press: Press, reference: str, reliability: float = 0.9) -> float:
    """log p(t, v) of one press under a setting (its density as `_binned` gives it; the module docstring), nats."""
    mass = binned.bin_matrix(press.t, press.starts, press.ends) @ binned.probs
    width = binned.config.bin_s if reference == "onset" else np.maximum(press.ends - press.starts, 1e-9)
    g = mass / width
    agree = polarity_likelihood(press.value, press.polarity, reliability)
    p = (1.0 - STRAY) * float(np.mean(g * agree)) + STRAY / SPAN_S / 2.0
    return math.log(p)


@dataclasses.dataclass
class SettingScore:
    delay: str
    credit: str
    fitted: int
    scored: int
    mean_loglik: float  # nats per scored press
    estimate: dict  # teacher -> the fitted model's summary (median_s, p10_s, p90_s, feedbacks)


def _splits(n: int, fit_share: float, folds: int) -> list[tuple[int, int]]:
    """(presses fitted, end of those scored) per split: one cut at `fit_share`, or forward chaining over `folds`
    blocks in time order (fit on the blocks before block k, score block k, for k = 1 .. folds - 1)."""
    if folds < 2:
        return [(int(round(fit_share * n)), n)]
    cuts = [int(round(k * n / folds)) for k in range(folds + 1)]
    return [(cuts[k], cuts[k + 1]) for k in range(1, folds)]


def score_setting(
    presses: dict[str, list[Press]],
    delay: str,
    credit: str,
    fit_share: float = 0.7,
    reliability: float = 0.9,
    folds: int = 0,
) -> SettingScore:
    fitted = scored = 0
    total, estimate = 0.0, {}
    for teacher, mine in presses.items():
        for cut, end in _splits(len(mine), fit_share, folds):
            model = delay_estimate(delay, reference=credit)
            for p in mine[:cut]:
                model.observe(p.t, p.starts, p.ends, polarity_likelihood(p.value, p.polarity, reliability))
            binned = _binned(model, credit)
            total += sum(log_density(binned, p, credit, reliability) for p in mine[cut:end])
            fitted, scored = fitted + cut, scored + end - cut
            estimate[teacher] = model.summary()  # (the last split's: fitted on the most)
    return SettingScore(delay, credit, fitted, scored, total / scored if scored else float("nan"), estimate)


def compare_settings(
    path: str | os.PathLike,
    delays: list[str],
    credits: list[str],
    fit_share: float = 0.7,
    teacher: str | None = None,
    folds: int = 0,
) -> list[SettingScore]:
    """Every (delay, credit) setting scored on the log's held-out presses, best first."""
    if not 0 < fit_share < 1 or folds < 0 or folds == 1:
        raise ValueError(f"fit share must be in (0, 1) and folds 0 or >= 2, got {fit_share}, {folds}")
    presses = presses_from_log(path)
    if teacher is not None:
        presses = {teacher: presses.get(teacher, [])}
    if not any(len(p) >= 2 for p in presses.values()):
        raise ValueError(f"{path}: fewer than 2 console presses (Feedback listing the steps shown) to fit and score")
    scores = [score_setting(presses, d, c, fit_share, folds=folds) for d, c in itertools.product(delays, credits)]
    return sorted(scores, key=lambda s: -s.mean_loglik if math.isfinite(s.mean_loglik) else math.inf)


def format_scores(scores: list[SettingScore]) -> str:
    best = scores[0].mean_loglik
    lines = [
        f"held-out presses: scored on {scores[0].scored}, each by a fit on presses before it in time "
        f"({scores[0].fitted} fitted in all)",
        f"{'delay':<24} {'credit':<9} {'nats/press':>10} {'vs best':>8}   estimate after fitting (median, p10-p90 s)",
    ]
    for s in scores:
        est = "; ".join(f"{t}: {e['median_s']:.2f} ({e['p10_s']:.2f}-{e['p90_s']:.2f})" for t, e in s.estimate.items())
        lines.append(f"{s.delay:<24} {s.credit:<9} {s.mean_loglik:10.4f} {s.mean_loglik - best:+8.4f}   {est}")
    return "\n".join(lines)

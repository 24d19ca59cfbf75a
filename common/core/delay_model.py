"""A teacher's reaction delay in seconds, learned online: the credit of each feedback is its own posterior.

A person presses a key some delay D after the moment they react to. `LearnedDelay` keeps a discretised
density of D over 0..`max_s` seconds (`bin_s` bins; piecewise uniform inside a bin) whose prior is Deep
TAMER's uniform 0.2-4 s (only a prior: the data move it anywhere in 0-6 s). For one feedback stamped t_f and
the candidate steps shown during [start_k, end_k) on the same clock (seconds), it gives:

  weights   the feedback's posterior over the candidates: w_k proportional to the mass the density puts
            on step k (its onset, t_f - start_k, for `reference` "onset"; its whole interval for "interval",
            Deep TAMER's reading), times an optional likelihood of the feedback under step k; normalised over
            the candidates. Nothing shown after t_f is a candidate (weight 0).
  observe   one EM row: the likelihood of each delay bin given the feedback and a model of the rated event
            (P(value | step k was rated), e.g. the task's teacher rule's polarity of each candidate step:
            `polarity_likelihood`). The caller gives that model, never H trained with this very credit, so
            the estimate cannot confirm itself. Each observation then refits the density by a few EM
            steps over the last `window` rows, row i weighted `forget`^age (drift: the estimate follows a
            person who slows down), plus `prior_weight` pseudo-feedbacks of the prior, smoothed by a
            [1/4, 1/2, 1/4] kernel per step (EMS). A row that cannot tell delays apart (every candidate
            equally likely) leaves the density where it is, so an empty model of the event keeps the prior.

`FixedDelay` wraps a fixed distribution (`common.core.delay.delay_from_spec`) behind the same interface: its
weights are the credit function's (`common.core.credit`), unnormalised (mass on steps not held is lost),
and it learns nothing. `delay_estimate(spec)` builds either from the command line's text: ``learned``,
``learned:PRIOR`` (``learned:gamma:2,0,0.4``), or a fixed spec (``uniform:0.2,4``, ``steps:...``, ``NAME:...``).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from common.core.credit import credit_weights, onset_weights
from common.core.delay import check_delay_spec, delay_from_spec

LEARNED = "learned"
DEFAULT_PRIOR = "uniform:0.2,4"
REFERENCES = ("onset", "interval")
SMOOTHING = np.array([0.25, 0.5, 0.25])


@dataclass(frozen=True)
class LearnedDelayConfig:
    """How a teacher's delay density is learned (defaults suit a person at a few steps per second)."""

    prior: str = DEFAULT_PRIOR
    max_s: float = 6.0
    bin_s: float = 0.1
    prior_weight: float = 2.0
    """Pseudo-feedbacks of the prior (it weighs as much as this many feedbacks)."""
    forget: float = 0.97
    """Weight of a row per later feedback: about 1 / (1 - forget) = 33 feedbacks remembered (drift)."""
    window: int = 150
    """Rows kept (older ones weigh forget^window, under 1%)."""
    iterations: int = 3
    """EM steps after each feedback, from the current estimate."""
    floor: float = 0.02
    """Share of the prior spread over all of 0..max_s, so that the data can revive any delay."""
    reference: str = "onset"
    """What a candidate step's time means: its onset (a person reacts to a move appearing) or its interval."""

    def __post_init__(self):
        check_delay_spec(self.prior)
        if not (0 < self.bin_s < self.max_s and math.isfinite(self.max_s)):
            raise ValueError(f"need 0 < bin_s < max_s, got {self.bin_s}, {self.max_s}")
        if not (0 < self.forget <= 1 and self.prior_weight > 0 and 0 <= self.floor < 1):
            raise ValueError("need 0 < forget <= 1, prior_weight > 0 and 0 <= floor < 1")
        if self.window < 1 or self.iterations < 1:
            raise ValueError("window and iterations must be >= 1")
        if self.reference not in REFERENCES:
            raise ValueError(f"reference must be one of {REFERENCES}, got {self.reference!r}")


def polarity_likelihood(value: int, polarities, reliability: float = 0.9) -> np.ndarray:
    """P(value | step k was rated) for a teacher who agrees with a rule's polarity (+1/-1; 0 = unknown: 1/2)
    of each candidate step with probability `reliability`."""
    pol = np.asarray(polarities, np.float64) * float(value)
    return np.where(pol > 0, reliability, np.where(pol < 0, 1.0 - reliability, 0.5))


class LearnedDelay:
    """One teacher's delay density over 0..max_s seconds, learned online (see the module docstring)."""

    def __init__(self, config: LearnedDelayConfig = LearnedDelayConfig()):
        self.config = c = config
        self.edges = np.linspace(0.0, c.max_s, int(round(c.max_s / c.bin_s)) + 1)
        n = len(self.edges) - 1
        prior = delay_from_spec(c.prior)
        mass = np.diff(np.clip(np.asarray(prior.cdf(self.edges), np.float64), 0.0, 1.0))
        mass = mass / mass.sum() if mass.sum() > 0 else np.full(n, 1.0 / n)
        self.prior = (1.0 - c.floor) * mass + c.floor / n
        self.probs = self.prior.copy()
        self.rows = np.zeros((c.window, n), np.float64)  # likelihood of each bin, per observed feedback
        self.seen = np.zeros(c.window, np.int64)  # the feedback count at which each row was observed
        self.feedbacks = 0  # feedbacks observed (informative or not)

    # -- credit ------------------------------------------------------------------------------------------------
    def bin_matrix(self, t_feedback: float, starts, ends=None) -> np.ndarray:
        """[K, bins]: how candidate step k (shown [start_k, end_k), ending at the next start by default) lies
        over the delay bins, as seen from a feedback at t_feedback: onset, a 1 in the bin of t_f - start_k;
        interval, the share of each bin inside (t_f - end_k, t_f - start_k]. Steps shown after t_f: zeros."""
        starts = np.asarray(starts, np.float64)
        if ends is None:
            ends = np.append(starts[1:], np.inf)
        ends = np.asarray(ends, np.float64)
        late = t_feedback - starts  # the largest delay that reaches step k
        if self.config.reference == "onset":
            out = np.zeros((len(starts), len(self.edges) - 1))
            b = np.searchsorted(self.edges, late, side="right") - 1
            ok = (late >= 0) & (b < out.shape[1])
            out[np.flatnonzero(ok), b[ok]] = 1.0
            return out
        early = np.maximum(t_feedback - ends, 0.0)
        lo, hi = self.edges[:-1][None, :], self.edges[1:][None, :]
        overlap = np.clip(np.minimum(hi, late[:, None]) - np.maximum(lo, early[:, None]), 0.0, None)
        return np.where((late >= 0)[:, None], overlap / self.config.bin_s, 0.0)

    def weights(self, t_feedback: float, starts, ends=None, likelihood=None) -> np.ndarray:
        """The feedback's posterior over the candidate steps (1-d `starts`, `ends`; seconds, the clock of
        t_feedback): sums to 1, or all zeros when the density puts no mass on any of them. `likelihood`
        (optional, [K]) is P(value | step k rated) under a model of the rated event."""
        w = self.bin_matrix(t_feedback, starts, ends) @ self.probs
        if likelihood is not None:
            w = w * np.asarray(likelihood, np.float64)
        total = w.sum()
        return w / total if total > 0 else np.zeros(len(w))

    # -- learning ----------------------------------------------------------------------------------------------
    def observe(self, t_feedback: float, starts, ends=None, likelihood=None) -> bool:
        """Learn from one feedback: `likelihood[k]` = P(its value | candidate k was rated) under a model of the
        rated event that was not fitted with this credit (None: uninformative). False when no candidate lies
        in 0..max_s (nothing learned)."""
        m = self.bin_matrix(t_feedback, starts, ends)
        like = np.ones(len(m)) if likelihood is None else np.asarray(likelihood, np.float64)
        row = like @ m  # P(feedback | delay in bin b), up to a constant
        self.feedbacks += 1
        if not row.any():
            return False
        at = self.feedbacks % self.config.window
        self.rows[at] = row / row.max()
        self.seen[at] = self.feedbacks
        self._refit()
        return True

    def _refit(self) -> None:
        c = self.config
        held = self.seen > 0
        rows = self.rows[held]
        age = self.feedbacks - self.seen[held]
        weight = c.forget ** age.astype(np.float64)
        p = self.probs
        for _ in range(c.iterations):
            post = rows * p
            post /= post.sum(axis=1, keepdims=True)
            p = weight @ post + c.prior_weight * self.prior
            p = np.convolve(np.pad(p, 1, mode="edge"), SMOOTHING, mode="valid")
            p /= p.sum()
        self.probs = p

    # -- reading -----------------------------------------------------------------------------------------------
    def quantile(self, q: float) -> float:
        """The delay (s) below which a share q of the density lies (piecewise uniform within bins)."""
        cdf = np.concatenate([[0.0], np.cumsum(self.probs)])
        return float(np.interp(q * cdf[-1], cdf, self.edges))

    def summary(self) -> dict:
        """{"median_s", "p10_s", "p90_s", "feedbacks"}: the block `summary.json` writes per teacher."""
        return {"median_s": round(self.quantile(0.5), 4), "p10_s": round(self.quantile(0.1), 4),
                "p90_s": round(self.quantile(0.9), 4), "feedbacks": int(self.feedbacks)}

    def density(self) -> tuple[np.ndarray, np.ndarray]:
        """(bin edges in seconds [bins + 1], probability of each bin [bins])."""
        return self.edges.copy(), self.probs.copy()

    def state(self, window: bool = True) -> dict:
        """Plain JSON. With `window` (a checkpoint: `from_state` continues bit for bit) the rows are kept;
        without (a person's profile: a small file) only the estimate, which a new session starts from."""
        out = {"kind": LEARNED, "config": asdict(self.config), "probs": self.probs.tolist(),
               "feedbacks": self.feedbacks}
        if window:
            held = np.flatnonzero(self.seen > 0)
            out["rows"] = {"at": held.tolist(), "seen": self.seen[held].tolist(), "like": self.rows[held].tolist()}
        return out

    @classmethod
    def from_state(cls, state: dict) -> "LearnedDelay":
        """The model `state()` described (a profile without rows continues from its estimate)."""
        model = cls(LearnedDelayConfig(**state.get("config", {})))
        probs = np.asarray(state["probs"], np.float64)
        if probs.shape != model.probs.shape or not np.all(np.isfinite(probs)) or probs.min() < 0 or probs.sum() <= 0:
            raise ValueError("delay state: probs do not match the config's bins")
        model.probs = probs / probs.sum()
        model.feedbacks = int(state.get("feedbacks", 0))
        rows = state.get("rows")
        if rows:
            at = np.asarray(rows["at"], np.int64)
            model.rows[at] = np.asarray(rows["like"], np.float64)
            model.seen[at] = np.asarray(rows["seen"], np.int64)
        else:  # a returning person: their last estimate becomes the prior
            model.prior = (1.0 - model.config.floor) * model.probs + model.config.floor / len(model.probs)
            model.probs = model.prior.copy()
        return model


class FixedDelay:
    """A delay that is not learned (a fixed distribution from `delay_from_spec`), with `LearnedDelay`'s
    interface: weights are `common.core.credit`'s (not normalised: mass on steps not held is lost)."""

    def __init__(self, spec: str, reference: str = "interval"):
        self.spec, self.reference = spec, reference
        self.distribution = delay_from_spec(spec)
        self.feedbacks = 0

    def weights(self, t_feedback: float, starts, ends=None, likelihood=None) -> np.ndarray:
        if self.reference == "onset":
            w, _ = onset_weights(t_feedback, starts, self.distribution)
        else:
            w, _ = credit_weights(t_feedback, starts, self.distribution, ends=ends)
        return w  # (the event model's likelihood is not used: a fixed delay's credit is the paper's rule)

    def observe(self, t_feedback: float, starts, ends=None, likelihood=None) -> bool:
        self.feedbacks += 1
        return False

    def quantile(self, q: float) -> float:
        return float(self.distribution.ppf(q)) if hasattr(self.distribution, "ppf") else float("nan")

    def summary(self) -> dict:
        return {"median_s": round(self.quantile(0.5), 4), "p10_s": round(self.quantile(0.1), 4),
                "p90_s": round(self.quantile(0.9), 4), "feedbacks": int(self.feedbacks)}

    def density(self, max_s: float = 6.0, bin_s: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
        edges = np.linspace(0.0, max_s, int(round(max_s / bin_s)) + 1)
        return edges, np.diff(np.asarray(self.distribution.cdf(edges), np.float64))

    def state(self, window: bool = True) -> dict:
        return {"kind": "fixed", "spec": self.spec, "reference": self.reference, "feedbacks": self.feedbacks}

    @classmethod
    def from_state(cls, state: dict) -> "FixedDelay":
        model = cls(state["spec"], state.get("reference", "interval"))
        model.feedbacks = int(state.get("feedbacks", 0))
        return model


def is_learned(spec: str) -> bool:
    return spec.strip().partition(":")[0].strip() == LEARNED


def check_delay_estimate_spec(spec: str) -> None:
    """The one-line ValueError `delay_estimate` would raise (a config check at start-up)."""
    if is_learned(spec):
        prior = spec.strip().partition(":")[2].strip()
        check_delay_spec(prior or DEFAULT_PRIOR)
    else:
        check_delay_spec(spec)


def delay_estimate(spec: str, reference: str = "onset", **settings) -> LearnedDelay | FixedDelay:
    """From the command line's text: ``learned`` (prior uniform 0.2-4 s), ``learned:PRIOR`` (any fixed spec as
    the prior), or a fixed spec (``uniform:0.2,4``, ``NAME:ARGS``, ``steps:...``), credited over each step's
    onset or interval (`reference`). `settings` are further `LearnedDelayConfig` fields."""
    check_delay_estimate_spec(spec)
    if is_learned(spec):
        prior = spec.strip().partition(":")[2].strip() or DEFAULT_PRIOR
        return LearnedDelay(LearnedDelayConfig(prior=prior, reference=reference, **settings))
    return FixedDelay(spec, reference)


def estimate_from_state(state: dict) -> LearnedDelay | FixedDelay:
    """Inverse of either model's `state()`."""
    if state.get("kind") == LEARNED:
        return LearnedDelay.from_state(state)
    return FixedDelay.from_state(state)

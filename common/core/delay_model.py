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
            the estimate cannot confirm itself. A row that cannot tell delays apart (every candidate equally
            likely: a stuck agent's run of one polarity, or a model that knows nothing) is counted and not
            stored, so the density stays where it is (at the prior until something is learned). Each stored
            row refits two estimates by a few EM steps over the last `window` rows plus the prior, smoothed
            by a Gaussian kernel (`smooth_s`) per step (EMS): a steady one (row weight `forget`^age) and a
            fast one (`forget_fast`^age) that follows a person who slows down; credit uses whichever
            predicted the recent rows better (a running log-likelihood, `score_memory`).

`FixedDelay` wraps a fixed distribution (`common.core.delay.delay_from_spec`) behind the same interface: its
weights are the credit function's (`common.core.credit`), unnormalised (mass on steps not held is lost),
and it learns nothing. `delay_estimate(spec)` builds either from the command line's text: ``learned``,
``learned:PRIOR`` (``learned:gamma:2,0,0.4``), or a fixed spec (``uniform:0.2,4``, ``steps:...``, ``NAME:...``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from common.core.credit import credit_weights, interval_mass, onset_weights
from common.core.delay import check_delay_spec, delay_from_spec

LEARNED = "learned"
DEFAULT_PRIOR = "uniform:0.2,4"
REFERENCES = ("onset", "interval")


@dataclass(frozen=True)
class LearnedDelayConfig:
    """How a teacher's delay density is learned (defaults suit a person at a few steps per second)."""

    prior: str = DEFAULT_PRIOR
    max_s: float = 6.0
    bin_s: float = 0.1
    prior_weight: float = 2.0
    """Pseudo-feedbacks of the prior (it weighs as much as this many feedbacks)."""
    forget: float = 0.995
    """Weight of a row per later feedback for the steady estimate: about 1 / (1 - forget) = 200 feedbacks."""
    forget_fast: float = 0.96
    """The same for the estimate that follows drift (about 25 feedbacks); credit uses whichever of the two
    predicted the recent feedbacks better (`score_memory`)."""
    score_memory: float = 0.99
    """Decay per informative feedback of each estimate's running log-likelihood of the feedbacks it had not seen."""
    window: int = 300
    """Rows kept (older ones weigh forget^window, under 1%)."""
    iterations: int = 3
    """EM steps after each feedback, from the current estimate."""
    smooth_s: float = 0.1
    """Width (s, a Gaussian's sd) of the smoothing after each EM step: a density, not a comb of step-spaced spikes."""
    floor: float = 0.02
    """Share of the prior spread over all of 0..max_s, so that the data can revive any delay."""
    reference: str = "onset"
    """What a candidate step's time means: its onset (a person reacts to a move appearing) or its interval."""

    def __post_init__(self):
        check_delay_spec(self.prior)
        if not (0 < self.bin_s < self.max_s and math.isfinite(self.max_s)):
            raise ValueError(f"need 0 < bin_s < max_s, got {self.bin_s}, {self.max_s}")
        if not (0 < self.forget_fast <= 1 and 0 <= self.score_memory < 1):
            raise ValueError("need 0 < forget_fast <= 1 and 0 <= score_memory < 1")
        if not (0 < self.forget <= 1 and self.prior_weight > 0 and 0 <= self.floor < 1 and 0 <= self.smooth_s < 1):
            raise ValueError("need 0 < forget <= 1, prior_weight > 0, 0 <= floor < 1 and 0 <= smooth_s < 1")
        if self.window < 1 or self.iterations < 1:
            raise ValueError("window and iterations must be >= 1")
        if self.reference not in REFERENCES:
            raise ValueError(f"reference must be one of {REFERENCES}, got {self.reference!r}")


def summarise(model) -> dict:
    """A delay model's median, 10th and 90th percentiles (s) and the feedbacks it has seen."""
    q = model.quantile
    return {
        "median_s": round(q(0.5), 4),
        "p10_s": round(q(0.1), 4),
        "p90_s": round(q(0.9), 4),
        "feedbacks": int(model.feedbacks),
    }


def polarity_likelihood(value: int, polarities, reliability: float = 0.95) -> np.ndarray:
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
        self.rates = np.array([c.forget, c.forget_fast])
        self.by_rate = np.stack([self.prior, self.prior])  # the steady and the fast estimate
        self.scores = np.zeros(2)  # their running log-likelihood of new feedback (before fitting it)
        self.rows = np.zeros((c.window, n), np.float64)  # likelihood of each bin, per informative feedback
        self.seen = np.zeros(c.window, np.int64)  # the informative feedback count at which each row came
        self.informative = 0  # feedbacks that told something about the delay
        self.feedbacks = 0  # feedbacks observed (informative or not)
        half = max(1, int(np.ceil(3 * c.smooth_s / c.bin_s)))
        kernel = np.exp(-0.5 * (np.arange(-half, half + 1) * c.bin_s / max(c.smooth_s, 1e-9)) ** 2)
        self.kernel = kernel / kernel.sum()

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
        rated event that was not fitted with this credit (None: uninformative). False when it tells nothing
        about the delay (no candidate in 0..max_s, or all equally likely): nothing learned, only counted."""
        m = self.bin_matrix(t_feedback, starts, ends)
        like = np.ones(len(m)) if likelihood is None else np.asarray(likelihood, np.float64)
        self.feedbacks += 1
        reached = m.any(axis=1)
        if not reached.any() or np.ptp(like[reached]) <= 1e-12 * like[reached].max():
            # No candidate, or every candidate explains it equally: it tells nothing about the delay (stored, it
            # would only let the smoothing spread the density: a stuck agent's long runs of one polarity).
            return False
        row = like @ m  # P(feedback | delay in bin b), up to a constant
        row = row / row.max()
        self.scores = self.config.score_memory * self.scores + np.log(np.maximum(self.by_rate @ row, 1e-300))
        self.informative += 1
        at = self.informative % self.config.window
        self.rows[at] = row
        self.seen[at] = self.informative
        self._refit()
        return True

    def _refit(self) -> None:
        """A few EM steps of each estimate over the held rows (row i weighted rate^age in informative feedbacks,
        the prior as heavy against them in both), from where it was; credit then uses the one whose running
        score is higher (the steady one on ties)."""
        c = self.config
        held = self.seen > 0
        rows = self.rows[held]
        age = (self.informative - self.seen[held]).astype(np.float64)
        weight = self.rates[:, None] ** age[None, :]  # [2, rows]
        # The prior weighs as much against the fast estimate's few remembered rows as against the steady one's.
        strength = c.prior_weight * np.where(self.rates < 1, (1 - self.rates[0]) / np.maximum(1 - self.rates, 1e-12), 1)
        prior = strength[:, None] * self.prior
        p = self.by_rate
        for _ in range(c.iterations):
            post = rows[None, :, :] * p[:, None, :]  # [2, rows, bins]
            post /= post.sum(axis=2, keepdims=True)
            p = np.einsum("jn,jnb->jb", weight, post) + prior
            p = self.smooth(p)
            p /= p.sum(axis=1, keepdims=True)
        self.by_rate = p
        self.probs = self.by_rate[int(self.scores[1] > self.scores[0])]

    def smooth(self, p: np.ndarray) -> np.ndarray:
        """Each row of p convolved with the Gaussian kernel (edges repeated)."""
        half = len(self.kernel) // 2
        padded = np.pad(p, ((0, 0), (half, half)), mode="edge")
        windows = np.lib.stride_tricks.sliding_window_view(padded, len(self.kernel), axis=1)
        return windows @ self.kernel[::-1]

    # -- reading -----------------------------------------------------------------------------------------------
    def quantile(self, q: float) -> float:
        """The delay (s) below which a share q of the density lies (piecewise uniform within bins)."""
        cdf = np.concatenate([[0.0], np.cumsum(self.probs)])
        return float(np.interp(q * cdf[-1], cdf, self.edges))

    def reach_s(self) -> float:
        """The longest delay with any density: a step shown only before t_f - reach_s gets no credit."""
        return float(self.config.max_s)

    def mean(self) -> float:
        """The mean delay (s)."""
        return float(self.probs @ (self.edges[:-1] + self.edges[1:]) / 2)

    def summary(self) -> dict:
        """{"median_s", "p10_s", "p90_s", "feedbacks"}: the block `summary.json` writes per teacher."""
        return summarise(self)

    def density(self) -> tuple[np.ndarray, np.ndarray]:
        """(bin edges in seconds [bins + 1], probability of each bin [bins])."""
        return self.edges.copy(), self.probs.copy()

    def state(self, window: bool = True, arrays: bool = False) -> dict:
        """Plain JSON. With `window` (a checkpoint: `from_state` continues bit for bit) the rows are kept;
        without (a person's profile: a small file) only the estimate, which a new session starts from. With
        `arrays` the rows are numpy copies, not lists (a checkpoint stores them raw: 300 x 60 floats written as JSON
        took 10 ms of the learner's loop at every checkpoint)."""
        out = {
            "kind": LEARNED,
            "config": asdict(self.config),
            "probs": self.probs.tolist(),
            "feedbacks": self.feedbacks,
        }
        if window:
            held = np.flatnonzero(self.seen > 0)
            out.update(
                by_rate=self.by_rate.tolist(),
                scores=self.scores.tolist(),
                informative=self.informative,
                rows={"at": held, "seen": self.seen[held], "like": self.rows[held]},
            )
            if not arrays:
                out["rows"] = {name: rows.tolist() for name, rows in out["rows"].items()}
        return out

    @classmethod
    def from_state(cls, state: dict) -> LearnedDelay:
        """The model `state()` described (a profile without rows continues from its estimate). A state that does
        not fit its config is a one-line ValueError."""
        try:
            model = cls(LearnedDelayConfig(**state.get("config", {})))
            probs = np.asarray(state["probs"], np.float64)
            if (
                probs.shape != model.probs.shape
                or not np.all(np.isfinite(probs))
                or probs.min() < 0
                or not probs.sum() > 0
            ):
                raise ValueError("probs do not match the config's bins")
            model.feedbacks = int(state.get("feedbacks", 0))
            if "rows" in state:
                at = np.asarray(state["rows"]["at"], np.int64)
                model.rows[at] = np.asarray(state["rows"]["like"], np.float64).reshape(len(at), model.rows.shape[1])
                model.seen[at] = np.asarray(state["rows"]["seen"], np.int64)
                model.by_rate = np.asarray(state["by_rate"], np.float64).reshape(model.by_rate.shape)
                model.scores = np.asarray(state["scores"], np.float64).reshape(2)
                model.informative = int(state["informative"])
                model.probs = probs
            else:  # a returning person: their last estimate becomes the prior
                probs = probs / probs.sum()
                model.prior = (1.0 - model.config.floor) * probs + model.config.floor / len(probs)
                model.probs = model.prior.copy()
                model.by_rate = np.stack([model.prior, model.prior])
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise ValueError(f"delay state: {exc}") from None
        return model


def support_end(distribution) -> float:
    """The largest delay a distribution can give: its last point mass, the largest of a mixture's parts, a
    scipy.stats distribution's upper support; inf when it is not known."""
    if hasattr(distribution, "point_masses"):
        lags, probs = distribution.point_masses()
        return float(lags[np.flatnonzero(probs > 0)[-1]]) if np.any(probs > 0) else 0.0
    if hasattr(distribution, "parts"):
        return max(support_end(part) for part in distribution.parts)
    if hasattr(distribution, "support"):
        return float(distribution.support()[1])
    return math.inf


class FixedDelay:
    """A delay that is not learned (a fixed distribution from `delay_from_spec`), with `LearnedDelay`'s
    interface: weights are `common.core.credit`'s (not normalised: mass on steps not held is lost)."""

    def __init__(self, spec: str, reference: str = "interval", unit: float = 1.0):
        self.spec, self.reference, self.unit = spec, reference, unit
        self.distribution = delay_from_spec(spec, unit)  # (unit: seconds per lag of a steps: spec)
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

    def reach_s(self) -> float:
        """The end of the distribution's support (inf when unbounded): steps shown before t_f - reach_s get none."""
        return support_end(self.distribution)

    def quantile(self, q: float) -> float:
        if hasattr(self.distribution, "ppf"):
            return float(self.distribution.ppf(q))
        lags, probs = self.distribution.point_masses()  # (a DelayModel: the smallest lag reaching q)
        return float(lags[min(np.searchsorted(np.cumsum(probs), q - 1e-12), len(lags) - 1)])

    def summary(self) -> dict:
        return summarise(self)

    def density(self, max_s: float = 6.0, bin_s: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
        edges = np.linspace(0.0, max_s, int(round(max_s / bin_s)) + 1)
        # P(lo <= D < hi) per bin (a point mass on an edge falls in the bin it opens)
        return edges, interval_mass(self.distribution, edges[:-1] - 1e-12, edges[1:] - 1e-12)

    def state(self, window: bool = True, arrays: bool = False) -> dict:
        return {
            "kind": "fixed",
            "spec": self.spec,
            "reference": self.reference,
            "unit": self.unit,
            "feedbacks": self.feedbacks,
        }

    @classmethod
    def from_state(cls, state: dict) -> FixedDelay:
        model = cls(state["spec"], state.get("reference", "interval"), float(state.get("unit", 1.0)))
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

"""Delay distributions: the observer's true lag and the learner's assumption about it.

A `DelayModel` is a discrete distribution over lags of i * unit (i = 0, 1, ...): the paper's step-counted
model (unit one step on the step clock); `RowDelays` is one per trial of a batch. `delay_from_spec` also builds
continuous ones from scipy.stats (seconds on a person's screen: Deep TAMER's uniform 0.2-4 s is `uniform:0.2,4`).
The credit function (`common.core.credit`) needs only a distribution's CDF, so either kind serves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

PROBABILITY_TOLERANCE = 1e-3


def parse_probs(text: str | tuple | list, name: str = "probabilities") -> tuple[float, ...]:
    """'0.3,0.6,0.1' -> (0.3, 0.6, 0.1), checked to be finite, non-negative and to sum to 1."""
    if isinstance(text, str):
        try:
            values = tuple(float(x) for x in text.split(",") if x.strip())
        except ValueError:
            raise ValueError(f"{name} must be comma-separated numbers, got {text!r}") from None
    else:
        values = tuple(float(x) for x in text)
    if not values:
        raise ValueError(f"{name} is empty")
    if any(not math.isfinite(v) or v < 0 for v in values):
        raise ValueError(f"{name} must be finite and non-negative, got {values}")
    total = sum(values)
    if abs(total - 1.0) > PROBABILITY_TOLERANCE:
        raise ValueError(f"{name} must sum to 1, got {values} (sum {total:.4f})")
    return values


@dataclass(frozen=True)
class DelayModel:
    """P(lag = i * unit) = probs[i]."""

    probs: tuple[float, ...]
    unit: float = 1.0
    # Kept as arrays for `mass_between`, which credit calls for every feedback (set from the two above: not
    # arguments, and no part of ==).
    _lags: np.ndarray = field(init=False, repr=False, compare=False)
    _probs: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "probs", parse_probs(self.probs, "delay probabilities"))
        if not (self.unit > 0 and math.isfinite(self.unit)):
            raise ValueError(f"delay unit must be positive, got {self.unit}")
        object.__setattr__(self, "_lags", np.arange(len(self.probs), dtype=np.float64) * self.unit)
        object.__setattr__(self, "_probs", np.asarray(self.probs, np.float64))

    def mass_between(self, low, high):
        """P(low < lag <= high), elementwise over arrays (the point masses inside, summed in lag order)."""
        low, high = np.asarray(low, np.float64)[..., None], np.asarray(high, np.float64)[..., None]
        inside = (low < self._lags) & (self._lags <= high)
        out = np.where(inside, self._probs, 0.0).sum(axis=-1)
        return float(out) if out.ndim == 0 else out

    def point_masses(self) -> tuple[np.ndarray, np.ndarray]:
        """(lags, their probabilities), for credit's fast path."""
        return self._lags, self._probs

    def cdf(self, x):
        """P(lag <= x), elementwise."""
        return self.mass_between(np.full(np.shape(x), -np.inf), x)


class RowDelays:
    """A point-mass lag distribution per trial, for the credit function (`common.core.credit`): rows of `probs`
    [n, L] over lags 0, unit, 2 unit, ...; `mass_between(low, high)` takes [n, ...] arrays whose leading
    axis is the row. Same arithmetic as `DelayModel.mass_between`, one distribution per row."""

    def __init__(self, probs: np.ndarray, unit: float = 1.0):
        self.probs = np.asarray(probs, np.float64)
        self.lags = np.arange(self.probs.shape[1], dtype=np.float64) * unit

    def mass_between(self, low, high):
        low, high = np.asarray(low, np.float64)[..., None], np.asarray(high, np.float64)[..., None]
        inside = (low < self.lags) & (self.lags <= high)
        p = self.probs.reshape(self.probs.shape[:1] + (1,) * (low.ndim - 2) + self.probs.shape[1:])
        return np.where(inside, p, 0.0).sum(axis=-1)

    def point_masses(self) -> tuple[np.ndarray, np.ndarray]:
        return self.lags, self.probs

    def cdf(self, x):
        return self.mass_between(np.full(np.shape(x), -np.inf), x)


class MixtureDelay:
    """A mixture of delay distributions in seconds (a person with two ways of reacting: a bimodal delay), with
    the CDF credit needs, a density and a quantile function (by bisection on the CDF)."""

    def __init__(self, weights: list[float], parts: list):
        self.weights, self.parts = np.asarray(weights, np.float64), parts

    def cdf(self, x):
        return sum(w * np.asarray(p.cdf(x), np.float64) for w, p in zip(self.weights, self.parts))

    def pdf(self, x):
        return sum(w * np.asarray(p.pdf(x), np.float64) for w, p in zip(self.weights, self.parts))

    def ppf(self, q):
        q = np.asarray(q, np.float64)
        lo, hi = np.zeros(q.shape), np.full(q.shape, 60.0)
        for _ in range(60):
            mid = (lo + hi) / 2
            below = self.cdf(mid) < q
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        out = (lo + hi) / 2
        return float(out) if out.ndim == 0 else out


class UniformDelay:
    """The uniform delay on [loc, loc + scale] with the numbers scipy.stats.uniform gives, bit for bit
    (tests/core/test_delay.py), without importing scipy: that import costs each learner and console 1.5 s of CPU at
    start, for the default delay. Anything else scipy's frozen uniform has is read from it."""

    def __init__(self, loc: float, scale: float):
        if not (scale > 0 and math.isfinite(loc) and math.isfinite(scale)):
            raise ValueError(f"uniform delay needs a finite loc and scale > 0, got {loc}, {scale}")
        self.loc, self.scale = float(loc), float(scale)

    def _standard(self, x) -> np.ndarray:
        return np.asarray((np.asarray(x, np.float64) - self.loc) / self.scale, np.float64)

    @staticmethod
    def _out(values: np.ndarray):
        return values[()] if values.ndim == 0 else values

    def cdf(self, x):
        z = self._standard(x)
        return self._out(np.where(np.isnan(z), np.nan, np.clip(z, 0.0, 1.0)))

    def pdf(self, x):
        z = self._standard(x)
        return self._out(np.where(np.isnan(z), np.nan, np.where((z >= 0) & (z <= 1), 1.0 / self.scale, 0.0)))

    def ppf(self, q):
        q = np.asarray(q, np.float64)
        return self._out(np.where((q >= 0) & (q <= 1), q * self.scale + self.loc, np.nan))

    def rvs(self, size=None, random_state=None):
        if not isinstance(random_state, (np.random.Generator, np.random.RandomState)):  # a seed: scipy's own rules
            return self.__getattr__("rvs")(size=size, random_state=random_state)
        return random_state.uniform(0.0, 1.0, size) * self.scale + self.loc

    def support(self) -> tuple[float, float]:
        return self.loc, self.scale + self.loc

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        import scipy.stats

        return getattr(scipy.stats.uniform(loc=self.loc, scale=self.scale), name)


def _mixture_from_spec(spec: str) -> MixtureDelay:
    """``mix:W1*SPEC1+W2*SPEC2+...``: weights (normalised) of distributions in seconds."""
    weights, parts = [], []
    for term in spec.partition(":")[2].split("+"):
        w, star, part = term.partition("*")
        try:
            weight = float(w) if star else float("nan")
        except ValueError:
            weight = float("nan")
        if not (math.isfinite(weight) and weight > 0) or part.strip().startswith(("steps", "mix")):
            raise ValueError(f"delay {spec!r}: mix needs terms WEIGHT*NAME:ARGS (weights > 0, seconds)")
        weights.append(weight)
        parts.append(delay_from_spec(part.strip()))
    total = sum(weights)
    return MixtureDelay([w / total for w in weights], parts)


def _parse_spec(spec: str) -> tuple[str, str, list[float]]:
    """(name, the raw arguments, them as numbers: empty for ``steps`` and ``mix``); checks what needs no scipy."""
    name, _, args = spec.partition(":")
    name = name.strip()
    if name == "mix":
        return name, args, []
    if name == "steps":
        parse_probs(args, "delay steps")
        return name, args, []
    try:
        values = [float(a) for a in args.split(",") if a.strip()]
    except ValueError:
        raise ValueError(f"delay {spec!r}: arguments must be numbers") from None
    if name == "uniform" and (len(values) != 2 or not 0 <= values[0] < values[1]):
        raise ValueError(f"delay {spec!r}: uniform needs 0 <= LOW < HIGH")
    return name, args, values


def check_delay_spec(spec: str) -> None:
    """The one-line ValueError `delay_from_spec` would raise; scipy is imported only for a scipy.stats name (a
    config check at start-up stays cheap)."""
    if _parse_spec(spec)[0] not in ("steps", "uniform"):
        delay_from_spec(spec)


def delay_from_spec(spec: str, unit: float = 1.0):
    """A delay distribution from text: ``steps:0.3,0.6,0.1`` (point masses at 0, 1, 2 units), ``uniform:LOW,HIGH``
    (seconds; Deep TAMER's default is ``uniform:0.2,4``) or ``NAME:ARG,...`` for any scipy.stats distribution
    (``gamma:2.0,0,0.4`` = shape 2, loc 0, scale 0.4) or ``mix:W1*SPEC1+W2*SPEC2`` (a mixture of those).
    Errors are one-line ValueErrors."""
    name, args, values = _parse_spec(spec)
    if name == "steps":
        return DelayModel(parse_probs(args, "delay steps"), unit)
    if name == "mix":
        return _mixture_from_spec(spec)
    if name == "uniform":
        return UniformDelay(loc=values[0], scale=values[1] - values[0])
    import scipy.stats

    dist = getattr(scipy.stats, name, None)
    if not isinstance(dist, scipy.stats.rv_continuous):
        raise ValueError(f"delay {spec!r}: unknown distribution {name!r} (steps, uniform or a scipy.stats name)")
    try:
        frozen = dist(*values)
        ok = np.isfinite(frozen.cdf(1.0))
    except (TypeError, ValueError) as e:
        raise ValueError(f"delay {spec!r}: {e}") from None
    if not ok:
        raise ValueError(f"delay {spec!r}: invalid parameters for {name}")
    return frozen

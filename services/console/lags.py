"""A scripted person's reaction lag in seconds, as text: the shapes a declared design names (`designs/*.yaml`).

    uniform:0.3,1.5                      any `common.core.delay.delay_from_spec` distribution in seconds
    lognorm:0.6,0,0.9                    (scipy.stats names: shape(s), loc, scale)
    mix:0.6*gamma:8,0,0.075+0.4*gamma:12,0,0.15
                                         a mixture (`common.core.delay`'s): a bimodal person
    drift:0.5,2,0.2                      lognormal with spread (sigma) 0.2 whose median moves linearly from 0.5 s
                                         in the first episode to 2 s in the last: a person who tires

A run draws its whole lag plan up front (`lag_plan`): one lag per (episode, step in episode), from a generator
seeded by the run's seed, so two arms of a pair meet the same person (common random numbers) and a drifting
person is as tired in episode e of either arm. Lags are kept in [MIN_LAG, MAX_LAG]: a press faster than a
human's or later than the 6 s the learner's delay model covers would test something else.
"""

from __future__ import annotations

import math

import numpy as np

from common.core.delay import delay_from_spec

MIN_LAG, MAX_LAG = 0.15, 5.9


def _drift(args: str) -> tuple[float, float, float]:
    try:
        start, end, sigma = (float(a) for a in args.split(","))
    except ValueError:
        raise ValueError(
            f"lag drift:{args}: drift:START_MEDIAN,END_MEDIAN,SIGMA (seconds, seconds, log-spread)"
        ) from None
    if not (0 < start and 0 < end and 0 < sigma < 3 and math.isfinite(start + end)):
        raise ValueError(f"lag drift:{args}: medians must be positive and sigma in (0, 3)")
    return start, end, sigma


def check_lag_spec(spec: str) -> None:
    """The one-line ValueError `lag_plan` would raise for `spec`."""
    lag_plan(spec, 2, 2, 0)


def lag_plan(spec: str, episodes: int, steps: int, seed: int) -> np.ndarray:
    """Lags in seconds [episodes, steps]: the lag of the press on step `t` of episode `e` (if the person presses)."""
    rng = np.random.default_rng([seed, 0x1A6])
    name, _, args = spec.partition(":")
    if name == "drift":
        start, end, sigma = _drift(args)
        medians = np.linspace(start, end, episodes) if episodes > 1 else np.array([start])
        lags = medians[:, None] * np.exp(sigma * rng.standard_normal((episodes, steps)))
    elif name == "mix":  # the core's mixture (common.core.delay): each press from one of its parts
        mixture = delay_from_spec(spec)
        which = rng.choice(len(mixture.parts), size=(episodes, steps), p=mixture.weights)
        draws = np.stack([p.rvs(size=(episodes, steps), random_state=rng) for p in mixture.parts])
        lags = np.take_along_axis(draws, which[None], 0)[0]
    else:
        dist = delay_from_spec(spec)
        if not hasattr(dist, "rvs"):
            raise ValueError(f"lag {spec!r}: a distribution in seconds (not steps:...)")
        lags = np.asarray(dist.rvs(size=(episodes, steps), random_state=rng), np.float64)
    return np.clip(lags, MIN_LAG, MAX_LAG)

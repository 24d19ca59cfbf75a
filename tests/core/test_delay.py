"""The uniform delay without scipy (`common.core.delay.UniformDelay`) gives scipy.stats.uniform's numbers bit for bit:
the CDF credit integrates, the density onset credit reads, quantiles, draws from a generator, and the support."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from common.core.delay import UniformDelay, delay_from_spec


@pytest.mark.parametrize("low,high", [(0.2, 4.0), (0.0, 1.0), (0.3, 1.5), (1e-3, 60.0)])
def test_uniform_matches_scipy_bit_for_bit(low, high):
    ours, theirs = UniformDelay(low, high - low), scipy.stats.uniform(loc=low, scale=high - low)
    rng = np.random.default_rng(0)
    x = np.concatenate(
        [rng.uniform(-1, high + 1, 2000), [low, high, np.nextafter(low, -1), np.nextafter(high, 9), -np.inf, np.inf]]
    )
    x = np.append(x, np.nan)
    q = np.concatenate([rng.uniform(0, 1, 500), [0.0, 1.0, -0.1, 1.1, np.nan]])
    for method, arg in (("cdf", x), ("pdf", x), ("ppf", q)):
        a, b = getattr(ours, method)(arg), getattr(theirs, method)(arg)
        assert np.array_equal(a, b, equal_nan=True), method
        assert getattr(ours, method)(float(arg[3])) == getattr(theirs, method)(float(arg[3])), method
    assert ours.support() == theirs.support()
    draws = ours.rvs(size=(3, 50), random_state=np.random.default_rng(7))
    assert np.array_equal(draws, theirs.rvs(size=(3, 50), random_state=np.random.default_rng(7)))
    assert ours.rvs(size=4, random_state=5).tolist() == theirs.rvs(size=4, random_state=5).tolist()
    assert ours.mean() == theirs.mean() and ours.interval(0.5) == theirs.interval(0.5)  # (read from scipy)


def test_the_default_delay_is_the_uniform_without_scipy():
    assert isinstance(delay_from_spec("uniform:0.2,4"), UniformDelay)
    with pytest.raises(ValueError, match="uniform needs"):
        delay_from_spec("uniform:4,0.2")

"""Seed statistics: bootstrap intervals against closed forms and constructed arms."""

from __future__ import annotations

import numpy as np
import stats


def test_bootstrap_interval_of_the_mean_matches_the_normal_approximation():
    x = np.random.default_rng(0).normal(3.0, 2.0, 400)
    lo, hi = stats.bootstrap_mean_ci(x)
    half = 1.96 * x.std() / np.sqrt(x.size)  # large n: the bootstrap approaches it
    assert abs((hi - lo) / 2 - half) / half < 0.08
    assert abs((hi + lo) / 2 - x.mean()) < 0.1 * half
    assert stats.bootstrap_mean_ci([5.0]) == (5.0, 5.0)


def test_difference_interval_and_direction():
    rng = np.random.default_rng(1)
    a, b = rng.normal(0.0, 1.0, 10), rng.normal(5.0, 1.0, 10)
    ci = stats.bootstrap_diff_ci(a, b)
    assert ci[0] < a.mean() - b.mean() < ci[1] and ci[1] < 0
    assert stats.direction(ci) == "lower"
    assert stats.direction(stats.bootstrap_diff_ci(b, a)) == "higher"
    same = stats.bootstrap_diff_ci(a, rng.normal(0.0, 1.0, 10))
    assert stats.direction(same) == "unresolved"
    s = stats.summary([1.0, 2.0, 3.0])
    assert s["mean"] == 2.0 and s["n"] == 3 and s["ci_low"] >= 1.0 and s["ci_high"] <= 3.0


def test_std_ratio_interval_separates_a_narrow_arm_from_a_wide_one():
    rng = np.random.default_rng(3)
    narrow, wide = rng.normal(0, 1, 40), rng.normal(0, 10, 40)
    lo, hi = stats.bootstrap_std_ratio_ci(narrow, wide)
    assert lo < 0.1 < hi < 0.2  # the true ratio is 0.1
    lo, hi = stats.bootstrap_std_ratio_ci(wide, rng.normal(5, 10, 40))
    assert lo < 1 < hi  # same spread: the interval holds 1
    assert np.isnan(stats.bootstrap_std_ratio_ci([1.0], [1.0, 2.0])[0])

"""Seed statistics: bootstrap intervals against closed forms and constructed arms."""

from __future__ import annotations

import numpy as np
import pytest
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


def test_the_permutation_test_enumerates_every_relabeling():
    """Exact p-value against a brute-force count over all C(10, 5) = 252 relabelings."""
    import itertools

    a, b = [3.1, 4.0, 5.2, 6.0, 4.4], [1.0, 2.5, 3.0, 1.7, 2.2]
    pooled = np.array(a + b)
    observed = abs(np.mean(a) - np.mean(b))
    extreme = 0
    for chosen in itertools.combinations(range(10), 5):
        mask = np.zeros(10, bool)
        mask[list(chosen)] = True
        extreme += abs(pooled[mask].mean() - pooled[~mask].mean()) >= observed - 1e-12
    assert stats.permutation_p(a, b) == pytest.approx(extreme / 252)
    assert stats.permutation_p(a, b) == pytest.approx(2 / 252)  # fully separated arms
    assert stats.permutation_p(a, a) == pytest.approx(1.0)
    assert np.isnan(stats.permutation_p([], b))


def test_welch_interval_matches_its_closed_form():
    from scipy.stats import t as student

    a, b = np.array([3.1, 4.0, 5.2, 6.0, 4.4]), np.array([1.0, 2.5, 3.0, 1.7, 2.2, 9.0])
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    df = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    half = student.ppf(0.975, df) * np.sqrt(va + vb)
    diff = a.mean() - b.mean()
    assert stats.welch_ci(a, b) == pytest.approx((diff - half, diff + half))
    assert np.isnan(stats.welch_ci([1.0], b)[0])


def test_the_papers_own_difference_is_tested_from_its_numbers():
    """HalfCheetah 10K feedback, MA alpha 0.01 against MB-MPO: 36 +- 5.91 against 38 +- 3.95
    over 10 seeds is within the noise; 672 +- 67 against -1084 +- 73 is not. The p-value from
    summary numbers equals the test on data that have them."""
    assert stats.welch_p_from_stats(36, 5.91, 10, 38, 3.95, 10) > 0.3
    assert stats.welch_p_from_stats(672, 67, 10, -1084, 73, 10) < 1e-10
    from scipy.stats import ttest_ind

    x, y = np.array([1.0, 2.0, 4.0, 5.0]), np.array([2.0, 6.0, 7.0, 9.0, 11.0])
    direct = ttest_ind(x, y, equal_var=False).pvalue
    from_numbers = stats.welch_p_from_stats(x.mean(), x.std(ddof=1), 4, y.mean(),
                                            y.std(ddof=1), 5)  # fmt: skip
    assert from_numbers == pytest.approx(direct)


def test_holm_adjusts_step_down_and_keeps_untested_cells_out():
    assert stats.holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    # four cells at 0.01 .. 0.04: each below 5% alone, only the smallest after the correction
    adjusted = stats.holm([0.01, 0.02, 0.03, 0.04])
    assert adjusted == pytest.approx([0.04, 0.06, 0.06, 0.06])
    assert [stats.significant(p) for p in adjusted] == [True, False, False, False]
    out = stats.holm([0.02, float("nan"), 0.02])  # the NaN is no test: m = 2
    assert out[0] == pytest.approx(0.04) and np.isnan(out[1]) and out[2] == pytest.approx(0.04)


def test_benjamini_hochberg_against_a_hand_worked_example():
    # p sorted: 0.005, 0.01, 0.03, 0.04 (m = 4); m p / rank: 0.02, 0.02, 0.04, 0.04; the
    # step-up keeps the running minimum from the largest down: 0.02, 0.02, 0.04, 0.04.
    p = [0.01, 0.04, 0.03, 0.005]
    assert stats.benjamini_hochberg(p) == pytest.approx([0.02, 0.04, 0.04, 0.02])
    # the same four under Holm: 0.02, 0.03, 0.06, 0.06 by rank; BH rejects all four at 5%,
    # Holm only two (the false discovery rate is a weaker promise than the family-wise error)
    assert stats.holm(p) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    # a large p-value keeps its own: 0.9 * 2 / 2 = 0.9; the NaN is no test (m = 2)
    out = stats.benjamini_hochberg([0.9, float("nan"), 0.01])
    assert out[0] == pytest.approx(0.9) and np.isnan(out[1]) and out[2] == pytest.approx(0.02)
    assert stats.benjamini_hochberg([]) == []


def test_sign_flips_and_spreads():
    assert stats.sign_flip_p([1.0, 2.0, 3.0, 4.0, 5.0]) == pytest.approx(2 / 32)
    assert stats.sign_flip_p([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]) == pytest.approx(2 / 64)
    assert stats.sign_flip_p([1.0, -1.0, 2.0, -2.0]) == pytest.approx(1.0)
    narrow, wide = [10.0, 10.5, 9.5, 10.2, 9.8], [0.0, 20.0, 5.0, 15.0, 30.0]
    assert stats.spread_p(narrow, wide) < 0.05
    assert stats.spread_p(narrow, [x + 100 for x in narrow]) > 0.5  # same spread, other mean
    # the paper's HalfCheetah 200K return: std 128 against 318, 10 seeds each
    assert stats.f_test_p_from_stats(128, 10, 318, 10) < 0.05
    assert stats.f_test_p_from_stats(100, 10, 110, 10) > 0.5


def test_summary_uses_the_sample_standard_deviation():
    s = stats.summary([1.0, 2.0, 3.0, 4.0])
    assert s["std"] == pytest.approx(np.std([1.0, 2.0, 3.0, 4.0], ddof=1))
    assert np.isnan(stats.summary([2.0])["std"])


def test_t_interval_against_a_hand_worked_example():
    # 1, 2, 3, 4, 5: mean 3, sd sqrt(2.5), t(0.975, 4) = 2.7764451 -> half width 1.963243
    low, high = stats.t_interval([1.0, 2.0, 3.0, 4.0, 5.0])
    assert low == pytest.approx(3 - 1.963243, abs=1e-6)
    assert high == pytest.approx(3 + 1.963243, abs=1e-6)
    assert stats.t_interval([2.5]) == [2.5, 2.5]


def test_difference_is_the_welch_interval_and_the_exact_permutation_p():
    d = stats.difference([1.0, 2.0, 3.0], [4.0, 5.0, 6.0])
    assert d["diff"] == pytest.approx(-3.0)
    assert d["welch_ci"] == pytest.approx(list(stats.welch_ci([1, 2, 3], [4, 5, 6])))
    assert d["permutation_p"] == pytest.approx(2 / 20)  # 2 of C(6, 3) relabelings as extreme

"""Seed statistics for the experiments' tables: means, intervals, tests, corrections.

Seeds are the unit of replication (each seed's value is its final deterministic evaluation);
arms are unpaired (different seeds of different arms are not matched). With the handful of seeds
a CPU affords, a percentile bootstrap of a difference of means is too narrow, so a verdict rests
on tests that hold at small n: the exact permutation test of the difference of means (every
relabeling of the pooled seeds; no distributional assumption), beside Welch's t interval, with
Holm's correction over a claim's family of cells. The bootstrap intervals stay as descriptions.
Standard deviations are sample ones (ddof 1). The paper's own differences are tested from its
reported means, standard deviations and seed count (Welch's t-test from summary statistics).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.stats

RESAMPLES = 10_000


def _resampled(x: np.ndarray, statistic: str, resamples: int, rng: np.random.Generator):
    """``statistic`` ("mean" or "std") of ``resamples`` draws of ``x`` with replacement."""
    draws = x[rng.integers(0, x.size, (resamples, x.size))]
    return getattr(draws, statistic)(1)


def _interval(values: np.ndarray, level: float) -> tuple[float, float]:
    if values.size == 0:
        return float("nan"), float("nan")
    tail = 100 * (1 - level) / 2
    return float(np.percentile(values, tail)), float(np.percentile(values, 100 - tail))


def bootstrap_mean_ci(
    values: Sequence[float], level: float = 0.95, resamples: int = RESAMPLES, seed: int = 0
) -> tuple[float, float]:
    """The ``level`` percentile-bootstrap interval of the mean of ``values`` (NaN for none;
    a single value gives a zero-width interval)."""
    x = np.asarray(values, np.float64)
    if x.size == 0:
        return float("nan"), float("nan")
    return _interval(_resampled(x, "mean", resamples, np.random.default_rng(seed)), level)


def bootstrap_diff_ci(
    a: Sequence[float],
    b: Sequence[float],
    level: float = 0.95,
    resamples: int = RESAMPLES,
    seed: int = 0,
) -> tuple[float, float]:
    """The ``level`` percentile-bootstrap interval of mean(a) - mean(b), seeds resampled within
    each arm."""
    x, y = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if x.size == 0 or y.size == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    dx, dy = _resampled(x, "mean", resamples, rng), _resampled(y, "mean", resamples, rng)
    return _interval(dx - dy, level)


def bootstrap_std_ratio_ci(
    a: Sequence[float],
    b: Sequence[float],
    level: float = 0.95,
    resamples: int = RESAMPLES,
    seed: int = 0,
) -> tuple[float, float]:
    """The ``level`` percentile-bootstrap interval of std(a) / std(b) over seeds (the paper's
    "reduction in variance": below 1 when a's seeds spread less). NaN for fewer than 2 values
    in an arm; resamples where b's spread is zero are dropped."""
    x, y = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if x.size < 2 or y.size < 2:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    sx, sy = _resampled(x, "std", resamples, rng), _resampled(y, "std", resamples, rng)
    return _interval(sx[sy > 0] / sy[sy > 0], level)


def sample_std(values: Sequence[float]) -> float:
    """The sample standard deviation (ddof 1); NaN under 2 values."""
    x = np.asarray(values, np.float64)
    return float(x.std(ddof=1)) if x.size >= 2 else float("nan")


def summary(values: Sequence[float]) -> dict[str, float]:
    """mean, sample std (over seeds, ddof 1), n and the 95% bootstrap interval of the mean."""
    x = np.asarray(values, np.float64)
    lo, hi = bootstrap_mean_ci(x)
    return {"mean": float(x.mean()) if x.size else float("nan"),
            "std": sample_std(x) if x.size else float("nan"), "n": int(x.size),
            "ci_low": lo, "ci_high": hi}  # fmt: skip


EXACT_UP_TO = 10  # seeds per arm up to which the permutation test enumerates every relabeling


def permutation_p(a: Sequence[float], b: Sequence[float], resamples: int = 100_000,
                  seed: int = 0) -> float:  # fmt: skip
    """Two-sided p-value of mean(a) - mean(b) under exchangeable labels: exact (every
    relabeling of the pooled values) when both arms have at most ``EXACT_UP_TO`` values, else
    ``resamples`` random relabelings. NaN under 2 values in an arm. With 5 seeds an arm there are
    252 relabelings, so the smallest p-value is 2/252 = 0.0079."""
    x, y = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if x.size < 2 or y.size < 2:
        return float("nan")
    exact = max(x.size, y.size) <= EXACT_UP_TO
    result = scipy.stats.permutation_test(
        (x, y), lambda u, v, axis: np.mean(u, axis) - np.mean(v, axis), vectorized=True,
        permutation_type="independent", alternative="two-sided",
        n_resamples=np.inf if exact else resamples, rng=np.random.default_rng(seed),
    )  # fmt: skip
    return float(result.pvalue)


def sign_flip_p(values: Sequence[float], resamples: int = 100_000, seed: int = 0) -> float:
    """Two-sided p-value that the mean of ``values`` (paired differences, e.g. after - before
    adaptation per seed) is zero, by flipping their signs: exact (all 2^n flips) for at most
    ``EXACT_UP_TO`` values. NaN under 2 values. With 5 seeds the smallest p-value is 2/32 = 0.0625,
    so 5 seeds can never make it significant at 5%: such a claim needs 6 or more."""
    x = np.asarray(values, np.float64)
    if x.size < 2:
        return float("nan")
    result = scipy.stats.permutation_test(
        (x,), lambda u, axis: np.mean(u, axis), vectorized=True, permutation_type="samples",
        alternative="two-sided", n_resamples=np.inf if x.size <= EXACT_UP_TO else resamples,
        rng=np.random.default_rng(seed),
    )  # fmt: skip
    return float(result.pvalue)


def t_interval(values: Sequence[float], level: float = 0.95) -> list[float]:
    """The ``level`` t interval of the mean of ``values`` (n - 1 degrees of freedom): the
    interval for seeds (or paired differences) too few for a bootstrap; a single value is its
    own interval, none is NaN."""
    x = np.asarray(values, np.float64)
    if x.size == 0:
        return [float("nan")] * 2
    if x.size < 2:
        return [float(x.mean())] * 2
    half = scipy.stats.t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size)
    return [float(x.mean() - half), float(x.mean() + half)]


def spread_p(a: Sequence[float], b: Sequence[float]) -> float:
    """Two-sided p-value that two arms spread alike: the Brown-Forsythe test (Levene's on
    deviations from the median, robust to non-normal seeds). NaN under 2 values in an arm or
    where neither arm spreads."""
    x, y = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if x.size < 2 or y.size < 2 or (x.std() == 0 and y.std() == 0):
        return float("nan")
    return float(scipy.stats.levene(x, y, center="median").pvalue)


def f_test_p_from_stats(std_a: float, n_a: int, std_b: float, n_b: int) -> float:
    """Two-sided F-test p-value that two reported standard deviations differ (normal seeds
    assumed: all a published table allows)."""
    if std_a == 0 or std_b == 0:
        return 0.0 if std_a != std_b else 1.0
    f = (std_a / std_b) ** 2
    one = scipy.stats.f.sf(f, n_a - 1, n_b - 1) if f > 1 else scipy.stats.f.cdf(f, n_a - 1, n_b - 1)
    return float(min(1.0, 2 * one))


def welch_ci(a: Sequence[float], b: Sequence[float], level: float = 0.95) -> tuple[float, float]:
    """Welch's t interval of mean(a) - mean(b) (unequal variances, Welch-Satterthwaite degrees
    of freedom). NaN under 2 values in an arm, or where both arms have no spread."""
    x, y = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if x.size < 2 or y.size < 2 or (x.std() == 0 and y.std() == 0):
        return float("nan"), float("nan")
    ci = scipy.stats.ttest_ind(x, y, equal_var=False).confidence_interval(level)
    return float(ci.low), float(ci.high)


def difference(a: Sequence[float], b: Sequence[float]) -> dict[str, Any]:
    """mean(a) - mean(b) of two independent samples (seeds of two arms): the difference,
    Welch's 95% interval and the exact permutation p, as one record."""
    return {"diff": float(np.mean(a) - np.mean(b)),
            "welch_ci": [float(x) for x in welch_ci(a, b)],
            "permutation_p": permutation_p(a, b)}  # fmt: skip


def welch_p_from_stats(mean_a: float, std_a: float, n_a: int, mean_b: float, std_b: float,
                       n_b: int) -> float:  # fmt: skip
    """Two-sided Welch t-test p-value from reported means, sample standard deviations and seed
    counts: is a published difference significant by its own numbers?"""
    if std_a == 0 and std_b == 0:
        return 0.0 if mean_a != mean_b else 1.0
    result = scipy.stats.ttest_ind_from_stats(mean_a, std_a, n_a, mean_b, std_b, n_b,
                                              equal_var=False)  # fmt: skip
    return float(result.pvalue)


def holm(pvalues: Sequence[float]) -> list[float]:
    """Holm's step-down adjusted p-values for one family (NaN entries stay NaN and do not count
    as tests): reject where the adjusted value is below the level, family-wise error held."""
    p = np.asarray(pvalues, np.float64)
    tested = np.flatnonzero(~np.isnan(p))
    adjusted = np.full(p.shape, np.nan)
    m, running = tested.size, 0.0
    for rank, i in enumerate(tested[np.argsort(p[tested], kind="stable")]):
        running = max(running, min(1.0, (m - rank) * p[i]))
        adjusted[i] = running
    return adjusted.tolist()


def benjamini_hochberg(pvalues: Sequence[float]) -> list[float]:
    """Benjamini-Hochberg adjusted p-values (q-values) for one family (NaN entries stay NaN and
    do not count as tests): reject where the adjusted value is below the level, the false
    discovery rate held. The step-up: the i-th smallest of m gets min over j >= i of
    m p_(j) / j, capped at 1."""
    p = np.asarray(pvalues, np.float64)
    tested = np.flatnonzero(~np.isnan(p))
    adjusted = np.full(p.shape, np.nan)
    m = tested.size
    order = tested[np.argsort(p[tested], kind="stable")]
    running = 1.0
    for rank in range(m - 1, -1, -1):
        i = order[rank]
        running = min(running, m * p[i] / (rank + 1))
        adjusted[i] = running
    return adjusted.tolist()


def significant(p: float, level: float = 0.05) -> bool:
    """``p`` below ``level`` (False for NaN: no test)."""
    return not math.isnan(p) and p < level


def direction(diff_ci: tuple[float, float]) -> str:
    """ "lower" / "higher" when the interval excludes zero, else "unresolved"."""
    lo, hi = diff_ci
    if hi < 0:
        return "lower"
    if lo > 0:
        return "higher"
    return "unresolved"

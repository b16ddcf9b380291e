"""Seed statistics for the experiments' tables: means, bootstrap intervals, arm differences.

Seeds are the unit of replication (each seed's value is its final deterministic evaluation).
Intervals are percentile bootstraps over seeds (``resamples`` draws with replacement, a fixed
generator so tables are reproducible); a difference between two arms resamples each arm's seeds
independently (unpaired: different seeds of different arms are not matched).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

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


def summary(values: Sequence[float]) -> dict[str, float]:
    """mean, std (over seeds, ddof 0), n and the 95% bootstrap interval of the mean."""
    x = np.asarray(values, np.float64)
    lo, hi = bootstrap_mean_ci(x)
    return {"mean": float(x.mean()) if x.size else float("nan"),
            "std": float(x.std()) if x.size else float("nan"), "n": int(x.size),
            "ci_low": lo, "ci_high": hi}  # fmt: skip


def direction(diff_ci: tuple[float, float]) -> str:
    """ "lower" / "higher" when the interval excludes zero, else "unresolved"."""
    lo, hi = diff_ci
    if hi < 0:
        return "lower"
    if lo > 0:
        return "higher"
    return "unresolved"

"""Whether a chunk of training diverged: the guard the run loop asks before it writes a step.

A run diverges in more ways than NaN. A learning rate far too large sends a loss to 1e21 while
every value stays finite, drives the weights to huge magnitudes, or saturates a tanh policy
whose entropy estimate collapses to -1e10; the run would otherwise save that chunk and report
success. ``Guard.check`` names what went wrong in a record and in the parameters, after every
chunk and before anything of it is written:

* non-finite: any NaN or inf in the record (the model's holdout MSE excepted: it is inf until
  the first model fit) or in a parameter group;
* blown up: a guarded training metric (losses, entropies, Q values, the MA terms) whose
  magnitude exceeds ``JUMP`` times its running scale (the largest magnitude of the earlier
  records, at least 1) or ``ABSOLUTE`` outright;
* weights: a parameter group whose largest magnitude exceeds ``PARAMETER_BOUND``;
* saturated: an entropy below ``ENTROPY_FLOOR`` per action dimension (a Gaussian with the
  smallest admitted standard deviation, e^-20, has -18.6 per dimension).

The thresholds sit orders of magnitude beyond every committed record (the largest jump of a
guarded metric over its running scale in ``experiments/records`` is 7e4; the lowest entropy is
-27.5 in all; ``tests/test_divergence.py`` reads them all).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

JUMP = 1e6
ABSOLUTE = 1e12
PARAMETER_BOUND = 1e6
ENTROPY_FLOOR = -100.0
GUARDED = ("loss", "entropy", "q_mean", "ma_penalty", "ma_feedback", "ma_temporal")


def guarded(key: str) -> bool:
    """Whether a record's metric is watched for blowing up."""
    return any(part in key for part in GUARDED) and not key.endswith("_std")


def non_finite(record: dict[str, Any]) -> list[str]:
    """The names of a record's non-finite values (NaN or inf losses, returns)."""
    bad = []
    for k, v in record.items():
        if k.startswith("model_holdout_mse"):
            continue
        if not np.all(np.isfinite(np.asarray(v, dtype=np.float64))):
            bad.append(k)
    return bad


def parameter_report(state: Any) -> dict[str, tuple[bool, float]]:
    """Per parameter group of the agent's state: (all finite, largest magnitude)."""
    report = {}
    for name, tree in state.parameter_groups().items():
        leaves = jax.tree.leaves(tree)
        finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]))
        largest = jnp.max(jnp.stack([jnp.max(jnp.abs(x)) for x in leaves]))
        report[name] = (finite, largest)
    return {k: (bool(f), float(m)) for k, (f, m) in jax.device_get(report).items()}


class Guard:
    """One run's divergence check; ``scale`` holds each guarded metric's running scale."""

    def __init__(self, action_size: int, earlier: list[dict[str, Any]] = ()) -> None:
        self.action_size = action_size
        self.scale: dict[str, float] = {}
        for record in earlier:
            self.observe(record)

    def observe(self, record: dict[str, Any]) -> None:
        """Takes a written record into the running scales."""
        for k, v in record.items():
            if guarded(k) and not isinstance(v, list) and np.isfinite(v):
                self.scale[k] = max(self.scale.get(k, 0.0), abs(float(v)))

    def check(self, record: dict[str, Any], state: Any) -> list[str]:
        """What diverged in this chunk (empty when nothing did), each a short phrase."""
        problems = [f"{k} is not finite" for k in non_finite(record)]
        for name, (finite, largest) in parameter_report(state).items():
            if not finite:
                problems.append(f"{name} are not finite")
            elif largest > PARAMETER_BOUND:
                problems.append(f"{name} reach {largest:.3g} (bound {PARAMETER_BOUND:g})")
        for k, v in record.items():
            if not guarded(k) or isinstance(v, list) or not np.isfinite(v):
                continue
            size, scale = abs(float(v)), max(self.scale.get(k, 0.0), 1.0)
            if size > ABSOLUTE or size > JUMP * scale:
                problems.append(f"{k} is {float(v):.3g} (running scale {scale:.3g})")
            elif k == "entropy" and v < ENTROPY_FLOOR * self.action_size:
                problems.append(f"entropy collapsed to {float(v):.3g} (a saturated policy)")
        return problems

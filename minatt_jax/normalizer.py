"""Running mean/variance observation normalization (Welford/Chan updates), as a pytree."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

# normalize(): (obs - mean) / sqrt(var + EPS), clipped to [-CLIP, CLIP] (exported policies
# carry both, see export.py).
EPS = 1e-8
CLIP = 10.0


@struct.dataclass
class Normalizer:
    mean: jax.Array
    var: jax.Array
    count: jax.Array


def init_normalizer(dim: int) -> Normalizer:
    """Empty running statistics.

    Args:
        dim: the observation's size.

    Returns:
        A ``Normalizer`` with mean 0, variance 1 and count 0 (normalizing is then the identity
        up to ``EPS``).
    """
    return Normalizer(jnp.zeros((dim,)), jnp.ones((dim,)), jnp.zeros(()))


def update(norm: Normalizer, batch: jax.Array) -> Normalizer:
    """Adds a batch of observations to the running statistics (Chan's parallel update: exact
    for any batch sizes).

    Args:
        norm: the statistics so far.
        batch: observations, (n, dim).

    Returns:
        The statistics with the batch included.
    """
    n = batch.shape[0]
    b_mean, b_var = jnp.mean(batch, 0), jnp.var(batch, 0)
    total = norm.count + n
    delta = b_mean - norm.mean
    mean = norm.mean + delta * n / total
    m2 = norm.var * norm.count + b_var * n + delta**2 * norm.count * n / total
    return Normalizer(mean, m2 / total, total)


def scale_reward(return_stats: Normalizer | None, reward: jax.Array) -> jax.Array:
    """Scales rewards by the running standard deviation of the discounted return
    (``SACConfig.normalize_reward``).

    Args:
        return_stats: the discounted return's statistics (1-dim); None when scaling is off.
        reward: rewards of any shape.

    Returns:
        ``reward / sqrt(var + EPS)``, or ``reward`` unchanged when ``return_stats`` is None.
    """
    if return_stats is None:
        return reward
    return reward / jnp.sqrt(return_stats.var[0] + EPS)


def normalize(norm: Normalizer, obs: jax.Array, enabled: bool) -> jax.Array:
    """Normalizes observations by the running statistics.

    Args:
        norm: the statistics.
        obs: observations, (..., dim).
        enabled: False returns ``obs`` unchanged (a static switch: no trace of the statistics).

    Returns:
        ``(obs - mean) / sqrt(var + EPS)``, clipped to [-CLIP, CLIP].
    """
    if not enabled:
        return obs
    return jnp.clip((obs - norm.mean) / jnp.sqrt(norm.var + EPS), -CLIP, CLIP)

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
    return Normalizer(jnp.zeros((dim,)), jnp.ones((dim,)), jnp.zeros(()))


def update(norm: Normalizer, batch: jax.Array) -> Normalizer:
    """Adds a batch (n, dim) of observations to the running statistics."""
    n = batch.shape[0]
    b_mean, b_var = jnp.mean(batch, 0), jnp.var(batch, 0)
    total = norm.count + n
    delta = b_mean - norm.mean
    mean = norm.mean + delta * n / total
    m2 = norm.var * norm.count + b_var * n + delta**2 * norm.count * n / total
    return Normalizer(mean, m2 / total, total)


def scale_reward(return_stats: Normalizer | None, reward: jax.Array) -> jax.Array:
    """``reward / sqrt(var + EPS)`` with var the running variance of the discounted return
    (``SACConfig.normalize_reward``); unchanged when ``return_stats`` is None (off)."""
    if return_stats is None:
        return reward
    return reward / jnp.sqrt(return_stats.var[0] + EPS)


def normalize(norm: Normalizer, obs: jax.Array, enabled: bool) -> jax.Array:
    """(obs - mean) / std, clipped to [-10, 10]; identity when ``enabled`` is False."""
    if not enabled:
        return obs
    return jnp.clip((obs - norm.mean) / jnp.sqrt(norm.var + EPS), -CLIP, CLIP)

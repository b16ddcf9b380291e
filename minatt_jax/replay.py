"""A fixed-capacity replay buffer as a pytree (ring buffer; growth never changes shapes)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Transitions:
    """A batch of transitions (leading axis = transitions)."""

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array
    terminal: jax.Array  # 1.0 where the episode ended by termination (not by time limit)


@struct.dataclass
class ReplayBuffer:
    """Ring buffer of ``capacity`` transitions; ``size`` counts the valid ones."""

    data: Transitions
    position: jax.Array
    size: jax.Array

    @property
    def capacity(self) -> int:
        return int(self.data.reward.shape[0])


def init_buffer(capacity: int, obs_dim: int, act_dim: int) -> ReplayBuffer:
    """An empty buffer."""
    data = Transitions(
        obs=jnp.zeros((capacity, obs_dim), jnp.float32),
        action=jnp.zeros((capacity, act_dim), jnp.float32),
        reward=jnp.zeros((capacity,), jnp.float32),
        next_obs=jnp.zeros((capacity, obs_dim), jnp.float32),
        terminal=jnp.zeros((capacity,), jnp.float32),
    )
    zero = jnp.zeros((), jnp.int32)
    return ReplayBuffer(data, zero, zero)


def insert(buffer: ReplayBuffer, batch: Transitions) -> ReplayBuffer:
    """Appends a batch (overwriting the oldest transitions once full)."""
    n = batch.reward.shape[0]
    idx = (buffer.position + jnp.arange(n)) % buffer.capacity
    data = jax.tree.map(lambda store, new: store.at[idx].set(new), buffer.data, batch)
    return ReplayBuffer(
        data=data,
        position=(buffer.position + n) % buffer.capacity,
        size=jnp.minimum(buffer.size + n, buffer.capacity),
    )


def sample(buffer: ReplayBuffer, key: jax.Array, batch_size: int) -> Transitions:
    """``batch_size`` transitions drawn uniformly (with replacement) from the valid ones."""
    idx = jax.random.randint(key, (batch_size,), 0, jnp.maximum(buffer.size, 1))
    return jax.tree.map(lambda x: x[idx], buffer.data)

"""DreamerV3's sequence replay: one ring of steps per environment, and windows of collected
episodes (meta-test adaptation)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from minatt_jax import acting
from minatt_jax.dreamer.agent import Batch


@struct.dataclass
class SequenceReplay:
    """One ring of steps per environment (envs, capacity, ...); all rings advance together."""

    obs: jax.Array
    prev_action: jax.Array
    reward: jax.Array
    is_first: jax.Array
    cont: jax.Array
    position: jax.Array  # next slot to write (shared by the rings)
    size: jax.Array  # filled slots per ring

    @classmethod
    def create(cls, num_envs: int, capacity: int, obs_size: int, action_size: int):
        z = lambda *shape: jnp.zeros((num_envs, capacity, *shape), jnp.float32)  # noqa: E731
        zero = jnp.zeros((), jnp.int32)
        return cls(z(obs_size), z(action_size), z(), z(), z(), zero, zero)

    def add(self, step: Batch) -> SequenceReplay:
        """Writes one step of every environment (arrays (envs, ...))."""
        i = self.position
        put = lambda buf, x: buf.at[:, i].set(x)  # noqa: E731
        capacity = self.obs.shape[1]
        return self.replace(
            obs=put(self.obs, step.obs), prev_action=put(self.prev_action, step.prev_action),
            reward=put(self.reward, step.reward), is_first=put(self.is_first, step.is_first),
            cont=put(self.cont, step.cont), position=(i + 1) % capacity,
            size=jnp.minimum(self.size + 1, capacity),
        )  # fmt: skip

    def sample(self, key: jax.Array, batch_size: int, length: int) -> Batch:
        """``batch_size`` sequences of ``length`` consecutive steps, uniform over environments
        and start positions (in write order; a full ring's oldest step follows ``position``)."""
        k_env, k_start = jax.random.split(key)
        num_envs, capacity = self.obs.shape[:2]
        env = jax.random.randint(k_env, (batch_size,), 0, num_envs)
        start = jax.random.randint(k_start, (batch_size,), 0, self.size - length + 1)
        oldest = jnp.where(self.size < capacity, 0, self.position)
        index = (oldest + start[:, None] + jnp.arange(length)) % capacity
        return self._windows(env, index)

    def sample_starts(self, key: jax.Array, batch_size: int, length: int) -> Batch:
        """``batch_size`` sequences of ``length`` steps that each begin where an episode begins
        (``is_first``; MAMBA's whole meta-episodes), uniform over the environments' stored
        beginnings with ``length`` steps after them. Where none is stored yet (the warm-up
        covers one) the oldest slot stands in."""
        num_envs, capacity = self.obs.shape[:2]
        oldest = jnp.where(self.size < capacity, 0, self.position)
        order = jnp.arange(capacity)
        slots = (oldest + order) % capacity
        fits = (order <= self.size - length) & (self.is_first[:, slots] > 0)  # (envs, capacity)
        fits = fits.at[0, 0].set(fits[0, 0] | ~jnp.any(fits))
        cumulative = jnp.cumsum(fits.reshape(-1).astype(jnp.int32))
        pick = jax.random.randint(key, (batch_size,), 0, cumulative[-1])
        flat = jnp.searchsorted(cumulative, pick, side="right")
        env, start = flat // capacity, flat % capacity
        index = (oldest + start[:, None] + jnp.arange(length)) % capacity
        return self._windows(env, index)

    def _windows(self, env: jax.Array, index: jax.Array) -> Batch:
        take = lambda buf: buf[env[:, None], index]  # noqa: E731
        return Batch(take(self.obs), take(self.prev_action), take(self.reward),
                     take(self.is_first), take(self.cont))  # fmt: skip


def episode_sequences(traj: acting.Trajectory) -> tuple[Batch, jax.Array]:
    """Episodes (episodes, T, ...) from ``acting.unroll`` as replay steps in the replay's
    convention (obs_t, the action before it, the reward on arriving at it, is_first, 1 -
    terminal on arriving), with each episode's alive length."""
    zeros = jnp.zeros_like(traj.reward[:, :1])
    shift = lambda x, first: jnp.concatenate([first, x[:, :-1]], 1)  # noqa: E731
    batch = Batch(
        obs=traj.obs, prev_action=shift(traj.action, jnp.zeros_like(traj.action[:, :1])),
        reward=shift(traj.reward, zeros), is_first=jnp.zeros_like(traj.reward).at[:, 0].set(1.0),
        cont=shift(1.0 - traj.done, zeros + 1),
    )  # fmt: skip
    return batch, jnp.sum(traj.alive, -1).astype(jnp.int32)


def sample_episode_sequences(
    episodes: Batch, lengths: jax.Array, key: jax.Array, batch_size: int, length: int
) -> Batch:
    """``batch_size`` windows of ``length`` steps from the episodes' alive prefixes, uniform
    over episodes and start positions (an episode shorter than ``length`` gives its first
    ``length`` steps, those after its end included)."""
    k_episode, k_start = jax.random.split(key)
    which = jax.random.randint(k_episode, (batch_size,), 0, lengths.shape[0])
    last_start = jnp.maximum(lengths[which] - length, 0)
    start = jax.random.randint(k_start, (batch_size,), 0, last_start + 1)
    index = start[:, None] + jnp.arange(length)
    return jax.tree.map(lambda x: x[which[:, None], index], episodes)

"""Replay buffers as pytrees and everything done to them: insert, masked insert, sample, mix.

* a flat buffer (``ReplayBuffer``): one ring buffer of real transitions (fixed shapes);
* per-slot buffers: ``slots`` ring buffers stacked on a leading axis (one per model-ensemble elite,
  the MB-MPO tasks), filled by ``insert_slots`` and read one slot at a time (``sample_slot``) or
  all together (``sample_all_slots``);
* ``sample_mixed``: a batch of which ``real_count`` rows come from the real buffer and the rest
  from the model buffers (MBPO's 5% real / 95% model agent batches).
"""

from __future__ import annotations

from typing import Any

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
    """An empty buffer, its arrays allocated once at full size (a fixed shape for ``jit``).

    Args:
        capacity: transitions it holds; the oldest are overwritten once full.
        obs_dim: observation size.
        act_dim: action size.

    Returns:
        A ``ReplayBuffer`` with ``size`` and ``position`` 0.
    """
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
    """Appends a batch, overwriting the oldest transitions once full (a ring).

    Args:
        buffer: the buffer.
        batch: ``Transitions`` with a leading batch axis (n <= capacity).

    Returns:
        The buffer with the batch written and ``position``/``size`` advanced.
    """
    n = batch.reward.shape[0]
    idx = (buffer.position + jnp.arange(n)) % buffer.capacity
    data = jax.tree.map(lambda store, new: store.at[idx].set(new), buffer.data, batch)
    return ReplayBuffer(
        data=data,
        position=(buffer.position + n) % buffer.capacity,
        size=jnp.minimum(buffer.size + n, buffer.capacity),
    )


def sample(buffer: ReplayBuffer, key: jax.Array, batch_size: int) -> Transitions:
    """Draws transitions uniformly, with replacement, from those written.

    Args:
        buffer: the buffer (an empty one returns its zero rows).
        key: the random key.
        batch_size: how many to draw (static).

    Returns:
        ``Transitions`` with a leading axis of ``batch_size``.
    """
    idx = jax.random.randint(key, (batch_size,), 0, jnp.maximum(buffer.size, 1))
    return jax.tree.map(lambda x: x[idx], buffer.data)


def select_rows(mask: jax.Array, where_true: Any, where_false: Any) -> Any:
    """Row by row (the leading axes of ``mask``), the leaves of ``where_true`` where ``mask`` is
    set and those of ``where_false`` elsewhere: one masked choice for buffer rows, environments
    and ensemble members alike."""
    return jax.tree.map(
        lambda a, b: jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - mask.ndim)), a, b),
        where_true,
        where_false,
    )


def insert_masked(buffer: ReplayBuffer, batch: Transitions, mask: jax.Array) -> ReplayBuffer:
    """Appends the rows of ``batch`` (leading axis) where ``mask`` is 1, in order.

    Fixed shapes: every row is written, but rows past the kept count write back what the buffer
    already holds there, so nothing valid is lost. Needs ``len(mask) <= capacity``.
    """
    k = mask.shape[0]
    if k > buffer.capacity:
        raise ValueError(f"cannot insert {k} rows into a buffer of capacity {buffer.capacity}")
    keep = mask > 0
    order = jnp.argsort(~keep, stable=True)  # kept rows first, in their original order
    count = jnp.sum(keep.astype(jnp.int32))
    rows = jax.tree.map(lambda x: x[order], batch)
    idx = (buffer.position + jnp.arange(k)) % buffer.capacity
    use = jnp.arange(k) < count
    written = select_rows(use, rows, jax.tree.map(lambda store: store[idx], buffer.data))
    data = jax.tree.map(lambda store, new: store.at[idx].set(new), buffer.data, written)
    return ReplayBuffer(
        data=data,
        position=(buffer.position + count) % buffer.capacity,
        size=jnp.minimum(buffer.size + count, buffer.capacity),
    )


def insert_slots(buffers: ReplayBuffer, rollouts: Transitions, alive: jax.Array) -> ReplayBuffer:
    """Inserts each slot's alive transitions, (slots, steps, n, ...), into that slot's buffer
    (buffers stacked by slot): imagined rollouts keep each trajectory on its own slot."""

    def one(buf, roll, al):
        flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), roll)
        return insert_masked(buf, flat, al.reshape(-1))

    return jax.vmap(one)(buffers, rollouts, alive)


def init_slot_buffers(slots: int, capacity: int, obs_dim: int, act_dim: int) -> ReplayBuffer:
    """``slots`` empty buffers stacked on a leading axis."""
    one = init_buffer(capacity, obs_dim, act_dim)
    return jax.tree.map(lambda x: jnp.broadcast_to(x, (slots, *x.shape)).copy(), one)


def sample_slot(buffers: ReplayBuffer, slot: jax.Array, key: jax.Array, n: int) -> Transitions:
    """``n`` transitions drawn uniformly from one slot's valid rows."""
    size = jnp.maximum(buffers.size[slot], 1)
    idx = jax.random.randint(key, (n,), 0, size)
    return jax.tree.map(lambda x: x[slot, idx], buffers.data)


def sample_all_slots(buffers: ReplayBuffer, key: jax.Array, n: int) -> Transitions:
    """``n`` transitions drawn uniformly from the valid rows of all slots together."""
    sizes = buffers.size
    total = jnp.maximum(jnp.sum(sizes), 1)
    flat = jax.random.randint(key, (n,), 0, total)
    ends = jnp.cumsum(sizes)
    slot = jnp.searchsorted(ends, flat, side="right")
    slot = jnp.minimum(slot, sizes.shape[0] - 1)
    idx = flat - (ends[slot] - sizes[slot])
    return jax.tree.map(lambda x: x[slot, idx], buffers.data)


def concat(first: Transitions, second: Transitions) -> Transitions:
    """Two batches as one (rows of ``first``, then rows of ``second``)."""
    return jax.tree.map(lambda a, b: jnp.concatenate([a, b], 0), first, second)


def sample_mixed(
    model: ReplayBuffer,
    real: ReplayBuffer,
    key: jax.Array,
    batch_size: int,
    real_count: int,
    slot: jax.Array | None = None,
) -> Transitions:
    """``batch_size - real_count`` rows from the model buffers (all slots, or one ``slot``), then
    ``real_count`` rows from the real buffer."""
    k_model, k_real = jax.random.split(key)
    n_model = batch_size - real_count
    if slot is None:
        model_part = sample_all_slots(model, k_model, n_model)
    else:
        model_part = sample_slot(model, slot, k_model, n_model)
    return concat(model_part, sample(real, k_real, real_count))

"""Imagined rollouts in a learned dynamics ensemble and the model buffer they fill.

Shapes are fixed: ``start_obs`` is (slots, n, obs_dim) and a rollout writes (slots, max_len, n)
transitions with an ``alive`` mask, so a changing rollout length or early terminations never
change a shape. The loop runs ``length`` steps (a traced value: the rollout-length schedule costs
only the steps it uses). Slot g's trajectories stay on one member (``members[g]``, an elite) for
their whole length, as MB-MPO keeps each task's data on one model.

Guards against an exploited model: predicted observations are clipped to ``[-obs_clip, obs_clip]``,
and a non-finite prediction ends its trajectory without being stored.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from minatt_jax import replay
from minatt_jax.dynamics_ensemble import Ensemble, EnsembleState, member
from minatt_jax.replay import ReplayBuffer, Transitions

# (actor_params, obs (n, obs_dim), key) -> actions (n, act_dim)
PolicyFn = Callable[[Any, jax.Array, jax.Array], jax.Array]


def imagine(
    ensemble: Ensemble,
    ens_state: EnsembleState,
    members: jax.Array,
    policy: PolicyFn,
    actor_params: Any,
    termination: Callable[[jax.Array], jax.Array],
    start_obs: jax.Array,
    length: jax.Array,
    max_len: int,
    key: jax.Array,
    obs_clip: float = 100.0,
) -> tuple[Transitions, jax.Array]:
    """Rolls out ``policy`` in the model; returns transitions (slots, max_len, n) and ``alive``.

    ``alive[g, t, i]`` is 1.0 where step t of trajectory i of slot g was taken (the trajectory had
    not terminated before t, t < length, and the prediction was finite).
    """
    slots, n, obs_dim = start_obs.shape
    params = member(ens_state.params, members)  # (slots, ...)
    act_dim = policy(actor_params, start_obs[0, :1], key).shape[-1]

    def slot_step(p, obs, action, k):
        return ensemble.step(p, ens_state.norm, obs, action, k)

    def body(t, carry):
        obs, alive, out, out_alive, key = carry
        key, k_act, k_model = jax.random.split(key, 3)
        act_keys = jax.random.split(k_act, slots)
        action = jax.vmap(policy, in_axes=(None, 0, 0))(actor_params, obs, act_keys)
        next_obs, reward = jax.vmap(slot_step)(
            params, obs, action, jax.random.split(k_model, slots)
        )
        finite = jnp.all(jnp.isfinite(next_obs), axis=-1) & jnp.isfinite(reward)
        next_obs = jnp.where(finite[..., None], jnp.clip(next_obs, -obs_clip, obs_clip), obs)
        reward = jnp.where(finite, reward, 0.0)
        terminal = termination(next_obs)
        step_alive = alive * finite.astype(jnp.float32)
        new = Transitions(
            obs=obs, action=action, reward=reward, next_obs=next_obs, terminal=terminal
        )
        out = jax.tree.map(lambda buf, v: buf.at[:, t].set(v), out, new)
        out_alive = out_alive.at[:, t].set(step_alive)
        alive = step_alive * (1.0 - terminal)
        return next_obs, alive, out, out_alive, key

    out = Transitions(
        obs=jnp.zeros((slots, max_len, n, obs_dim)),
        action=jnp.zeros((slots, max_len, n, act_dim)),
        reward=jnp.zeros((slots, max_len, n)),
        next_obs=jnp.zeros((slots, max_len, n, obs_dim)),
        terminal=jnp.zeros((slots, max_len, n)),
    )
    carry = (start_obs, jnp.ones((slots, n)), out, jnp.zeros((slots, max_len, n)), key)
    length = jnp.clip(length, 0, max_len)
    _, _, out, out_alive, _ = jax.lax.fori_loop(0, length, body, carry)
    return out, out_alive


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
    data = jax.tree.map(
        lambda store, new: store.at[idx].set(
            jnp.where(use.reshape((-1,) + (1,) * (new.ndim - 1)), new, store[idx])
        ),
        buffer.data,
        rows,
    )
    return ReplayBuffer(
        data=data,
        position=(buffer.position + count) % buffer.capacity,
        size=jnp.minimum(buffer.size + count, buffer.capacity),
    )


def insert_rollouts(buffers: ReplayBuffer, rollouts: Transitions, alive: jax.Array) -> ReplayBuffer:
    """Inserts each slot's alive transitions into that slot's buffer (buffers stacked by slot)."""

    def one(buf, roll, al):
        flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), roll)
        return insert_masked(buf, flat, al.reshape(-1))

    return jax.vmap(one)(buffers, rollouts, alive)


def init_slot_buffers(slots: int, capacity: int, obs_dim: int, act_dim: int) -> ReplayBuffer:
    """``slots`` empty buffers stacked on a leading axis."""
    one = replay.init_buffer(capacity, obs_dim, act_dim)
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

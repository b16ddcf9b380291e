"""Imagined rollouts in a learned dynamics ensemble (the model used as an environment).

The imagined transitions go into per-slot buffers (``replay.insert_slots``). Shapes are fixed:
``start_obs`` is (slots, n, obs_dim) and a rollout writes (slots, max_len, n) transitions with
an ``alive`` mask, so a changing rollout length or early terminations never change a shape. The
loop runs ``length`` steps (a traced value: the rollout-length schedule costs only the steps it
uses). Slot g's trajectories stay on one member (``members[g]``, an elite) for
their whole length, as MB-MPO keeps each task's data on one model.

Guards against an exploited model: predicted observations are clipped to ``[-obs_clip, obs_clip]``,
and a non-finite prediction ends its trajectory without being stored.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from minatt_jax.dynamics_ensemble import Ensemble, EnsembleState, member
from minatt_jax.replay import Transitions

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

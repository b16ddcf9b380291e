"""Fixed-length environment rollouts as one scanned, vmappable function.

Episodes that terminate early keep stepping (fixed shapes under ``lax.scan``) but an alive mask
stops their reward from counting, as the first ``done`` ends a Gym episode.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from minatt_jax.envs import LocomotionEnv, Task

# A policy maps (key, observation) to an action in [-1, 1]^act_dim.
Policy = Callable[[jax.Array, jax.Array], jax.Array]


@struct.dataclass
class RolloutResult:
    """What one rollout returns (per environment when vmapped)."""

    episode_return: jax.Array  # sum of rewards until the first done
    length: jax.Array  # steps until the first done (or the rollout length)
    forward_reward: jax.Array  # sum of the forward term until the first done
    ctrl_reward: jax.Array  # sum of the (negative) control-cost term until the first done


def zero_policy(act_dim: int) -> Policy:
    """Always commands zero torque."""
    return lambda key, obs: jnp.zeros((act_dim,), jnp.float32)


def random_policy(act_dim: int) -> Policy:
    """Uniform random actions in [-1, 1]."""
    return lambda key, obs: jax.random.uniform(key, (act_dim,), minval=-1.0, maxval=1.0)


def make_rollout(
    env: LocomotionEnv, policy: Policy, steps: int
) -> Callable[[jax.Array, Task], RolloutResult]:
    """A function ``(key, task) -> RolloutResult`` running ``steps`` env steps; jit/vmap it."""

    def rollout(key: jax.Array, task: Task) -> RolloutResult:
        key_reset, key_policy = jax.random.split(key)
        state = env.reset(key_reset, task)

        def body(carry, key_t):
            state, alive, ret, fwd, ctrl, length = carry
            action = policy(key_t, state.obs)
            state = env.step(state, action)
            ret = ret + alive * state.reward
            fwd = fwd + alive * state.metrics["reward_forward"]
            ctrl = ctrl + alive * state.metrics["reward_ctrl"]
            length = length + alive
            alive = alive * (1.0 - state.done)
            return (state, alive, ret, fwd, ctrl, length), None

        zero = jnp.zeros((), jnp.float32)
        carry = (state, jnp.ones((), jnp.float32), zero, zero, zero, zero)
        keys = jax.random.split(key_policy, steps)
        (_, _, ret, fwd, ctrl, length), _ = jax.lax.scan(body, carry, keys)
        return RolloutResult(ret, length, fwd, ctrl)

    return rollout

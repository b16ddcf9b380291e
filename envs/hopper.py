"""Hopper (Gym v3): 11 observations, 3 actions, frame skip 4 (dt 0.008 s)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco import mjx

from minatt_jax.envs.base import LocomotionEnv, RewardWeights


class Hopper(LocomotionEnv):
    """Gym v3 Hopper: obs = qpos[1:] and clip(qvel, -10, 10); reward = forward velocity + 1
    - 1e-3 |a|^2; ends when z <= 0.7, |angle| >= 0.2 or any of state[2:] leaves (-100, 100)."""

    name = "hopper"
    frame_skip = 4
    reset_noise_scale = 5e-3
    weights = RewardWeights(forward=1.0, ctrl_cost=1e-3, healthy=1.0)
    obs_names = (
        "rootz", "rooty", "thigh", "leg", "foot",
        "vel_rootx", "vel_rootz", "vel_rooty", "vel_thigh", "vel_leg", "vel_foot",
    )  # fmt: skip

    def observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos[1:], jnp.clip(data.qvel, -10.0, 10.0)])

    def is_healthy(self, data: mjx.Data) -> jax.Array:
        state = jnp.concatenate([data.qpos, data.qvel])[2:]
        z, angle = data.qpos[1], data.qpos[2]
        ok = jnp.all(jnp.abs(state) < 100.0) & (z > 0.7) & (jnp.abs(angle) < 0.2)
        return ok.astype(jnp.float32)

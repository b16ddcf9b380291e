"""Walker2d (Gym v3): 17 observations, 6 actions, frame skip 4 (dt 0.008 s)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco import mjx

from minatt_jax.envs.base import LocomotionEnv, RewardWeights


class Walker2d(LocomotionEnv):
    """Gym v3 Walker2d: obs = qpos[1:] and clip(qvel, -10, 10); reward = forward velocity + 1
    - 1e-3 |a|^2; ends unless 0.8 < z < 2 and -1 < angle < 1."""

    name = "walker2d"
    asset_file = "walker2d.xml"  # the v2-v4 model (left foot friction 1.9), not walker2d_v5.xml
    frame_skip = 4
    reset_noise_scale = 5e-3
    weights = RewardWeights(forward=1.0, ctrl_cost=1e-3, healthy=1.0)
    reset_runs_forward = False  # observes qpos and qvel alone
    obs_names = (
        "rootz", "rooty", "thigh", "leg", "foot", "thigh_left", "leg_left", "foot_left",
        "vel_rootx", "vel_rootz", "vel_rooty", "vel_thigh", "vel_leg", "vel_foot",
        "vel_thigh_left", "vel_leg_left", "vel_foot_left",
    )  # fmt: skip
    projections = (("rootz", "rooty"), ("rooty", "vel_rooty"), ("vel_rootx", "rooty"))
    failure_grid_ranges = ((-1.0, 3.0), (-3.0, 3.0))
    crippled_joints = (("thigh_joint",),)

    @staticmethod
    def terminated(obs: jax.Array) -> jax.Array:
        """Done unless 0.8 < z < 2 and -1 < angle < 1."""
        z, angle = obs[..., 0], obs[..., 1]
        ok = (z > 0.8) & (z < 2.0) & (angle > -1.0) & (angle < 1.0)
        return 1.0 - ok.astype(jnp.float32)

    def observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos[1:], jnp.clip(data.qvel, -10.0, 10.0)])

    def is_healthy(self, data: mjx.Data) -> jax.Array:
        z, angle = data.qpos[1], data.qpos[2]
        ok = (z > 0.8) & (z < 2.0) & (angle > -1.0) & (angle < 1.0)
        return ok.astype(jnp.float32)

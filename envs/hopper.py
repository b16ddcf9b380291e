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
    asset_file = "hopper.xml"
    frame_skip = 4
    reset_noise_scale = 5e-3
    weights = RewardWeights(forward=1.0, ctrl_cost=1e-3, healthy=1.0)
    reset_runs_forward = False  # observes qpos and qvel alone
    obs_names = (
        "rootz", "rooty", "thigh", "leg", "foot",
        "vel_rootx", "vel_rootz", "vel_rooty", "vel_thigh", "vel_leg", "vel_foot",
    )  # fmt: skip
    projections = (("rooty", "rootz"), ("rooty", "vel_rooty"), ("vel_rootx", "rooty"))
    # The hopper ends at |pitch| >= 0.2 rad, so pitch rates of 4 rad/s end any episode within a
    # few steps whatever the policy does: a narrower range than the cheetah's.
    failure_grid_ranges = ((-1.0, 2.0), (-1.5, 1.5))
    crippled_joints = (("thigh_joint",),)

    @staticmethod
    def terminated(obs: jax.Array) -> jax.Array:
        """Done unless z > 0.7, |angle| < 0.2 and |obs[1:]| < 100 elementwise.

        The official MBPO function writes ``np.abs(next_obs[:, 1:] < 100)`` (the parenthesis
        closes after the comparison, so large negative values never terminate); here the absolute
        value is taken first. Velocities are clipped at 10 in the observation, so the |.| < 100
        test acts on the angles only (``is_healthy`` also sees the unclipped velocities).
        """
        z, angle = obs[..., 0], obs[..., 1]
        ok = jnp.all(jnp.abs(obs[..., 1:]) < 100.0, axis=-1) & (z > 0.7) & (jnp.abs(angle) < 0.2)
        return 1.0 - ok.astype(jnp.float32)

    def observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos[1:], jnp.clip(data.qvel, -10.0, 10.0)])

    def is_healthy(self, data: mjx.Data) -> jax.Array:
        state = jnp.concatenate([data.qpos, data.qvel])[2:]
        z, angle = data.qpos[1], data.qpos[2]
        ok = jnp.all(jnp.abs(state) < 100.0) & (z > 0.7) & (jnp.abs(angle) < 0.2)
        return ok.astype(jnp.float32)

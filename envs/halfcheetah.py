"""HalfCheetah (Gym v3): 17 observations, 6 actions, frame skip 5 (dt 0.05 s), no termination."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco import mjx

from minatt_jax.envs.base import LocomotionEnv, RewardWeights


class HalfCheetah(LocomotionEnv):
    """Gym v3 HalfCheetah: obs = qpos[1:] and qvel; reward = forward velocity - 0.1 |a|^2."""

    name = "halfcheetah"
    asset_file = "half_cheetah.xml"
    frame_skip = 5
    reset_noise_scale = 0.1
    weights = RewardWeights(forward=1.0, ctrl_cost=0.1, healthy=0.0)
    reset_runs_forward = False  # observes qpos and qvel alone
    terminates = False
    obs_names = (
        "rootz", "rooty", "bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot",
        "vel_rootx", "vel_rootz", "vel_rooty", "vel_bthigh", "vel_bshin", "vel_bfoot",
        "vel_fthigh", "vel_fshin", "vel_ffoot",
    )  # fmt: skip
    projections = (("vel_rootx", "rootz"), ("vel_rootx", "vel_rootz"), ("vel_rootx", "vel_rooty"))
    failure_grid_ranges = ((-1.0, 4.0), (-4.0, 4.0))
    crippled_joints = (("bthigh",), ("bshin",), ("bfoot",), ("bthigh", "bshin", "bfoot"))
    # The paper's failure criterion: torso z (relative to its initial height) below -0.42 or
    # |pitch| above 1.1 rad.
    failure_z_min = -0.42
    failure_pitch_max = 1.1

    def failed(self, obs: jax.Array) -> jax.Array:
        """The paper's criterion on obs[0] (rootz) and obs[1] (rooty)."""
        bad = (obs[..., 0] < self.failure_z_min) | (jnp.abs(obs[..., 1]) > self.failure_pitch_max)
        return bad.astype(jnp.float32)

    def reset_noise(self, key_q: jax.Array, key_v: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Gym v3: uniform(-0.1, 0.1) on qpos, 0.1 * standard normal on qvel."""
        c = self.reset_noise_scale
        qpos = self._init_qpos + jax.random.uniform(
            key_q, self._init_qpos.shape, minval=-c, maxval=c
        )
        qvel = self._init_qvel + c * jax.random.normal(key_v, self._init_qvel.shape)
        return qpos, qvel

    def observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos[1:], data.qvel])

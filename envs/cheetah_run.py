"""The DeepMind Control Suite's cheetah-run on MJX (the paper's DreamerV3 benchmark).

DMC's own model (``suite/cheetah.xml`` of the installed ``dm-control`` package: 14 kg, dt 0.01 s,
joint springs, self-collisions) and task: each leg joint starts uniform in its range and the body
settles for 200 physics steps with zero control; observation = qpos[1:] (8) and qvel (9), 17 like
Gym's HalfCheetah, whose names, crippled legs and failure criterion it shares; reward = DMC's
``tolerance(speed, bounds=(10, inf), margin=10, sigmoid="linear")`` = clip(speed / 10, 0, 1), with
speed the x-velocity of the torso subtree's centre of mass (DMC's ``subtreelinvel`` sensor, read
after the step); 1000-step episodes (``max_episode_steps``), no termination, action repeat 1.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco import mjx

from minatt_jax.envs.base import RewardWeights
from minatt_jax.envs.halfcheetah import HalfCheetah

RUN_SPEED = 10.0  # DMC's _RUN_SPEED: at and above it the reward is 1


def com_velocity_x(model: mjx.Model, data: mjx.Data) -> jax.Array:
    """Forward velocity of the centre of mass of every body: d/dt of the mass-weighted body COM
    x positions along qvel (a forward-mode derivative of the kinematics; nq = nv here)."""
    mass = model.body_mass

    def com_x(qpos: jax.Array) -> jax.Array:
        xipos = mjx.kinematics(model, data.replace(qpos=qpos)).xipos
        return jnp.sum(mass * xipos[:, 0]) / jnp.sum(mass)

    return jax.jvp(com_x, (data.qpos,), (data.qvel,))[1]


def run_reward(speed: jax.Array) -> jax.Array:
    """DMC's linear tolerance with bounds (RUN_SPEED, inf), margin RUN_SPEED, value 0 at the
    margin: 0 standing still, rising linearly to 1 at RUN_SPEED."""
    return jnp.clip(speed / RUN_SPEED, 0.0, 1.0)


class CheetahRun(HalfCheetah):
    """DMC cheetah-run: reward in [0, 1] per step, returns at most 1000."""

    name = "cheetah_run"
    asset_file = "cheetah.xml"
    asset_package = "dm_control"
    frame_skip = 1
    settle_steps = 200
    # DMC's own solver settings (Euler, Newton with 100 iterations, self-collisions): the
    # published DreamerV3 curves were measured on them, and DreamerV3's cost is in its updates.
    default_physics = "gym"
    weights = RewardWeights(forward=1.0, ctrl_cost=0.0, healthy=0.0)
    terminates = False
    # DMC's cheetah stands with its torso at z = 0.7 m, as Gym's does.
    failure_grid_ranges = ((-1.0, 10.0), (-4.0, 4.0))

    def reset_noise(self, key_q: jax.Array, key_v: jax.Array) -> tuple[jax.Array, jax.Array]:
        """DMC: every limited joint (the legs) uniform in its range; velocities zero."""
        del key_v
        limited = jnp.asarray(self.mj_model.jnt_limited == 1)
        low, high = (jnp.asarray(self.mj_model.jnt_range[:, i], jnp.float32) for i in (0, 1))
        uniform = jax.random.uniform(key_q, low.shape, minval=low, maxval=high)
        return jnp.where(limited, uniform, self._init_qpos), self._init_qvel

    def reward_terms(
        self, model: mjx.Model, before: mjx.Data, after: mjx.Data, action: jax.Array
    ) -> dict[str, jax.Array]:
        """The run reward of the state after the step, and its speed (the ``x_velocity``)."""
        del before, action
        speed = com_velocity_x(model, after)
        return {"forward": run_reward(speed), "ctrl": jnp.zeros(()), "speed": speed}

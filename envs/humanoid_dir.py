"""Humanoid-dir: the meta-RL benchmark MAMBA reports on (its Table S3 with MA): run in a
direction given by the task.

The definition follows the meta-RL code this benchmark comes from (PEARL's ``humanoid_dir``,
copied unchanged into VariBAD and into MAMBA's ``envs/mujoco/humanoid_dir.py``), on Gym's
Humanoid model and 376-dim observation:

* a task is a direction ``theta`` (``Task.target``, radians); the reward is
  ``1.25 * dot((cos theta, sin theta), d com_xy / dt) + 5 - 0.1 |ctrl|^2
  - min(5e-7 |cfrc_ext|^2, 10)``. The reference writes the velocity term as
  ``0.25 * dot(dir, d com_xy) / opt.timestep``: with 5 physics steps per env step that is
  1.25 times the velocity over the env step, Gym Humanoid's forward weight.
* the policy acts in [-1, 1] and ``ctrl = 0.4 * action`` (the model's control range), and the
  control cost reads ``ctrl``, as the reference rescales its actions;
* it ends unless 1 < z < 2; episodes are 200 steps in the reference (``max_episode_steps``).

Task sets: ``train`` holds 8 directions spread over the upper half plane [0, pi) (the reference
draws from the whole circle; a half keeps directions for testing out of distribution), ``ood``
5 directions in the lower half (pi, 2 pi), ``nominal`` the direction 0 (the x axis). The
perturbation sets (mass, crippled, slope) keep the direction 0.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from minatt_jax.envs.humanoid import HumanoidFull
from minatt_jax.envs.tasks import Task

TRAIN_DIRECTIONS = tuple(np.pi * k / 8 for k in range(8))  # [0, pi)
OOD_DIRECTIONS = tuple(np.pi + np.pi * k / 6 for k in range(1, 6))  # (pi, 2 pi)


class HumanoidDir(HumanoidFull):
    """Humanoid (376-dim observation) running in the task's direction (see the module)."""

    name = "humanoid_dir"
    default_target = 0.0
    action_scale = 0.4
    target_sets = {"nominal": (0.0,), "train": TRAIN_DIRECTIONS, "ood": OOD_DIRECTIONS}
    target_label = "direction {:.4f} rad"

    def task_reward_terms(self, model: mjx.Model, before: mjx.Data, after: mjx.Data,
                          ctrl: jax.Array, task: Task) -> dict[str, jax.Array]:  # fmt: skip
        """The centre of mass's velocity along the task's direction, ``ctrl``'s cost, the
        contact forces."""
        terms = self.reward_terms(model, before, after, ctrl)
        mass = model.body_mass

        def com_xy(data: mjx.Data) -> jax.Array:
            return jnp.sum(mass[:, None] * data.xipos[:, :2], 0) / jnp.sum(mass)

        direction = jnp.stack([jnp.cos(task.target), jnp.sin(task.target)])
        velocity = (com_xy(after) - com_xy(before)) / self.dt
        return {**terms, "forward": jnp.dot(direction, velocity), "speed": velocity[0]}

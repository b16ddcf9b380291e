"""Point robot navigation to a goal on a half circle: the meta-RL task MAMBA learns in 2M steps
(its "halfcircle" setting), small enough to learn on a CPU.

After the reference (MAMBA's ``envs/point_robot.py``, from VariBAD's): a point starts at the
origin of the plane and moves by ``0.1 * clip(action, -1, 1)`` each step; a task is a goal on
the unit circle at angle ``Task.target``; the reward is sparse: ``1 - |x - goal|`` within 0.2
of the goal, 0 elsewhere (the reference's ``goal_radius`` 2 / 10). Episodes never end early:
100 steps in the reference, 3 of them in a meta-episode (``envs.meta_episode``).

Task sets: ``train`` holds 16 goals over the upper half circle [0, pi] (the reference draws them
uniformly there), ``ood`` 6 goals on the lower half (pi, 2 pi), ``nominal`` the goal at angle
pi / 2. The crippled set zeroes one axis's motion (``Task.actuator_scale``); mass, friction,
gravity and slope do not move a point that is stepped without physics, so tasks naming them and
the mass and slope sets are refused (``ignored_task_fields``).

``point_robot_dense`` (:class:`DensePointRobot`) is the same task with the dense reward of the
reference's ``PointEnv`` (the base of its sparse one): minus the distance to the goal at every
step. The goal is still unknown to the agent, so episode 1 of a meta-episode searches and the
later ones can go straight to it; the signal at every step makes it learnable in minutes on a CPU.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import State
from mujoco import mjx

from minatt_jax.envs.base import LocomotionEnv
from minatt_jax.envs.tasks import Task

STEP = 0.1  # position change per unit action
GOAL_RADIUS = 0.2
TRAIN_GOALS = tuple(np.pi * k / 15 for k in range(16))  # [0, pi]
OOD_GOALS = tuple(np.pi + np.pi * k / 7 for k in range(1, 7))  # (pi, 2 pi)


class PointRobot(LocomotionEnv):
    """A point stepped by its actions toward a goal given by the task (see the module)."""

    name = "point_robot"
    asset_file = "point_robot.xml"
    asset_package = "minatt_jax.envs"
    terminates = False
    reset_runs_forward = False
    default_target = float(np.pi / 2)
    target_sets = {"nominal": (float(np.pi / 2),), "train": TRAIN_GOALS, "ood": OOD_GOALS}
    target_label = "goal at {:.4f} rad"
    obs_names = ("x", "y")
    projections = (("x", "y"),)
    failure_grid_ranges = ((-0.5, 0.5), (-0.5, 0.5))
    failure_qvel_indices = (0, 1)
    crippled_joints = (("slide_x",), ("slide_y",))
    ignored_task_fields = ("mass", "friction", "gravity", "slope")  # no physics moves the point

    def observation(self, data: mjx.Data) -> jax.Array:
        return data.qpos

    @staticmethod
    def metric_names() -> tuple[str, ...]:
        return ("reward_goal", "distance", "x_position", "x_velocity")

    @staticmethod
    def reward(distance: jax.Array) -> jax.Array:
        """Sparse: 1 - distance within ``GOAL_RADIUS`` of the goal, 0 elsewhere."""
        return jnp.where(distance <= GOAL_RADIUS, 1.0 - distance, 0.0)

    @staticmethod
    def goal(task: Task) -> jax.Array:
        return jnp.stack([jnp.cos(task.target), jnp.sin(task.target)])

    def step(self, state: State, action: jax.Array) -> State:
        """One position step under the state's task (crippled axes do not move)."""
        task = state.info["task"]
        move = STEP * jnp.clip(action, -1.0, 1.0) * task.actuator_scale
        data = state.pipeline_state
        qpos = data.qpos + move
        data = data.replace(qpos=qpos, qvel=move / self.dt)
        distance = jnp.linalg.norm(qpos - self.goal(task))
        reward = self.reward(distance).astype(jnp.float32)
        metrics = {"reward_goal": reward, "distance": distance, "x_position": qpos[0],
                   "x_velocity": move[0] / self.dt}  # fmt: skip
        info = {**state.info, "steps": state.info["steps"] + 1}
        done = jnp.zeros((), jnp.float32)
        return state.replace(pipeline_state=data, obs=self.observation(data), reward=reward,
                             done=done, metrics=metrics, info=info)  # fmt: skip


class DensePointRobot(PointRobot):
    """The point robot with the dense reward: minus the distance to the goal."""

    name = "point_robot_dense"

    @staticmethod
    def reward(distance: jax.Array) -> jax.Array:
        return -distance

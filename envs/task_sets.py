"""Named task sets per environment: the meta-training family and the out-of-distribution sets.

Values and sources are tabled in ``docs/tasks.md``; the paper names the kinds of perturbation
(gravity and friction for training, body mass, a crippled leg and slopes for meta-testing) but
gives no values beyond mass x1.5, so the rest are ours.
"""

from __future__ import annotations

import numpy as np

from minatt_jax.envs.base import LocomotionEnv
from minatt_jax.envs.tasks import Task, stack_tasks

TASK_SET_NAMES = ("nominal", "train", "mass", "crippled", "slope")

TRAIN_GRAVITY_FRICTION = ((1.00, 1.00), (0.90, 0.90), (0.95, 1.10), (1.05, 0.90), (1.10, 1.10))
MASS_SCALES = (0.5, 0.75, 1.25, 1.5, 2.0)
SLOPES = (0.05, 0.10, -0.05, -0.10)  # radians; positive = uphill

# Crippled joints (actuators are found by the joint they drive), one tuple per task.
CRIPPLED_JOINTS: dict[str, tuple[tuple[str, ...], ...]] = {
    "halfcheetah": (("bthigh",), ("bshin",), ("bfoot",), ("bthigh", "bshin", "bfoot")),
    "hopper": (("thigh_joint",),),
    "walker2d": (("thigh_joint",),),
    "humanoid": (("right_hip_x", "right_hip_z", "right_hip_y", "right_knee"),),
}


def _actuator_scale(env: LocomotionEnv, joints: tuple[str, ...]) -> np.ndarray:
    """Actuator scale vector with 0 for the actuators driving ``joints``."""
    m = env.mj_model
    scale = [1.0] * m.nu
    for a in range(m.nu):
        if m.joint(int(m.actuator_trnid[a, 0])).name in joints:
            scale[a] = 0.0
    if scale.count(0.0) != len(joints):
        raise ValueError(f"{env.name}: could not find actuators for joints {joints}")
    return np.asarray(scale)


def task_list(env: LocomotionEnv, set_name: str) -> tuple[list[Task], list[str]]:
    """The tasks of ``set_name`` for ``env`` and a short label for each."""
    if set_name == "nominal":
        return [env.nominal_task()], ["nominal"]
    if set_name == "train":
        tasks = [
            env.make_task(gravity_scale=g, friction_scale=f) for g, f in TRAIN_GRAVITY_FRICTION
        ]
        return tasks, [f"gravity x{g:.2f}, friction x{f:.2f}" for g, f in TRAIN_GRAVITY_FRICTION]
    if set_name == "mass":
        tasks = [env.make_task(mass_scale=s) for s in MASS_SCALES]
        return tasks, [f"mass x{s}" for s in MASS_SCALES]
    if set_name == "crippled":
        joint_sets = CRIPPLED_JOINTS[env.name]
        tasks = [env.make_task(actuator_scale=_actuator_scale(env, j)) for j in joint_sets]
        return tasks, ["crippled " + "+".join(j) for j in joint_sets]
    if set_name == "slope":
        tasks = [env.make_task(slope=s) for s in SLOPES]
        labels = [f"{'uphill' if s > 0 else 'downhill'} {abs(s):.2f} rad" for s in SLOPES]
        return tasks, labels
    raise KeyError(set_name)


def task_set(env: LocomotionEnv, set_name: str) -> Task:
    """The tasks of ``set_name`` stacked along a leading axis."""
    return stack_tasks(task_list(env, set_name)[0])

"""MJX-backed locomotion environments with perturbation tasks as data.

Installed as ``minatt_jax.envs`` (the repository's top-level ``envs/`` folder), so the import name
cannot collide with other distributions. ``make(name)`` builds an environment; ``task_set(env,
set_name)`` returns a stacked :class:`Task` set for meta-training or meta-testing.
"""

from __future__ import annotations

import contextlib
import io

# mujoco.mjx prints a note to stdout when its optional Warp (GPU) backend is absent; the JAX
# backend this package uses needs no Warp, so the note is only noise in CLI output.
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: F401

from minatt_jax.envs.base import LocomotionEnv  # noqa: E402 - after the mjx note is silenced
from minatt_jax.envs.cheetah_run import CheetahRun
from minatt_jax.envs.halfcheetah import HalfCheetah
from minatt_jax.envs.hopper import Hopper
from minatt_jax.envs.humanoid import Humanoid, HumanoidFull
from minatt_jax.envs.humanoid_dir import HumanoidDir
from minatt_jax.envs.mjcf import PHYSICS_PRESETS, MissingModelError, PhysicsOptions
from minatt_jax.envs.point_robot import DensePointRobot, PointRobot
from minatt_jax.envs.task_sets import (
    TARGET_SET_NAMES,
    TASK_FIELDS,
    TASK_SET_NAMES,
    TaskSpecError,
    parse_task,
    resolve_tasks,
    task_list,
    task_set,
    task_set_names,
)
from minatt_jax.envs.tasks import (
    Task,
    apply_task,
    apply_task_to_mj_model,
    make_task,
    num_tasks,
    sample_task,
    select_task,
    stack_tasks,
)
from minatt_jax.envs.walker2d import Walker2d

ENVIRONMENTS: dict[str, type[LocomotionEnv]] = {
    "hopper": Hopper,
    "halfcheetah": HalfCheetah,
    "walker2d": Walker2d,
    "humanoid": Humanoid,
    "humanoid_376": HumanoidFull,
    "cheetah_run": CheetahRun,
    "humanoid_dir": HumanoidDir,
    "point_robot": PointRobot,
    "point_robot_dense": DensePointRobot,
}
ENV_NAMES = tuple(ENVIRONMENTS)


def register(name: str, env_class: type[LocomotionEnv]) -> None:
    """Adds a user's environment under ``name`` (``make(name)``, ``--env name``): a
    ``LocomotionEnv`` subclass built as ``env_class(physics)`` (see ``docs/extending.md``)."""
    ENVIRONMENTS[name] = env_class


class UnknownNameError(ValueError):
    """An environment, task set or physics preset name that does not exist."""


class UnavailableEnvError(UnknownNameError):
    """An environment whose model file's package is not installed (the message names it)."""


def load_plugin_env(name: str) -> None:
    """Imports the installed plugin that provides environment ``name`` (an entry point of group
    ``minatt_jax.envs`` under that name, whose module calls ``register``), if there is one."""
    from importlib.metadata import entry_points

    from minatt_jax.agents.registry import ENV_ENTRY_POINTS, import_plugin

    for ep in entry_points(group=ENV_ENTRY_POINTS):
        if ep.name == name:
            import_plugin(ep.value.partition(":")[0])


def environment_names() -> list[str]:
    """Every environment name: the built-in ones, those registered since and installed plugins'."""
    from importlib.metadata import entry_points

    from minatt_jax.agents.registry import ENV_ENTRY_POINTS

    plugins = {ep.name for ep in entry_points(group=ENV_ENTRY_POINTS)}
    return [*ENVIRONMENTS, *sorted(plugins - set(ENVIRONMENTS))]


def make(name: str, physics: str | PhysicsOptions | None = None) -> LocomotionEnv:
    """The environment ``name`` (one of ``environment_names()``) with the given physics preset
    (None: the environment's default, ``fast`` but for cheetah_run's DMC settings)."""
    if name not in ENVIRONMENTS:
        load_plugin_env(name)
    if name not in ENVIRONMENTS:
        raise UnknownNameError(
            f"unknown environment {name!r}; choose from {', '.join(environment_names())}"
        )
    if isinstance(physics, str) and physics not in PHYSICS_PRESETS:
        raise UnknownNameError(
            f"unknown physics preset {physics!r}; choose from {', '.join(PHYSICS_PRESETS)}"
        )
    try:
        return ENVIRONMENTS[name](physics)
    except MissingModelError as e:
        raise UnavailableEnvError(f"environment {name!r}: {e}") from None


def check_task_set_name(set_name: str) -> None:
    """Raises UnknownNameError for a task-set name that does not exist."""
    names = TASK_SET_NAMES + TARGET_SET_NAMES
    if set_name not in names:
        raise UnknownNameError(f"unknown variant {set_name!r}; choose from {', '.join(names)}")


__all__ = [
    "ENV_NAMES",
    "ENVIRONMENTS",
    "PHYSICS_PRESETS",
    "PointRobot",
    "TARGET_SET_NAMES",
    "TASK_FIELDS",
    "TASK_SET_NAMES",
    "CheetahRun",
    "HalfCheetah",
    "Hopper",
    "Humanoid",
    "HumanoidDir",
    "HumanoidFull",
    "LocomotionEnv",
    "PhysicsOptions",
    "Task",
    "TaskSpecError",
    "UnavailableEnvError",
    "UnknownNameError",
    "Walker2d",
    "apply_task",
    "apply_task_to_mj_model",
    "check_task_set_name",
    "make",
    "make_task",
    "num_tasks",
    "parse_task",
    "resolve_tasks",
    "sample_task",
    "select_task",
    "stack_tasks",
    "task_list",
    "task_set",
    "task_set_names",
]

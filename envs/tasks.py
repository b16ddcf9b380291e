"""Task parameters as data: a pytree applied to the MJX model inside the jitted step.

A :class:`Task` holds the perturbations the paper meta-trains and meta-tests on. Because every
field is an array, changing the task changes only the values flowing through a compiled program,
never its shape: switching tasks, or running a batch of environments on different tasks in one
vmapped call, does not recompile.

How each field enters the physics (``apply_task``):

* ``mass_scale`` (per body): ``body_mass`` and ``body_inertia`` scale together (a uniform change of
  density), so the model stays consistent. MJX has no ``mj_setConst``, so :func:`make_task` runs
  MuJoCo's on the host when the task is built and the task carries the derived constants MJX
  reads (``body_subtreemass`` and the inverse weights ``body_invweight0``/``dof_invweight0``, which
  set contact and joint-limit softness); with joint armature they do not simply scale by 1/s.
* ``friction_scale``: multiplies every geom's friction coefficients (MuJoCo takes the larger of
  the two geoms' coefficients per contact, so the contact friction scales by the same factor).
* ``gravity_scale`` and ``slope`` (radians, positive = uphill): gravity becomes
  ``g * gravity_scale * (-sin(slope), 0, -cos(slope))``. Tilting gravity about the y axis is the
  same physics as tilting the floor plane (the floor is infinite), with every observation read in
  the slope's frame: height above the slope and velocity along it.
* ``actuator_scale`` (per actuator): multiplies the actuator gain; 0 cripples the actuator (it
  produces no force whatever the policy commands; the policy still pays the control cost).
"""

from __future__ import annotations

import copy
import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from mujoco import mjx


@struct.dataclass
class Task:
    """Perturbation parameters of one task (or, with a leading axis, of a set of tasks)."""

    mass_scale: jax.Array  # (nbody,)
    friction_scale: jax.Array  # ()
    gravity_scale: jax.Array  # ()
    slope: jax.Array  # () radians, positive = uphill
    actuator_scale: jax.Array  # (nu,)
    # Constants MuJoCo derives from the masses (mj_setConst), computed by make_task.
    body_subtreemass: jax.Array  # (nbody,)
    body_invweight0: jax.Array  # (nbody, 2)
    dof_invweight0: jax.Array  # (nv,)
    # What a meta-RL task asks for, read by the environment's reward (humanoid_dir: the running
    # direction in radians). None for the perturbation tasks: a None field has no leaves, so
    # their pytrees, and the checkpoints that hold them, are what they were without it.
    target: jax.Array | None = None


def make_task(
    mj_model: mujoco.MjModel,
    mass_scale: float | np.ndarray = 1.0,
    friction_scale: float = 1.0,
    gravity_scale: float = 1.0,
    slope: float = 0.0,
    actuator_scale: float | np.ndarray = 1.0,
    target: float | np.ndarray | None = None,
) -> Task:
    """A task for ``mj_model``, with the mass-derived constants from MuJoCo's ``mj_setConst``.

    Scalars broadcast: ``mass_scale`` to every body, ``actuator_scale`` to every actuator.
    ``target``: what a meta-RL environment's reward reads (None for the others). Raises
    ValueError for non-finite or non-positive scales and a non-finite target.
    """
    mass = np.broadcast_to(np.asarray(mass_scale, np.float64), (mj_model.nbody,)).copy()
    act = np.broadcast_to(np.asarray(actuator_scale, np.float64), (mj_model.nu,)).copy()
    for label, value in (("mass_scale", mass), ("friction_scale", friction_scale),
                         ("gravity_scale", gravity_scale)):  # fmt: skip
        if not np.all(np.isfinite(value)) or np.any(np.asarray(value) <= 0):
            raise ValueError(f"{label} must be finite and positive, got {value}")
    if not np.all(np.isfinite(act)) or np.any(act < 0):
        raise ValueError(f"actuator_scale must be finite and >= 0, got {act}")
    if target is not None and not np.all(np.isfinite(target)):
        raise ValueError(f"target must be finite, got {target}")
    if not abs(slope) < np.pi / 2:
        raise ValueError(f"slope must be in (-pi/2, pi/2) radians, got {slope}")
    scaled = copy.copy(mj_model)
    scaled.body_mass[:] = mj_model.body_mass * mass
    scaled.body_inertia[:] = mj_model.body_inertia * mass[:, None]
    mujoco.mj_setConst(scaled, mujoco.MjData(scaled))
    f32 = functools.partial(jnp.asarray, dtype=jnp.float32)
    return Task(
        mass_scale=f32(mass),
        friction_scale=f32(friction_scale),
        gravity_scale=f32(gravity_scale),
        slope=f32(slope),
        actuator_scale=f32(act),
        body_subtreemass=f32(scaled.body_subtreemass),
        body_invweight0=f32(scaled.body_invweight0),
        dof_invweight0=f32(scaled.dof_invweight0),
        target=None if target is None else f32(target),
    )


def stack_tasks(tasks: list[Task]) -> Task:
    """Stacks tasks along a new leading axis (a task set)."""
    return jax.tree.map(lambda *xs: jnp.stack(xs), *tasks)


def num_tasks(task_set: Task) -> int:
    """Number of tasks in a stacked task set."""
    return int(task_set.friction_scale.shape[0])


def select_task(task_set: Task, index: jax.Array) -> Task:
    """Task ``index`` of a stacked task set (index may be traced)."""
    return jax.tree.map(lambda x: x[index], task_set)


def sample_task(key: jax.Array, task_set: Task) -> Task:
    """A task drawn uniformly from a stacked task set (one draw per episode)."""
    index = jax.random.randint(key, (), 0, task_set.friction_scale.shape[0])
    return select_task(task_set, index)


@struct.dataclass
class NominalModelFields:
    """The model fields a task modifies, at their nominal values (constants of the env)."""

    body_mass: jax.Array
    body_inertia: jax.Array
    geom_friction: jax.Array
    gravity: jax.Array
    actuator_gainprm: jax.Array

    @classmethod
    def from_model(cls, model: mjx.Model | mujoco.MjModel) -> NominalModelFields:
        return cls(
            body_mass=jnp.asarray(model.body_mass),
            body_inertia=jnp.asarray(model.body_inertia),
            geom_friction=jnp.asarray(model.geom_friction),
            gravity=jnp.asarray(model.opt.gravity),
            actuator_gainprm=jnp.asarray(model.actuator_gainprm),
        )


def perturbed_fields(nominal: NominalModelFields, task: Task) -> dict[str, jax.Array]:
    """The model fields ``task`` sets (by MJX ``tree_replace`` path), from their nominal values.

    The one statement of how a task enters the physics: :func:`apply_task` writes these into the
    MJX model, :func:`apply_task_to_mj_model` into a MuJoCo C model.
    """
    g = jnp.linalg.norm(nominal.gravity) * task.gravity_scale
    gravity = g * jnp.stack([-jnp.sin(task.slope), 0.0 * task.slope, -jnp.cos(task.slope)])
    gain = nominal.actuator_gainprm.at[:, 0].multiply(task.actuator_scale)
    return {
        "body_mass": nominal.body_mass * task.mass_scale,
        "body_inertia": nominal.body_inertia * task.mass_scale[:, None],
        "body_subtreemass": task.body_subtreemass,
        "body_invweight0": task.body_invweight0,
        "dof_invweight0": task.dof_invweight0,
        "geom_friction": nominal.geom_friction * task.friction_scale,
        "opt.gravity": gravity,
        "actuator_gainprm": gain,
    }


def apply_task(model: mjx.Model, nominal: NominalModelFields, task: Task) -> mjx.Model:
    """The MJX model with ``task`` applied; jit- and vmap-safe (task values may be traced)."""
    return model.tree_replace(perturbed_fields(nominal, task))


_DERIVED_BY_SET_CONST = ("body_subtreemass", "body_invweight0", "dof_invweight0")


def apply_task_to_mj_model(mj_model: mujoco.MjModel, task: Task) -> None:
    """Applies ``task`` in place to an unperturbed MuJoCo C model (e.g. a Gymnasium
    environment's), then lets ``mj_setConst`` derive the mass-dependent constants for that model.

    The task's arrays must match the model (same bodies and actuators as the environment the
    task was made for); raises ValueError otherwise.
    """
    if task.mass_scale.shape != (mj_model.nbody,) or task.actuator_scale.shape != (mj_model.nu,):
        raise ValueError(
            f"task made for {task.mass_scale.shape[0]} bodies and {task.actuator_scale.shape[0]} "
            f"actuators; this model has {mj_model.nbody} and {mj_model.nu}"
        )
    nominal = NominalModelFields.from_model(mj_model)  # the C model has the same field names
    for path, value in perturbed_fields(nominal, task).items():
        if path in _DERIVED_BY_SET_CONST:
            continue
        owner = mj_model.opt if path.startswith("opt.") else mj_model
        getattr(owner, path.removeprefix("opt."))[:] = np.asarray(value, np.float64)
    mujoco.mj_setConst(mj_model, mujoco.MjData(mj_model))

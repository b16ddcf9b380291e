"""Task parameters as data: a pytree applied to the MJX model inside the jitted step.

A :class:`Task` holds the perturbations the paper meta-trains and meta-tests on. Because every
field is an array, changing the task changes only the values flowing through a compiled program,
never its shape: switching tasks, or running a batch of environments on different tasks in one
vmapped call, does not recompile.

How each field enters the physics (``apply_task``):

* ``mass_scale`` (per body): ``body_mass`` and ``body_inertia`` scale together (a uniform change of
  density), so the model stays consistent. The derived constants that MuJoCo's ``mj_setConst``
  would recompute are updated where MJX reads them: ``body_subtreemass`` scales by the subtree's
  factor and the inverse weights ``body_invweight0``/``dof_invweight0`` (which set contact and
  joint-limit softness) by the inverse of the mean factor; for a uniform factor s the first is
  exact and the second is exact up to joint armature (which does not scale).
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

import jax
import jax.numpy as jnp
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


def nominal_task(nbody: int, nu: int) -> Task:
    """The unperturbed task."""
    return Task(
        mass_scale=jnp.ones((nbody,), jnp.float32),
        friction_scale=jnp.ones((), jnp.float32),
        gravity_scale=jnp.ones((), jnp.float32),
        slope=jnp.zeros((), jnp.float32),
        actuator_scale=jnp.ones((nu,), jnp.float32),
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
    body_subtreemass: jax.Array
    body_invweight0: jax.Array
    dof_invweight0: jax.Array
    geom_friction: jax.Array
    gravity: jax.Array
    actuator_gainprm: jax.Array
    body_parentid: np.ndarray = struct.field(pytree_node=False)

    @classmethod
    def from_model(cls, model: mjx.Model) -> NominalModelFields:
        return cls(
            body_mass=jnp.asarray(model.body_mass),
            body_inertia=jnp.asarray(model.body_inertia),
            body_subtreemass=jnp.asarray(model.body_subtreemass),
            body_invweight0=jnp.asarray(model.body_invweight0),
            dof_invweight0=jnp.asarray(model.dof_invweight0),
            geom_friction=jnp.asarray(model.geom_friction),
            gravity=jnp.asarray(model.opt.gravity),
            actuator_gainprm=jnp.asarray(model.actuator_gainprm),
            body_parentid=np.asarray(model.body_parentid),
        )


def _subtree_mass(body_mass: jax.Array, parent: np.ndarray) -> jax.Array:
    """Subtree masses from body masses (bodies are ordered parents first, as in MuJoCo)."""
    subtree = body_mass
    for b in range(len(parent) - 1, 0, -1):
        subtree = subtree.at[parent[b]].add(subtree[b])
    return subtree


def apply_task(model: mjx.Model, nominal: NominalModelFields, task: Task) -> mjx.Model:
    """The MJX model with ``task`` applied; jit- and vmap-safe (task values may be traced)."""
    mass = nominal.body_mass * task.mass_scale
    mean_scale = jnp.mean(task.mass_scale[1:])
    g = jnp.linalg.norm(nominal.gravity) * task.gravity_scale
    gravity = g * jnp.stack([-jnp.sin(task.slope), 0.0 * task.slope, -jnp.cos(task.slope)])
    gain = nominal.actuator_gainprm.at[:, 0].multiply(task.actuator_scale)
    return model.tree_replace(
        {
            "body_mass": mass,
            "body_inertia": nominal.body_inertia * task.mass_scale[:, None],
            "body_subtreemass": _subtree_mass(mass, nominal.body_parentid),
            "body_invweight0": nominal.body_invweight0 / mean_scale,
            "dof_invweight0": nominal.dof_invweight0 / mean_scale,
            "geom_friction": nominal.geom_friction * task.friction_scale,
            "opt.gravity": gravity,
            "actuator_gainprm": gain,
        }
    )

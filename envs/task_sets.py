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
# Sets only meta-RL environments define (``LocomotionEnv.target_tasks``): targets outside the
# training range.
TARGET_SET_NAMES = ("ood",)

TRAIN_GRAVITY_FRICTION = ((1.00, 1.00), (0.90, 0.90), (0.95, 1.10), (1.05, 0.90), (1.10, 1.10))
MASS_SCALES = (0.5, 0.75, 1.25, 1.5, 2.0)
SLOPES = (0.05, 0.10, -0.05, -0.10)  # radians; positive = uphill


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


class TaskSpecError(ValueError):
    """A custom task specification that cannot be read (a user-facing error)."""


# The custom-task field each perturbation set varies.
SET_FIELDS = {"mass": "mass", "slope": "slope"}


def _ignores(env: LocomotionEnv, field: str) -> bool:
    return field in getattr(env, "ignored_task_fields", ())


def task_list(env: LocomotionEnv, set_name: str) -> tuple[list[Task], list[str]]:
    """The tasks of ``set_name`` for ``env`` and a short label for each."""
    own = env.target_tasks(set_name)
    if own is not None:
        return own
    field = SET_FIELDS.get(set_name)
    if field is not None and _ignores(env, field):
        raise TaskSpecError(f"{env.name} has no {set_name!r} task set: its dynamics ignore "
                            f"{field}, so every task would be the nominal one")  # fmt: skip
    if set_name in TARGET_SET_NAMES:
        raise TaskSpecError(f"{env.name} has no {set_name!r} task set: it holds the targets of a "
                            "meta-RL environment (humanoid_dir)")  # fmt: skip
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
        joint_sets = env.crippled_joints
        tasks = [env.make_task(actuator_scale=_actuator_scale(env, j)) for j in joint_sets]
        return tasks, ["crippled " + "+".join(j) for j in joint_sets]
    if set_name == "slope":
        tasks = [env.make_task(slope=s) for s in SLOPES]
        labels = [f"{'uphill' if s > 0 else 'downhill'} {abs(s):.2f} rad" for s in SLOPES]
        return tasks, labels
    raise KeyError(set_name)


TASK_FIELDS = {
    "mass": "mass_scale",
    "friction": "friction_scale",
    "gravity": "gravity_scale",
    "slope": "slope",
    "crippled": "actuator_scale",
    "target": "target",
}


def parse_task(env: LocomotionEnv, spec: str) -> tuple[Task, str]:
    """One custom task from ``"field=value[,field=value...]"`` and its label.

    Fields: ``mass``, ``friction``, ``gravity`` (scales, > 0), ``slope`` (radians, positive =
    uphill), ``crippled`` (joint names joined by ``+``, e.g. ``crippled=bthigh+bshin``) and, for
    a meta-RL environment, ``target`` (humanoid_dir: the running direction in radians).
    Example: ``mass=1.25,slope=0.12``.
    """
    fields: dict[str, object] = {}
    for part in spec.split(","):
        name, sep, value = part.strip().partition("=")
        name = name.strip()
        if not sep or not value.strip():
            raise TaskSpecError(f"task {spec!r}: expected field=value, got {part.strip()!r}")
        if name not in TASK_FIELDS:
            raise TaskSpecError(
                f"task {spec!r}: unknown field {name!r}; choose from {', '.join(TASK_FIELDS)}"
            )
        if TASK_FIELDS[name] in fields:
            raise TaskSpecError(f"task {spec!r}: field {name!r} given twice")
        if _ignores(env, name):
            raise TaskSpecError(f"task {spec!r}: {env.name}'s dynamics ignore {name}; the task "
                                "would run as the nominal one")  # fmt: skip
        if name == "crippled":
            joints = tuple(j.strip() for j in value.split("+"))
            actuated = [env.mj_model.joint(int(env.mj_model.actuator_trnid[a, 0])).name
                        for a in range(env.mj_model.nu)]  # fmt: skip
            unknown = [j for j in joints if j not in actuated]
            if unknown:
                raise TaskSpecError(
                    f"task {spec!r}: {env.name} has no actuated joint {unknown[0]!r}; "
                    f"choose from {', '.join(actuated)}"
                )
            fields["actuator_scale"] = _actuator_scale(env, joints)
            continue
        try:
            number = float(value)
        except ValueError:
            raise TaskSpecError(f"task {spec!r}: {name} must be a number, got {value!r}") from None
        fields[TASK_FIELDS[name]] = number
    try:
        return env.make_task(**fields), spec.replace(" ", "")
    except ValueError as e:
        raise TaskSpecError(f"task {spec!r}: {e}") from None


def resolve_tasks(
    env: LocomotionEnv, set_name: str, specs: tuple[str, ...] | list[str] = ()
) -> tuple[list[Task], list[str]]:
    """Custom tasks when ``specs`` are given (one task per spec), else the named set's."""
    if specs:
        pairs = [parse_task(env, s) for s in specs]
        return [t for t, _ in pairs], [label for _, label in pairs]
    return task_list(env, set_name)


def task_set_names(env: LocomotionEnv) -> tuple[str, ...]:
    """The task sets ``env`` has: every environment's (less those varying what its dynamics
    ignore), and its own targets' where it has any."""
    sets = tuple(s for s in TASK_SET_NAMES
                 if not (s in SET_FIELDS and _ignores(env, SET_FIELDS[s])))  # fmt: skip
    return sets + (TARGET_SET_NAMES if env.default_target is not None else ())


def task_set(env: LocomotionEnv, set_name: str) -> Task:
    """The tasks of ``set_name`` stacked along a leading axis."""
    return stack_tasks(task_list(env, set_name)[0])

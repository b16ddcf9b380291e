"""Loads the Gym v3 MuJoCo models and applies the MJX solver settings.

The MJCF files are the ones Gym's v3 locomotion tasks use; they are read from the installed
``gymnasium`` distribution (a pure-Python dependency that is never imported), so the physical
model is exactly Gym's. MJX cannot run every option those files set (Humanoid asks for the PGS
solver), and some settings cost far more under MJX than they buy, so :func:`load_model` applies
named :class:`PhysicsOptions`: ``gym`` keeps everything Gym sets that MJX can run, ``fast`` is the
tuned default measured in ``benchmarks/env_throughput.py``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.util
import os
import sys
import tempfile
from collections.abc import Iterator

import mujoco


@dataclasses.dataclass(frozen=True)
class PhysicsOptions:
    """MuJoCo solver settings applied on top of the Gym MJCF.

    Attributes:
      integrator: "rk4", "euler" or None (keep the file's).
      iterations: constraint-solver iterations, or None (keep the file's).
      ls_iterations: line-search iterations, or None (keep the file's).
      floor_contacts_only: keep only body-vs-floor contact pairs (drops self-collisions).
      solver: "newton", "cg" or None (keep the file's; PGS becomes Newton, MJX lacks PGS).
      disable_eulerdamp: integrate joint damping explicitly instead of implicitly.
      no_floor_contact_bodies: bodies whose geoms never touch the floor while the agent is
        healthy; their floor contacts are dropped.
      tolerance: solver tolerance (relative cost improvement that ends the iterations early).
    """

    integrator: str | None = None
    iterations: int | None = None
    ls_iterations: int | None = None
    floor_contacts_only: bool = False
    solver: str | None = None
    disable_eulerdamp: bool = False
    no_floor_contact_bodies: tuple[str, ...] = ()
    tolerance: float | None = None


PHYSICS_PRESETS: dict[str, PhysicsOptions] = {
    # Gym's own settings, except what MJX lacks (PGS -> Newton, MuJoCo's default 100 iterations).
    "gym": PhysicsOptions(),
    # Measured in benchmarks/env_throughput.py: Euler (semi-implicit, implicit joint damping),
    # 4 Newton iterations with 8 line-search steps, and body-vs-floor contacts only.
    "fast": PhysicsOptions(
        integrator="euler", iterations=4, ls_iterations=8, floor_contacts_only=True
    ),
    # One Newton iteration: about twice the throughput of "fast", but the solve is no longer
    # converged and trajectories drift from Gym's (benchmarks/physics_fidelity.py measures it).
    "fastest": PhysicsOptions(
        integrator="euler", iterations=1, ls_iterations=4, floor_contacts_only=True
    ),
}


# Where each package keeps its MJCF files, and how to get the package when it is missing.
MODEL_PACKAGES = {
    "gymnasium": (("envs", "mujoco", "assets"), "reinstall minatt-jax with its dependencies"),
    "dm_control": (("suite",), "pip install 'minatt-jax[dmc]' (the DeepMind Control Suite)"),
    "minatt_jax.envs": (("assets",), "reinstall minatt-jax (its model files are package data)"),
}


class MissingModelError(RuntimeError):
    """The package that ships an environment's MJCF file is not installed."""


def asset_path(asset_file: str, package: str = "gymnasium") -> str:
    """Path of the MJCF file ``asset_file`` inside the installed ``package`` (gymnasium's Gym
    models, dm_control's suite models), found without importing the package."""
    folders, remedy = MODEL_PACKAGES[package]
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        raise MissingModelError(f"the {package} package (which ships the model file "
                                f"{asset_file}) is not installed: {remedy}")  # fmt: skip
    root = list(spec.submodule_search_locations)[0]
    path = os.path.join(root, *folders, asset_file)
    if not os.path.exists(path):
        raise MissingModelError(f"model file missing from {package}: {path}")
    return path


# MuJoCo 4 warns, on the C-level stderr, that Gym's humanoid.xml uses the deprecated attribute
# ``settotalmass``; the model compiles as before, so the warning is only noise in every command.
_KNOWN_COMPILER_WARNINGS = ("compiler attribute 'settotalmass' is deprecated",)


@contextlib.contextmanager
def known_warnings_dropped() -> Iterator[None]:
    """Captures file descriptor 2 while a model compiles and passes on every line but the known
    compiler warnings above."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            captured.seek(0)
            lines = captured.read().decode(errors="replace").splitlines()
            kept = [line for line in lines if line.strip()
                    and not any(w in line for w in _KNOWN_COMPILER_WARNINGS)]  # fmt: skip
            if kept:
                sys.stderr.write("\n".join(kept) + "\n")


def load_model(
    asset_file: str, options: PhysicsOptions, package: str = "gymnasium"
) -> mujoco.MjModel:
    """The MJCF model ``asset_file`` of ``package`` (an environment's ``asset_file`` and
    ``asset_package``) with ``options`` applied (a MuJoCo C model)."""
    with known_warnings_dropped():
        model = mujoco.MjModel.from_xml_path(asset_path(asset_file, package))
    if model.opt.solver == mujoco.mjtSolver.mjSOL_PGS:
        # MJX implements only CG and Newton; Newton is MuJoCo's default.
        model.opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
        model.opt.iterations = 100
    if options.integrator is not None:
        model.opt.integrator = {
            "euler": mujoco.mjtIntegrator.mjINT_EULER,
            "rk4": mujoco.mjtIntegrator.mjINT_RK4,
        }[options.integrator]
    if options.solver is not None:
        model.opt.solver = {
            "newton": mujoco.mjtSolver.mjSOL_NEWTON,
            "cg": mujoco.mjtSolver.mjSOL_CG,
        }[options.solver]
    if options.disable_eulerdamp:
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EULERDAMP
    if options.tolerance is not None:
        model.opt.tolerance = options.tolerance
    if options.iterations is not None:
        model.opt.iterations = options.iterations
    if options.ls_iterations is not None:
        model.opt.ls_iterations = options.ls_iterations
    if options.floor_contacts_only:
        _keep_floor_contacts(model)
    for body in options.no_floor_contact_bodies:
        body_id = model.body(body).id
        for g in range(model.ngeom):
            if model.geom_bodyid[g] == body_id:
                model.geom_contype[g] = model.geom_conaffinity[g] = 0
    return model


def _keep_floor_contacts(model: mujoco.MjModel) -> None:
    """Rewrites contype/conaffinity so that only world-body geoms collide with body geoms.

    Body geoms get contype 2 and conaffinity 0, world geoms (the floor) contype 0 and
    conaffinity 2: a pair collides when (contype_a & conaffinity_b) | (contype_b & conaffinity_a)
    is nonzero, which now holds only for body-floor pairs.
    """
    for g in range(model.ngeom):
        collides = model.geom_contype[g] or model.geom_conaffinity[g]
        if not collides:
            continue
        if model.geom_bodyid[g] == 0:
            model.geom_contype[g], model.geom_conaffinity[g] = 0, 2
        else:
            model.geom_contype[g], model.geom_conaffinity[g] = 2, 0

"""Humanoid (Gym v3 physics, MBPO's truncated 45-dim observation): 17 actions, frame skip 5."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco import mjx

from minatt_jax.envs.base import LocomotionEnv, RewardWeights
from minatt_jax.envs.mjcf import PhysicsOptions


def backend_field(data: mjx.Data, name: str) -> jax.Array:
    """A field of ``data``, from the backend's part where MJX 3.4+ keeps it (``cfrc_ext``,
    filled by ``Humanoid.complete``, and ``cinert``: their public attributes are deprecated)."""
    impl = getattr(data, "_impl", None)
    return getattr(impl, name) if hasattr(impl, name) else getattr(data, name)


class Humanoid(LocomotionEnv):
    """Gym v3 Humanoid with MBPO's ``HumanoidTruncatedObs``: obs = qpos[2:] (22) and qvel (23).

    Reward = 1.25 * centre-of-mass x velocity + 5 - 0.1 |a|^2 - min(5e-7 |cfrc_ext|^2, 10);
    ends unless 1 < z < 2. The contact cost is Gym's (v3 and v5): ``cfrc_ext`` after the step
    from ``mjx.rne_postconstraint``, as Gymnasium v5 calls ``mj_rnePostConstraint`` (under
    mujoco-py >= 2.0, Gym v2/v3 read it as zeros, so MBPO-era numbers may have had no contact
    cost).
    """

    name = "humanoid"
    asset_file = "humanoid.xml"
    frame_skip = 5
    reset_noise_scale = 1e-2
    weights = RewardWeights(forward=1.25, ctrl_cost=0.1, healthy=5.0, contact_cost=5e-7,
                            contact_cost_max=10.0)  # fmt: skip
    projections = (("vel_root_x", "root_z"), ("right_hip_y", "left_hip_y"))
    failure_grid_ranges = ((-1.0, 2.0), (-1.0, 1.0))
    failure_qvel_indices = (0, 4)  # free joint: (vx, vy, vz, wx, wy, wz)
    crippled_joints = (("right_hip_x", "right_hip_z", "right_hip_y", "right_knee"),)

    @staticmethod
    def terminated(obs: jax.Array) -> jax.Array:
        """Done unless 1 < z < 2 (z = obs[0] of the truncated observation)."""
        z = obs[..., 0]
        return 1.0 - ((z > 1.0) & (z < 2.0)).astype(jnp.float32)

    def __init__(self, physics: str | PhysicsOptions = "fast") -> None:
        super().__init__(physics)
        # qpos[2:]: root z, root quaternion (w, x, y, z), then the hinge angles; qvel: root linear
        # and angular velocity, then the hinge velocities.
        hinges = [self.mj_model.joint(j).name for j in range(1, self.mj_model.njnt)]
        self.obs_names = (
            ("root_z", "root_qw", "root_qx", "root_qy", "root_qz", *hinges)
            + ("vel_root_x", "vel_root_y", "vel_root_z", "angvel_root_x", "angvel_root_y")
            + ("angvel_root_z", *(f"vel_{h}" for h in hinges))
        )

    def observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos[2:], data.qvel])

    def reward_terms(
        self, model: mjx.Model, before: mjx.Data, after: mjx.Data, action: jax.Array
    ) -> dict[str, jax.Array]:
        """Forward term from the centre of mass (Gym v3's ``mass_center``)."""
        mass = model.body_mass

        def com_x(data: mjx.Data) -> jax.Array:
            return jnp.sum(mass * data.xipos[:, 0]) / jnp.sum(mass)

        forward = (com_x(after) - com_x(before)) / self.dt
        terms = {"forward": forward, "ctrl": jnp.sum(jnp.square(action))}
        if self.weights.contact_cost > 0:
            terms["contact"] = jnp.sum(jnp.square(backend_field(after, "cfrc_ext")))
        return terms

    def complete(self, model: mjx.Model, data: mjx.Data) -> mjx.Data:
        """The external contact forces ``cfrc_ext`` after the step (``mj_rnePostConstraint``),
        which the contact cost (and the 376-dim observation) read."""
        return mjx.rne_postconstraint(model, data)

    def metric_names(self) -> tuple[str, ...]:
        extra = ("reward_contact",) if self.weights.contact_cost > 0 else ()
        return (*super().metric_names(), *extra)

    def is_healthy(self, data: mjx.Data) -> jax.Array:
        z = data.qpos[2]
        return ((z > 1.0) & (z < 2.0)).astype(jnp.float32)


class HumanoidFull(Humanoid):
    """Humanoid with Gym v2/v3's whole 376-dim observation (``humanoid_376``): qpos[2:] (22),
    qvel (23), then per body (world included) the com-based inertia ``cinert`` (14 x 10) and
    velocity ``cvel`` (14 x 6), the actuator forces ``qfrc_actuator`` (23) and the external
    contact forces ``cfrc_ext`` (14 x 6). Everything else is ``humanoid``'s; the first 45
    entries are its observation, so the termination function and projections carry over.
    Gym v2/v3 under mujoco-py >= 2.0 (and Gymnasium v4) observed ``cfrc_ext`` as zeros; here it
    is the real post-constraint force, as Gymnasium v5 (whose 348 dims leave the world body and
    the free joint's actuator forces out) observes it."""

    name = "humanoid_376"

    def __init__(self, physics: str | PhysicsOptions = "fast") -> None:
        super().__init__(physics)
        bodies = [self.mj_model.body(b).name or "world" for b in range(self.mj_model.nbody)]
        dofs = [f"dof{i}" for i in range(self.mj_model.nv)]
        self.obs_names = (
            self.obs_names
            + tuple(f"cinert_{b}_{i}" for b in bodies for i in range(10))
            + tuple(f"cvel_{b}_{i}" for b in bodies for i in range(6))
            + tuple(f"qfrc_actuator_{d}" for d in dofs)
            + tuple(f"cfrc_ext_{b}_{i}" for b in bodies for i in range(6))
        )

    def observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([
            data.qpos[2:], data.qvel, backend_field(data, "cinert").ravel(),
            backend_field(data, "cvel").ravel(), data.qfrc_actuator,
            backend_field(data, "cfrc_ext").ravel(),
        ])  # fmt: skip

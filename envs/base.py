"""An MJX locomotion environment with Brax's ``Env`` interface and tasks as data.

Why our own class rather than brax's ``PipelineEnv``: brax's MJX pipeline computes brax transforms
and reformats contacts after every physics step (work nothing here reads), its asset files change
the Gym models (moved root joints, other contact dimensions), and applying a traced task needs the
model swapped per call anyway. This class keeps brax's ``State``/``Env`` API, so brax wrappers
still apply, and steps ``mjx.step`` directly on the Gym model.

Subclasses define the Gym v3 semantics of each environment (observation, reward terms, health)
and carry the facts every other part of minatt-jax reads about it, so adding an environment is one
file plus a registry line in ``envs/__init__.py``:

* ``asset_file``: the Gym MJCF model (inside the installed gymnasium package);
* ``obs_names``: a name per observation index;
* ``terminated(obs)``: termination as a function of the observation, for imagined rollouts in a
  learned model (which predicts observations, not MuJoCo states);
* ``failed(obs)``: the failure criterion of the failure grid (default: ``terminated``);
* ``projections``: the paper's 2D heatmap projections, as observation names;
* ``failure_grid_ranges`` / ``failure_qvel_indices``: the failure grid's (forward velocity, pitch
  rate) ranges of initial states and where those two sit in ``qvel``;
* ``crippled_joints``: the joint groups the ``crippled`` task set disables, one tuple per task.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
from brax.envs.base import Env, State
from mujoco import mjx

from minatt_jax.envs import mjcf
from minatt_jax.envs.tasks import NominalModelFields, Task, apply_task, make_task


@dataclasses.dataclass(frozen=True)
class RewardWeights:
    """Gym reward weights (forward, control cost, healthy bonus; Humanoid's contact cost
    ``min(contact_cost * |cfrc_ext|^2, contact_cost_max)``)."""

    forward: float
    ctrl_cost: float
    healthy: float
    contact_cost: float = 0.0
    contact_cost_max: float = float("inf")


class LocomotionEnv(Env, abc.ABC):
    """A Gym-v3 locomotion task on MJX with per-episode task parameters.

    ``state.info['task']`` holds the :class:`Task` applied in every step; ``reset(rng, task)``
    sets it. Observations, rewards and termination follow Gym v3 (see each subclass).
    """

    name: str = ""
    frame_skip: int = 1
    reset_noise_scale: float = 0.0
    weights: RewardWeights = RewardWeights(1.0, 0.0, 0.0)
    terminates: bool = True
    asset_file: str = ""
    asset_package: str = "gymnasium"
    # Physics steps with zero control after the reset noise, before the episode starts (the
    # DeepMind Control Suite lets its bodies settle this way); 0 for Gym's environments.
    settle_steps: int = 0
    # Whether reset runs ``mjx.forward``: only for observations that read what it computes
    # (Humanoid's inertias, body velocities and forces). ``mjx.step`` starts from qpos and qvel
    # with a forward of its own, so an environment that observes only those skips it: its
    # trajectories are the same, and every program that resets (a run's init, the collection's
    # resets, evaluation) compiles one MJX pipeline fewer (on a 2-core CPU, 12-16 s each).
    reset_runs_forward: bool = True
    # The physics preset when none is named (mjcf.PHYSICS_PRESETS).
    default_physics: str = "fast"
    # Observation index names for analysis (heatmaps); filled by subclasses.
    obs_names: tuple[str, ...] = ()
    projections: tuple[tuple[str, str], ...] = ()
    # ((vx min, vx max), (pitch rate min, pitch rate max)) of the failure grid's initial states.
    failure_grid_ranges: tuple[tuple[float, float], tuple[float, float]] = (
        (-1.0, 1.0),
        (-1.0, 1.0),
    )
    # qvel indices of forward velocity and torso pitch rate (planar root: x, z, pitch).
    failure_qvel_indices: tuple[int, int] = (0, 2)
    crippled_joints: tuple[tuple[str, ...], ...] = ()
    # Custom-task fields (``mass``, ``friction``, ``gravity``, ``slope``) the dynamics never read:
    # a task naming one, and the task set that varies it, are refused rather than run unchanged.
    ignored_task_fields: tuple[str, ...] = ()
    # Meta-RL environments whose tasks carry a target (``Task.target``): its nominal value;
    # None for the others, whose tasks have none.
    default_target: float | None = None
    # Their target sets: set name -> target values, and how a target reads in a task's label.
    target_sets: dict[str, tuple[float, ...]] = {}
    target_label: str = "target {:.3g}"
    # ctrl = action_scale * action (the policy acts in [-1, 1]); the control cost reads ctrl.
    action_scale: float = 1.0

    def __init__(self, physics: str | mjcf.PhysicsOptions | None = None) -> None:
        physics = self.default_physics if physics is None else physics
        options = mjcf.PHYSICS_PRESETS[physics] if isinstance(physics, str) else physics
        self.physics_options = options
        model = mjcf.load_model(self.asset_file, options, self.asset_package)
        self.mj_model: mujoco.MjModel = model
        # This process's own device: with jax.distributed, jax.devices()[0] (MJX's default) can
        # belong to another process.
        self.device = jax.local_devices()[0]
        self.mjx_model: mjx.Model = mjx.put_model(self.mj_model, device=self.device)
        self.nominal_fields = NominalModelFields.from_model(self.mjx_model)
        self.dt = float(self.mj_model.opt.timestep) * self.frame_skip
        self._init_qpos = jnp.asarray(self.mj_model.qpos0, jnp.float32)
        self._init_qvel = jnp.zeros((self.mj_model.nv,), jnp.float32)
        self._nominal_task = self.make_task()
        data = mjx.make_data(self.mjx_model, device=self.device)
        self._obs_size = int(self.observation(data).shape[-1])

    # ---- Brax Env interface -------------------------------------------------------------
    @property
    def observation_size(self) -> int:
        return self._obs_size

    @property
    def action_size(self) -> int:
        return int(self.mj_model.nu)

    @property
    def backend(self) -> str:
        return "mjx"

    def nominal_task(self) -> Task:
        """This environment's unperturbed task."""
        return self._nominal_task

    def make_task(self, **scales: Any) -> Task:
        """A task for this environment; keywords as :func:`minatt_jax.envs.tasks.make_task`
        (an environment with targets gets its ``default_target`` where none is given)."""
        if self.default_target is None:
            if scales.get("target") is not None:
                raise ValueError(f"{self.name}'s tasks take no target")
        else:
            scales.setdefault("target", self.default_target)
        return make_task(self.mj_model, **scales)

    def target_tasks(self, set_name: str) -> tuple[list[Task], list[str]] | None:
        """The tasks and labels of a task set this environment defines itself (a meta-RL
        environment's ``target_sets``), or None for the perturbation sets every environment
        shares."""
        if set_name not in self.target_sets:
            return None
        chosen = self.target_sets[set_name]
        return ([self.make_task(target=t) for t in chosen],
                [self.target_label.format(t) for t in chosen])  # fmt: skip

    def task_reward_terms(self, model: mjx.Model, before: mjx.Data, after: mjx.Data,
                          ctrl: jax.Array, task: Task) -> dict[str, jax.Array]:  # fmt: skip
        """The reward terms under ``task``: ``reward_terms``'s, for environments whose reward
        does not read the task (a meta-RL environment's reads its target)."""
        del task
        return self.reward_terms(model, before, after, ctrl)

    def reset(self, rng: jax.Array, task: Task | None = None) -> State:
        """Initial state with Gym v3 reset noise; ``task`` defaults to the nominal task."""
        task = self.nominal_task() if task is None else task
        rng, key_q, key_v = jax.random.split(rng, 3)
        qpos, qvel = self.reset_noise(key_q, key_v)
        model = apply_task(self.mjx_model, self.nominal_fields, task)
        data = mjx.make_data(model, device=self.device).replace(qpos=qpos, qvel=qvel)
        if self.settle_steps:
            data, _ = jax.lax.scan(lambda d, _: (mjx.step(model, d), None), data, None,
                                   self.settle_steps)  # fmt: skip
            data = data.replace(time=jnp.zeros_like(data.time))
        if self.reset_runs_forward:
            data = self.complete(model, mjx.forward(model, data))
        zero = jnp.zeros((), jnp.float32)
        metrics = {k: zero for k in self.metric_names()}
        info: dict[str, Any] = {"task": task, "rng": rng, "steps": jnp.zeros((), jnp.int32)}
        return State(data, self.observation(data), zero, zero, metrics, info)

    def step(self, state: State, action: jax.Array) -> State:
        """One environment step (``frame_skip`` physics steps) under the state's task."""
        model = apply_task(self.mjx_model, self.nominal_fields, state.info["task"])
        data0 = state.pipeline_state

        def physics_step(data: mjx.Data, _: None) -> tuple[mjx.Data, None]:
            return mjx.step(model, data), None

        ctrl = action if self.action_scale == 1.0 else self.action_scale * action
        data, _ = jax.lax.scan(physics_step, data0.replace(ctrl=ctrl), None, self.frame_skip)
        data = self.complete(model, data)
        terms = self.task_reward_terms(model, data0, data, ctrl, state.info["task"])
        healthy = self.is_healthy(data)
        reward = (
            self.weights.forward * terms["forward"]
            - self.weights.ctrl_cost * terms["ctrl"]
            + self.weights.healthy * jnp.ones_like(terms["forward"])
        )
        contact = {}
        if self.weights.contact_cost > 0:  # static: only Humanoid pays it
            cost = jnp.minimum(self.weights.contact_cost * terms["contact"],
                               self.weights.contact_cost_max)  # fmt: skip
            reward = reward - cost
            contact = {"reward_contact": -cost}
        done = jnp.where(self.terminates, 1.0 - healthy, 0.0)
        metrics = {
            "reward_forward": self.weights.forward * terms["forward"],
            "reward_ctrl": -self.weights.ctrl_cost * terms["ctrl"],
            "reward_healthy": self.weights.healthy * jnp.ones_like(terms["forward"]),
            "x_position": data.qpos[0],
            "x_velocity": terms.get("speed", terms["forward"]),
            **contact,
        }
        info = {**state.info, "steps": state.info["steps"] + 1}
        return state.replace(
            pipeline_state=data,
            obs=self.observation(data),
            reward=reward.astype(jnp.float32),
            done=done.astype(jnp.float32),
            metrics=metrics,
            info=info,
        )

    # ---- Gym v3 semantics (overridden per environment) -----------------------------------
    @staticmethod
    def metric_names() -> tuple[str, ...]:
        return ("reward_forward", "reward_ctrl", "reward_healthy", "x_position", "x_velocity")

    def reset_noise(self, key_q: jax.Array, key_v: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Gym's default: uniform noise of ``reset_noise_scale`` on qpos and qvel."""
        c = self.reset_noise_scale
        qpos = self._init_qpos + jax.random.uniform(
            key_q, self._init_qpos.shape, minval=-c, maxval=c
        )
        qvel = self._init_qvel + jax.random.uniform(
            key_v, self._init_qvel.shape, minval=-c, maxval=c
        )
        return qpos, qvel

    def reward_terms(
        self, model: mjx.Model, before: mjx.Data, after: mjx.Data, action: jax.Array
    ) -> dict[str, jax.Array]:
        """Unweighted reward terms: forward velocity of the root and sum of squared actions."""
        del model
        forward = (after.qpos[0] - before.qpos[0]) / self.dt
        return {"forward": forward, "ctrl": jnp.sum(jnp.square(action))}

    def complete(self, model: mjx.Model, data: mjx.Data) -> mjx.Data:
        """``data`` with what the observation and reward read beyond ``mjx.step`` /
        ``mjx.forward`` (Humanoid: the external contact forces); called after every step and
        reset, and wherever a state is set by hand."""
        del model
        return data

    def with_start(self, state: State, data: mjx.Data) -> State:
        """``state`` (a reset's) started from the simulator state ``data`` instead: the
        failure grid's chosen initial velocities. ``data`` is complete (``complete``)."""
        return state.replace(pipeline_state=data, obs=self.observation(data))

    @abc.abstractmethod
    def observation(self, data: mjx.Data) -> jax.Array:
        """Gym v3 observation from physics data."""

    def is_healthy(self, data: mjx.Data) -> jax.Array:
        """1.0 while the agent is healthy (Gym v3 ``is_healthy``); always 1 by default."""
        del data
        return jnp.ones((), jnp.float32)

    # ---- Facts on observations (imagined rollouts, analysis) --------------------------------
    @staticmethod
    def terminated(obs: jax.Array) -> jax.Array:
        """1.0 where an observation (..., obs_dim) ends the episode; never by default."""
        return jnp.zeros(obs.shape[:-1], jnp.float32)

    def failed(self, obs: jax.Array) -> jax.Array:
        """1.0 where a state counts as a failure in the failure grid (default: termination)."""
        return self.terminated(obs)

    def projection_indices(self) -> list[tuple[int, int]]:
        """The observation indices of ``projections``."""
        return [(self.obs_names.index(a), self.obs_names.index(b)) for a, b in self.projections]

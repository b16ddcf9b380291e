"""A trained policy in Gymnasium's v5 environments on the MuJoCo C engine.

Why: policies are trained in MJX with our Gym-v3 environments and tuned solver settings (see
``envs/mjcf.py``); everyone else reports on Gymnasium's v5 environments in the C engine. This
module runs a run's deterministic policy there, with the same perturbations (a :class:`Task` is
written into the C model by ``envs.apply_task_to_mj_model``, the same formulas as in MJX) and the
same per-episode metrics (``acting.episode_metrics``, the exact feedback probe, the smoothness
score), so the two evaluations can be set side by side.

Differences between the engines' environments that a reader of the numbers should know:
the C engine runs Gym's own solver settings (RK4 for hopper/walker2d, full contacts, MuJoCo's
default iterations); Walker2d-v5 gives both feet the same friction (v3: the left foot 0.9); the
Humanoid-v5 observation is cut to our 45 dims (qpos[2:], qvel) through Gymnasium's
``include_*_in_observation`` switches, and its reward has a contact cost that ours lacks.

Gymnasium's MuJoCo environments import ``imageio`` (for rendering) at import time; it comes with
the ``mujoco-engine`` extra: ``pip install "minatt-jax[mujoco-engine]"``.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import minatt_jax.envs as envs
from minatt_jax import acting
from minatt_jax.envs import mjcf
from minatt_jax.evaluation import EvalResult, summarize

GYMNASIUM_IDS: dict[str, str] = {
    "hopper": "Hopper-v5",
    "halfcheetah": "HalfCheetah-v5",
    "walker2d": "Walker2d-v5",
    "humanoid": "Humanoid-v5",
}
EXTRA = "mujoco-engine"

# Humanoid-v5 observes qpos[2:], qvel and then body inertias, velocities, actuator and external
# contact forces; with these switched off its observation is exactly our 45 dims.
_HUMANOID_OBS_45 = {
    "include_cinert_in_observation": False,
    "include_cvel_in_observation": False,
    "include_qfrc_actuator_in_observation": False,
    "include_cfrc_ext_in_observation": False,
}


class MissingExtraError(RuntimeError):
    """Gymnasium's MuJoCo environments cannot be imported (a missing optional package)."""


def make_gym_env(env_name: str, max_episode_steps: int, task: envs.Task | None = None) -> Any:
    """Gymnasium's v5 environment for ``env_name`` on the C engine, with ``task`` applied.

    Raises ValueError for an environment without a Gymnasium counterpart and MissingExtraError
    when Gymnasium's MuJoCo environments cannot be imported.
    """
    if env_name not in GYMNASIUM_IDS:
        raise ValueError(
            f"no Gymnasium v5 counterpart for {env_name!r}; the C engine evaluates "
            f"{', '.join(GYMNASIUM_IDS)}"
        )
    try:
        import gymnasium
        import gymnasium.envs.mujoco  # noqa: F401 - imports imageio and the mujoco bindings
    except ModuleNotFoundError as e:
        raise MissingExtraError(
            f"evaluating in the MuJoCo C engine needs Gymnasium's MuJoCo environments, which "
            f'need the package {e.name!r}: pip install "minatt-jax[{EXTRA}]"'
        ) from None
    kwargs = _HUMANOID_OBS_45 if env_name == "humanoid" else {}
    with mjcf.known_warnings_dropped():
        env = gymnasium.make(GYMNASIUM_IDS[env_name], max_episode_steps=max_episode_steps, **kwargs)
    if task is not None:
        envs.apply_task_to_mj_model(env.unwrapped.model, task)
    return env


def _episode(gym_env: Any, step_fn: Any, seed: int, max_steps: int) -> dict[str, np.ndarray]:
    """One deterministic episode, padded to ``max_steps`` rows (``alive`` marks the real ones)."""
    obs, _ = gym_env.reset(seed=seed)
    rows: dict[str, list] = {k: [] for k in ("obs", "policy_obs", "action", "reward",
                                             "next_obs", "done")}  # fmt: skip
    for _ in range(max_steps):
        x, u = step_fn(jnp.asarray(obs, jnp.float32))
        u = np.asarray(u)
        nxt, reward, terminated, truncated, _ = gym_env.step(u.astype(np.float64))
        for key, value in (("obs", obs), ("policy_obs", x), ("action", u), ("reward", reward),
                           ("next_obs", nxt), ("done", float(terminated))):  # fmt: skip
            rows[key].append(np.asarray(value, np.float32))
        obs = nxt
        if terminated or truncated:
            break
    length = len(rows["reward"])
    out = {}
    for key, values in rows.items():
        stacked = np.stack(values)
        pad = [(0, max_steps - length)] + [(0, 0)] * (stacked.ndim - 1)
        out[key] = np.pad(stacked, pad)
    out["alive"] = (np.arange(max_steps) < length).astype(np.float32)
    return out


def evaluate(policy: Any, tasks: list[envs.Task], episodes: int, seed: int = 0) -> dict[str, float]:
    """Mean and std over ``episodes`` deterministic episodes of ``policy`` (a
    ``checkpoint.Policy``) in the C engine; episode i runs ``tasks[i % len(tasks)]`` with reset
    seed ``seed + i``. The same metrics as the MJX evaluation (``evaluation.summarize``)."""
    config = policy.config
    actor = policy.family.deterministic(policy.actor_params, policy.normalizer)

    @jax.jit
    def step_fn(obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        x = actor.prepare(obs)
        return x, actor.act(x, None)

    feedback = jax.jit(jax.vmap(lambda x: acting.feedback_at(actor.control, x)))
    max_steps = config.max_episode_steps
    gym_envs = [make_gym_env(config.env, max_steps, task) for task in tasks]
    dt = float(gym_envs[0].unwrapped.dt)
    rows = []
    for i in range(episodes):
        row = _episode(gym_envs[i % len(tasks)], step_fn, seed + i, max_steps)
        row["feedback"] = np.asarray(feedback(jnp.asarray(row["policy_obs"])))
        rows.append(row)
    for gym_env in gym_envs:
        gym_env.close()
    batch = {k: jnp.asarray(np.stack([r[k] for r in rows])) for k in rows[0]}
    trajectories = acting.Trajectory(env_metrics={}, **batch)
    metrics = jax.vmap(lambda t: acting.episode_metrics(t, dt))(trajectories)
    return summarize(jax.device_get(EvalResult(metrics, batch["action"], batch["alive"])), dt)

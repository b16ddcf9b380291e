"""Deterministic evaluation episodes and the paper's control metrics.

Per episode (deterministic actions u_t = tanh(mean(x_t)), steps until the first ``done``), the
metrics of ``acting.episode_metrics``: return; feedback_norm (mean ||du/dx||_F^2, exact, with
respect to the observation the policy receives); feedforward_norm (mean ||(u_t - u_{t-1}) / dt||^2,
the rollout reading: the paper's "action jerk"); energy (mean ||u_t||^2, the paper's "control cost
sum(u^2) per step"); jerk (second differences); and ``smoothness``, the CAPS score
Sm = 2 / (n f_s) * sum_i M_i f_i over the n one-sided FFT bins of each action dimension's sequence
(M_i = 2 |X_i| / N, f_s = 1 / dt), averaged over action dimensions. Lower is smoother. This is the
convention of Mysore et al. (2021); the other one seen in code (M_i = |X_i| without the 2 / N) is
larger by N / 4 for N-step episodes.

Metrics are mean and std over episodes; seeds are aggregated by the caller. A run in
meta-episodes (``TrainConfig.meta_episodes``) evaluates whole meta-episodes and adds
``return_episode_<i>``, each inner episode's return: the in-context adaptation curve.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

import minatt_jax.envs as envs
from minatt_jax import acting, memory
from minatt_jax import normalizer as obs_norm
from minatt_jax.envs.meta_episode import returns_by_episode

METRIC_NAMES = ("return", "length", "feedback_norm", "feedforward_norm", "energy", "jerk")


@struct.dataclass
class EvalResult:
    """Per-episode metrics (episodes,) and the action sequences (episodes, steps, act_dim)."""

    metrics: dict[str, jax.Array]
    actions: jax.Array
    alive: jax.Array  # (episodes, steps) 1.0 until the episode's first done (inclusive)


def check_episodes_fit(env: envs.LocomotionEnv, episodes: int, steps: int) -> None:
    """RunError before anything is allocated when ``episodes`` parallel episodes of ``steps``
    steps cannot fit: each holds its simulator state and, per step, its observations (raw and
    as the policy sees them), action, the Jacobian probe's and the metrics' values (float32)."""
    shapes = jax.eval_shape(env.reset, jax.random.PRNGKey(0), env.nominal_task())
    state = sum(int(np.prod(x.shape)) * x.dtype.itemsize for x in jax.tree.leaves(shapes))
    per_step = 4 * (2 * env.observation_size + 2 * env.action_size + 16)
    memory.check_fits(episodes * (state + steps * per_step),
                      f"{episodes} evaluation episodes of {steps} steps",
                      "ask for fewer episodes (--episodes)")  # fmt: skip


def make_evaluator(
    env: envs.LocomotionEnv,
    policy_of: Callable[[Any, Any], acting.AnyPolicy],
    max_steps: int,
    episodes: int,
) -> Callable[[Any, Any, jax.Array, envs.Task], EvalResult]:
    """A jitted ``(params, normalizer, key, task_set) -> EvalResult``; ``policy_of(params,
    normalizer)`` is the deterministic policy (``deterministic_of`` for a feedforward control
    law, a recurrent policy for DreamerV3).

    Episode i runs task ``i % num_tasks`` of the task set (``acting.unroll`` with the exact
    feedback probe).
    """
    dt = env.dt
    check_episodes_fit(env, episodes, max_steps)

    inner_episodes = getattr(env, "episodes", 1)  # a meta-episode's (envs.meta_episode)

    def episode(params: Any, norm: Any, key: jax.Array, task: envs.Task):
        policy = policy_of(params, norm)
        traj = acting.unroll(env, policy, env.reset(key, task), max_steps, probe_feedback=True)
        metrics = acting.episode_metrics(traj, dt)
        if inner_episodes > 1:  # the in-context adaptation curve: each inner episode's return
            returns = returns_by_episode(traj.reward, traj.env_metrics["meta_episode_index"],
                                         traj.alive, inner_episodes)  # fmt: skip
            metrics |= {f"return_episode_{i + 1}": returns[i] for i in range(inner_episodes)}
        return metrics, traj.action, traj.alive

    def evaluate(params, norm, key, task_set):
        k = envs.num_tasks(task_set)
        tasks = jax.tree.map(lambda x: x[jnp.arange(episodes) % k], task_set)
        keys = jax.random.split(key, episodes)
        metrics, actions, alive = jax.vmap(episode, in_axes=(None, None, 0, 0))(
            params, norm, keys, tasks
        )
        return EvalResult(metrics, actions, alive)

    return jax.jit(evaluate)


def deterministic_of(
    control: Callable[[Any, jax.Array], jax.Array], normalize_obs: bool
) -> Callable[[Any, obs_norm.Normalizer], acting.Policy]:
    """``(params, normalizer) -> `` the deterministic feedforward policy u = control(params, x)
    on (normalized, where ``normalize_obs``) observations x."""
    return lambda params, norm: acting.deterministic(control, params, norm, normalize_obs)


def smoothness(actions: np.ndarray, alive: np.ndarray, dt: float) -> np.ndarray:
    """CAPS smoothness Sm per episode (see the module docstring), on the alive prefix."""
    scores = []
    for a, m in zip(np.asarray(actions), np.asarray(alive), strict=True):
        n_steps = int(m.sum())
        if n_steps < 2:
            scores.append(0.0)
            continue
        seq = a[:n_steps]
        spectrum = 2.0 * np.abs(np.fft.rfft(seq, axis=0)) / n_steps
        freqs = np.fft.rfftfreq(n_steps, d=dt)
        fs = 1.0 / dt
        sm = 2.0 / (len(freqs) * fs) * np.sum(spectrum * freqs[:, None], axis=0)
        scores.append(float(np.mean(sm)))
    return np.asarray(scores)


def summarize(result: EvalResult, dt: float) -> dict[str, float]:
    """Mean and std over episodes of every metric, plus the smoothness score."""
    metrics = {k: np.asarray(v) for k, v in result.metrics.items()}
    metrics["smoothness"] = smoothness(result.actions, result.alive, dt)
    out: dict[str, float] = {}
    for name, values in metrics.items():
        out[name] = float(np.mean(values))
        out[f"{name}_std"] = float(np.std(values))
    return out


def baseline_rollouts(
    env: Any, tasks: list, labels: list[str], policy: str, steps: int, seed: int
) -> dict[str, Any]:
    """A zero or random policy (``policy``) for ``steps`` steps on each task, all tasks in one
    vmapped call (``minatt-jax rollout``): returns, lengths, reward terms and the throughput."""
    make_policy = acting.random_policy if policy == "random" else acting.zero_policy
    acts = make_policy(env.action_size)

    def rollout(key, task):
        key_reset, key_policy = jax.random.split(key)
        traj = acting.unroll(env, acts, env.reset(key_reset, task), steps, key=key_policy)
        alive = traj.alive
        return {
            "return": jnp.sum(alive * traj.reward),
            "length": jnp.sum(alive),
            "forward_reward": jnp.sum(alive * traj.env_metrics["reward_forward"]),
            "ctrl_reward": jnp.sum(alive * traj.env_metrics["reward_ctrl"]),
        }

    task_set = envs.stack_tasks(tasks)
    keys = jax.random.split(jax.random.PRNGKey(seed), len(tasks))
    t0 = time.perf_counter()
    compiled = jax.jit(jax.vmap(rollout)).lower(keys, task_set).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = jax.device_get(jax.block_until_ready(compiled(keys, task_set)))
    run_s = time.perf_counter() - t0
    steps_per_s = len(tasks) * steps / run_s
    rows = [
        {
            "task": label,
            "return": float(result["return"][i]),
            "length": int(result["length"][i]),
            "forward_reward": float(result["forward_reward"][i]),
            "ctrl_reward": float(result["ctrl_reward"][i]),
        }
        for i, label in enumerate(labels)
    ]
    return {
        "policy": policy,
        "steps": steps,
        "seed": seed,
        "compile_s": compile_s,
        "run_s": run_s,
        "env_steps_per_s": steps_per_s,
        "physics_steps_per_s": steps_per_s * env.frame_skip,
        "mean_return": float(np.mean(result["return"])),
        "tasks": rows,
    }

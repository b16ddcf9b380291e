"""Model-free SAC training on the MJX environments: one train-state pytree, one jitted chunk.

``make_trainer(config)`` returns pure functions:

* ``init(key) -> TrainState``: agent, replay buffer, environments, noise, normalizer, RNG, counters;
* ``train_chunk(state) -> (state, metrics)``: ``eval_every / num_envs`` iterations of (one step of
  every environment, replay insertion, ``updates_per_step`` SAC updates), all in one ``lax.scan``
  compiled once; warm-up (random actions, no updates) is a ``lax.cond`` on the step counter, so
  the same program runs before and after it;
* ``evaluate(state, key, task_set) -> EvalResult``: deterministic episodes (see ``evaluation``).

Episodes end by termination or at ``max_episode_steps``; the buffer's ``terminal`` flag is set
for the first only (time limits are bootstrapped). A new task is drawn from the task set at every
reset.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from brax.envs.base import State as EnvState
from flax import struct

import minatt_jax.envs as envs
from minatt_jax import normalizer as obs_norm
from minatt_jax import replay
from minatt_jax.config import TrainConfig
from minatt_jax.evaluation import EvalResult, make_evaluator
from minatt_jax.sac import SAC, SACState, make_sac, metric_names


@struct.dataclass
class TrainState:
    """Everything a run needs to continue exactly: saved whole in each checkpoint."""

    agent: SACState
    buffer: replay.ReplayBuffer
    env_state: EnvState  # batched over num_envs
    normalizer: obs_norm.Normalizer
    ou_noise: jax.Array  # (num_envs, act_dim)
    episode_return: jax.Array  # running return of the current episodes (num_envs,)
    episode_length: jax.Array  # (num_envs,)
    rng: jax.Array
    env_steps: jax.Array  # total env steps taken (all environments)


class Trainer(NamedTuple):
    """Pure functions of a training run, plus what they were built from."""

    config: TrainConfig
    env: envs.LocomotionEnv
    sac: SAC
    task_set: envs.Task
    init: Callable[[jax.Array], TrainState]
    train_chunk: Callable[[TrainState], tuple[TrainState, dict]]
    evaluate: Callable[[TrainState, jax.Array, envs.Task], EvalResult]
    steps_per_chunk: int
    # Pieces of one iteration, (state, key) -> state or (state, out), for timing breakdowns.
    parts: dict[str, Callable] | None = None


def summarize_chunk(metrics: dict, names: tuple[str, ...], updates_per_step: int) -> dict:
    """A chunk's per-iteration outputs -> update metrics averaged over the iterations that
    updated, mean return of the episodes that finished, and counts."""
    updated = jnp.maximum(jnp.sum(metrics["updated"]), 1.0)
    summary = {k: jnp.sum(metrics[k] * metrics["updated"]) / updated for k in names}
    episodes = jnp.sum(metrics["episodes_finished"])
    summary["train_episode_return"] = jnp.where(
        episodes > 0, jnp.sum(metrics["finished_return_sum"]) / jnp.maximum(episodes, 1), 0.0
    )
    summary["train_episodes"] = episodes
    summary["updates"] = jnp.sum(metrics["updated"]) * updates_per_step
    return summary


class EnvStep(NamedTuple):
    """One step of the training environments with the episode bookkeeping done."""

    transitions: replay.Transitions  # what to store: (obs, action, reward, next_obs, terminal)
    env_state: EnvState  # next states, with ended episodes replaced by fresh resets
    episode_return: jax.Array  # running returns, zeroed where an episode ended
    episode_length: jax.Array
    ended: jax.Array  # (num_envs,) bool: terminated or reached the step limit
    finished_return: jax.Array  # sum of the returns of the episodes that ended this step


def env_step(
    env: Any,
    env_state: EnvState,
    action: jax.Array,
    episode_return: jax.Array,
    episode_length: jax.Array,
    max_episode_steps: int,
    reset: Callable[[jax.Array], EnvState],
    key: jax.Array,
) -> EnvStep:
    """Steps every environment, ends episodes (termination or the step limit) and resets them.

    ``reset(key)`` returns fresh states for all environments (new tasks included); it runs
    under a ``lax.cond`` only when some episode ended, so resets cost nothing otherwise.
    Shared by the model-free and the model-based trainers.
    """
    next_state = jax.vmap(env.step)(env_state, action)
    length = episode_length + 1
    terminal = next_state.done
    ended = (terminal > 0) | (length >= max_episode_steps)
    transitions = replay.Transitions(obs=env_state.obs, action=action, reward=next_state.reward,
                                     next_obs=next_state.obs, terminal=terminal)  # fmt: skip
    ep_return = episode_return + next_state.reward
    fresh = jax.lax.cond(jnp.any(ended), reset, lambda k: next_state, key)
    new_state = jax.tree.map(
        lambda a, b: jnp.where(ended.reshape((-1,) + (1,) * (a.ndim - 1)), a, b),
        fresh,
        next_state,
    )
    return EnvStep(
        transitions=transitions,
        env_state=new_state,
        episode_return=jnp.where(ended, 0.0, ep_return),
        episode_length=jnp.where(ended, 0, length),
        ended=ended,
        finished_return=jnp.sum(jnp.where(ended, ep_return, 0.0)),
    )


def make_trainer(config: TrainConfig) -> Trainer:
    """Builds the environment, agent and jitted functions for ``config``.

    ``algo`` "sac" is model-free (this module); "mbpo" and "mbmpo" are built by ``model_based``.
    """
    if config.algo != "sac":
        from minatt_jax.model_based import make_mb_trainer

        return make_mb_trainer(config)
    env = envs.make(config.env, config.physics)
    envs.check_task_set_name(config.task_set)
    task_set = envs.task_set(env, config.task_set)
    obs_dim, act_dim = env.observation_size, env.action_size
    ma_config = config.ma
    if ma_config.temporal == "rollout" and ma_config.temporal_dt == 1.0:
        ma_config = dataclasses.replace(ma_config, temporal_dt=env.dt)
    sac = make_sac(obs_dim, act_dim, config.sac, ma_config, config.caps)
    n = config.num_envs
    norm_on = config.sac.normalize_obs
    iterations = config.eval_every // n
    names = metric_names(ma_config, config.caps)

    def reset_envs(key: jax.Array) -> EnvState:
        k_task, k_reset = jax.random.split(key)
        tasks = jax.vmap(lambda k: envs.sample_task(k, task_set))(jax.random.split(k_task, n))
        return jax.vmap(env.reset)(jax.random.split(k_reset, n), tasks)

    @jax.jit
    def init_compiled(key: jax.Array) -> TrainState:
        k_agent, k_env, k_run = jax.random.split(key, 3)
        env_state = reset_envs(k_env)
        return TrainState(
            agent=sac.init(k_agent),
            buffer=replay.init_buffer(config.buffer_size, obs_dim, act_dim),
            env_state=env_state,
            normalizer=obs_norm.init_normalizer(obs_dim),
            ou_noise=jnp.zeros((n, act_dim)),
            episode_return=jnp.zeros((n,)),
            episode_length=jnp.zeros((n,), jnp.int32),
            rng=k_run,
            env_steps=jnp.zeros((), jnp.int32),
        )

    def init(key: jax.Array) -> TrainState:
        # Compiled (an eager MJX reset takes tens of seconds). Every leaf then gets its own
        # buffer: the state is donated to train_chunk, and donation fails when one buffer
        # appears twice (XLA may return one buffer for equal outputs). The copies stay
        # committed to the device, as jit keys its cache on committed-ness.
        ts = init_compiled(key)
        return jax.device_put(jax.tree.map(lambda x: jnp.array(x, copy=True), ts), jax.devices()[0])

    def act(ts: TrainState, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Exploration actions for every environment and the new OU state."""
        k_random, k_policy, k_ou = jax.random.split(key, 3)
        obs = obs_norm.normalize(ts.normalizer, ts.env_state.obs, norm_on)
        ou = ts.ou_noise
        if config.noise == "ou":
            ou = ou - config.ou_theta * ou + config.ou_sigma * jax.random.normal(k_ou, ou.shape)
            policy_action = jnp.clip(sac.control(ts.agent.actor_params, obs) + ou, -1.0, 1.0)
        else:
            keys = jax.random.split(k_policy, n)
            policy_action = jax.vmap(sac.sample, in_axes=(None, 0, 0))(
                ts.agent.actor_params, obs, keys
            )
        random_action = jax.random.uniform(k_random, (n, act_dim), minval=-1.0, maxval=1.0)
        warm = ts.env_steps < config.warmup_steps
        return jnp.where(warm, random_action, policy_action), ou

    def iteration(ts: TrainState, _: None) -> tuple[TrainState, dict]:
        rng, k_act, k_reset, k_update = jax.random.split(ts.rng, 4)
        action, ou = act(ts, k_act)
        s = env_step(env, ts.env_state, action, ts.episode_return, ts.episode_length,
                     config.max_episode_steps, reset_envs, k_reset)  # fmt: skip
        buffer = replay.insert(ts.buffer, s.transitions)
        next_obs = s.transitions.next_obs
        normalizer = obs_norm.update(ts.normalizer, next_obs) if norm_on else ts.normalizer
        ended, finished_return = s.ended, s.finished_return
        ts = ts.replace(
            buffer=buffer,
            env_state=s.env_state,
            normalizer=normalizer,
            ou_noise=jnp.where(ended[:, None], 0.0, ou),
            episode_return=s.episode_return,
            episode_length=s.episode_length,
            rng=rng,
            env_steps=ts.env_steps + n,
        )

        def do_updates(agent: SACState) -> tuple[SACState, dict]:
            def one(agent, key):
                k_batch, k_sac = jax.random.split(key)
                batch = replay.sample(buffer, k_batch, config.sac.batch_size)
                batch = batch.replace(
                    obs=obs_norm.normalize(normalizer, batch.obs, norm_on),
                    next_obs=obs_norm.normalize(normalizer, batch.next_obs, norm_on),
                )
                return sac.update(agent, batch, k_sac)

            keys = jax.random.split(k_update, config.updates_per_step)
            agent, metrics = jax.lax.scan(one, agent, keys)
            return agent, {k: jnp.mean(metrics[k]) for k in names}

        def skip(agent: SACState) -> tuple[SACState, dict]:
            return agent, {k: jnp.zeros(()) for k in names}

        ready = (ts.env_steps >= config.warmup_steps) & (buffer.size >= config.sac.batch_size)
        agent, update_metrics = jax.lax.cond(ready, do_updates, skip, ts.agent)
        ts = ts.replace(agent=agent)
        out = {
            **update_metrics,
            "updated": ready.astype(jnp.float32),
            "episodes_finished": jnp.sum(ended.astype(jnp.float32)),
            "finished_return_sum": finished_return,
        }
        return ts, out

    def train_chunk(ts: TrainState) -> tuple[TrainState, dict]:
        ts, metrics = jax.lax.scan(iteration, ts, None, length=iterations)
        return ts, summarize_chunk(metrics, names, config.updates_per_step)

    evaluator = make_evaluator(
        env, sac.control, config.max_episode_steps, norm_on, config.eval_episodes
    )

    def evaluate(ts: TrainState, key: jax.Array, tasks: envs.Task) -> EvalResult:
        return evaluator(ts.agent.actor_params, ts.normalizer, key, tasks)

    return Trainer(
        config=config,
        env=env,
        sac=sac,
        task_set=task_set,
        init=init,
        train_chunk=jax.jit(train_chunk, donate_argnums=0),
        evaluate=evaluate,
        steps_per_chunk=config.eval_every,
    )

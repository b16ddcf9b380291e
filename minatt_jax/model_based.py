"""Model-based training (``mbpo``) and MB-MPO meta-training (``mbmpo``) in one XLA program.

``make_mb_trainer(config)`` returns a :class:`minatt_jax.trainer.Trainer` like the SAC trainer;
its ``train_chunk`` scans ``eval_every`` iterations, each of which

1. takes one real env step (random actions during warm-up; then mbpo acts with the policy, mbmpo
   with the adapted policy of the episode's task slot) on a task of the run's task set (drawn at
   every reset) and stores the transition in the real buffer;
2. every ``model_train_every`` steps after warm-up (a ``lax.cond``): fits the dynamics ensemble
   on all real data, then rolls the policy out in the model from ``rollout_batch`` real start
   states, one slot per elite (each trajectory stays on one member), and stores the alive
   imagined transitions in that slot's model buffer;
3. ``agent_updates_per_step`` agent updates on batches of (1 - real_ratio) model and real_ratio
   real data: mbpo a SAC update (MA in the actor loss); mbmpo the meta step of ``maml`` with the
   slots as tasks (support and query batches from slot i's data, the batch split over tasks).

All of it, model fitting included, is one jitted function over one ``MBTrainState`` pytree, so
the run compiles once and a checkpoint of the state resumes it exactly.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import State as EnvState
from flax import struct

import minatt_jax.envs as envs
from minatt_jax import imagination, replay
from minatt_jax import normalizer as obs_norm
from minatt_jax.config import TrainConfig
from minatt_jax.dynamics_ensemble import EnsembleState, make_ensemble
from minatt_jax.envs.termination import TERMINATION_FNS
from minatt_jax.evaluation import EvalResult, make_evaluator
from minatt_jax.maml import Trajectories, make_meta_step
from minatt_jax.replay import Transitions
from minatt_jax.sac import SACState, make_sac, metric_names


@struct.dataclass
class MBTrainState:
    """Everything a model-based run needs to continue exactly (saved whole in checkpoints)."""

    agent: SACState
    ensemble: EnsembleState
    real: replay.ReplayBuffer
    model_buffer: replay.ReplayBuffer  # one ring buffer per slot, stacked (slots, capacity)
    adapted_actor: Any  # mbmpo: theta'_i per slot from the last meta step; mbpo: None
    env_state: EnvState  # batched over one environment
    normalizer: obs_norm.Normalizer  # unused (kept for the evaluator's interface)
    episode_return: jax.Array
    episode_length: jax.Array
    episode_slot: jax.Array  # mbmpo: which adapted policy acts in the current episode
    rng: jax.Array
    env_steps: jax.Array
    imagined: jax.Array  # total imagined transitions stored


def meta_metric_names(base: tuple[str, ...], outer: str = "sac") -> tuple[str, ...]:
    extra = ("trpo_accepted", "trpo_kl") if outer == "trpo" else ()
    return (*base, "meta_inner_loss", "meta_outer_loss", *extra)


def make_mb_trainer(config: TrainConfig):
    """Builds the model-based trainer (``config.algo`` in {"mbpo", "mbmpo"})."""
    from minatt_jax.trainer import Trainer, env_step, summarize_chunk  # shared with SAC

    mb, mcfg = config.mb, config.model
    meta = config.algo == "mbmpo"
    env = envs.make(config.env, config.physics)
    envs.check_task_set_name(config.task_set)
    task_set = envs.task_set(env, config.task_set)
    obs_dim, act_dim = env.observation_size, env.action_size
    ma_config = config.ma
    if ma_config.temporal == "rollout" and ma_config.temporal_dt == 1.0:
        ma_config = dataclasses.replace(ma_config, temporal_dt=env.dt)
    sac = make_sac(obs_dim, act_dim, config.sac, ma_config, config.caps)
    ensemble = make_ensemble(obs_dim, act_dim, mcfg)
    meta_step = make_meta_step(
        sac, mb.meta_inner_lr, mb.meta_first_order, mb.meta_inner, config.sac.gamma,
        outer=mb.meta_outer, max_kl=mb.trpo_max_kl,
    )  # fmt: skip
    termination = TERMINATION_FNS[config.env]
    slots = mcfg.num_elites
    per_slot = mb.rollout_batch // slots
    max_len = mb.rollout_schedule[3]
    slot_capacity = mb.model_buffer_size // slots
    batch = config.sac.batch_size
    n_real = int(round(mb.real_ratio * batch))
    n_model = batch - n_real
    # MB-MPO splits the agent batch over the tasks: each task's support and query batches hold
    # batch / slots transitions (at least 16), real_ratio of them real.
    task_batch_size = max(batch // slots, 16)
    t_real = int(round(mb.real_ratio * task_batch_size))
    t_model = task_batch_size - t_real
    names = metric_names(ma_config, config.caps)
    if meta:
        names = meta_metric_names(names, mb.meta_outer)
    iterations = config.eval_every

    def sample_task_reset(key: jax.Array) -> EnvState:
        k_task, k_reset = jax.random.split(key)
        tasks = jax.vmap(lambda k: envs.sample_task(k, task_set))(jax.random.split(k_task, 1))
        return jax.vmap(env.reset)(jax.random.split(k_reset, 1), tasks)

    @jax.jit
    def init_compiled(key: jax.Array) -> MBTrainState:
        k_agent, k_model, k_env, k_run = jax.random.split(key, 4)
        agent = sac.init(k_agent)
        adapted = None
        if meta:
            adapted = jax.tree.map(
                lambda p: jnp.broadcast_to(p, (slots, *p.shape)), agent.actor_params
            )
        return MBTrainState(
            agent=agent,
            ensemble=ensemble.init(k_model),
            real=replay.init_buffer(config.buffer_size, obs_dim, act_dim),
            model_buffer=imagination.init_slot_buffers(slots, slot_capacity, obs_dim, act_dim),
            adapted_actor=adapted,
            env_state=sample_task_reset(k_env),
            normalizer=obs_norm.init_normalizer(obs_dim),
            episode_return=jnp.zeros((1,)),
            episode_length=jnp.zeros((1,), jnp.int32),
            episode_slot=jnp.zeros((1,), jnp.int32),
            rng=k_run,
            env_steps=jnp.zeros((), jnp.int32),
            imagined=jnp.zeros((), jnp.int32),
        )

    def init(key: jax.Array) -> MBTrainState:
        # As the SAC trainer: compiled, and every leaf its own committed buffer (donation).
        ts = init_compiled(key)
        return jax.device_put(jax.tree.map(lambda x: jnp.array(x, copy=True), ts), jax.devices()[0])

    def rollout_length(env_steps: jax.Array) -> jax.Array:
        return jnp.asarray(mb.rollout_length(env_steps // mb.epoch_length), jnp.int32)

    def act(ts: MBTrainState, key: jax.Array) -> jax.Array:
        k_random, k_policy = jax.random.split(key)
        obs = ts.env_state.obs
        if meta:
            params = jax.tree.map(lambda p: p[ts.episode_slot[0]], ts.adapted_actor)
        else:
            params = ts.agent.actor_params
        policy_action = sac.sample(params, obs, k_policy)
        random_action = jax.random.uniform(k_random, (1, act_dim), minval=-1.0, maxval=1.0)
        return jnp.where(ts.env_steps < config.warmup_steps, random_action, policy_action)

    def refit(ts: MBTrainState, key: jax.Array) -> MBTrainState:
        ens_state, _ = ensemble.fit(ts.ensemble, ts.real.data, ts.real.size, key)
        return ts.replace(ensemble=ens_state)

    def imagine(ts: MBTrainState, key: jax.Array) -> tuple[MBTrainState, jax.Array]:
        k_start, k_roll = jax.random.split(key)
        ens_state = ts.ensemble
        idx = jax.random.randint(k_start, (slots, per_slot), 0, jnp.maximum(ts.real.size, 1))
        start = ts.real.data.obs[idx]
        rollouts, alive = imagination.imagine(
            ensemble, ens_state, ens_state.elites, sac.sample, ts.agent.actor_params,
            termination, start, rollout_length(ts.env_steps), max_len, k_roll, mb.obs_clip,
        )  # fmt: skip
        model_buffer = imagination.insert_rollouts(ts.model_buffer, rollouts, alive)
        count = jnp.sum(alive).astype(jnp.int32)
        return ts.replace(model_buffer=model_buffer, imagined=ts.imagined + count), count

    def refit_and_imagine(ts: MBTrainState, key: jax.Array) -> tuple[MBTrainState, jax.Array]:
        k_fit, k_imagine = jax.random.split(key)
        return imagine(refit(ts, k_fit), k_imagine)

    def mixed(model_part: Transitions, real_part: Transitions) -> Transitions:
        return jax.tree.map(lambda a, b: jnp.concatenate([a, b], 0), model_part, real_part)

    def agent_update(ts: MBTrainState, key: jax.Array) -> tuple[MBTrainState, dict]:
        k_model, k_real, k_tasks, k_update = jax.random.split(key, 4)
        critic_batch = mixed(
            imagination.sample_all_slots(ts.model_buffer, k_model, n_model),
            replay.sample(ts.real, k_real, n_real),
        )
        if not meta:
            agent, metrics = sac.update(ts.agent, critic_batch, k_update)
            return ts.replace(agent=agent), {k: metrics[k] for k in names}

        def task_batch(slot, key):
            k_m, k_r = jax.random.split(key)
            return mixed(
                imagination.sample_slot(ts.model_buffer, slot, k_m, t_model),
                replay.sample(ts.real, k_r, t_real),
            )

        task_keys = jax.random.split(k_tasks, 2 * slots).reshape(2, slots, -1)
        if mb.meta_inner == "vpg":
            # Fresh trajectories of the current policy in each task's model (REINFORCE data).
            k_start, k_roll = jax.random.split(task_keys[0, 0])
            idx = jax.random.randint(
                k_start, (slots, task_batch_size), 0, jnp.maximum(ts.real.size, 1)
            )
            data, alive = imagination.imagine(
                ensemble, ts.ensemble, ts.ensemble.elites, sac.sample, ts.agent.actor_params,
                termination, ts.real.data.obs[idx], jnp.asarray(mb.vpg_horizon), mb.vpg_horizon,
                k_roll, mb.obs_clip,
            )  # fmt: skip
            supports = Trajectories(data=data, alive=alive)
        else:
            supports = jax.vmap(task_batch)(jnp.arange(slots), task_keys[0])
        queries = jax.vmap(task_batch)(jnp.arange(slots), task_keys[1])
        agent, adapted, metrics = meta_step.update(
            ts.agent, critic_batch, supports, queries, k_update
        )
        return ts.replace(agent=agent, adapted_actor=adapted), {k: metrics[k] for k in names}

    def iteration(ts: MBTrainState, _: None) -> tuple[MBTrainState, dict]:
        rng, k_act, k_reset, k_slot, k_model, k_update = jax.random.split(ts.rng, 6)
        action = act(ts, k_act)
        s = env_step(env, ts.env_state, action, ts.episode_return, ts.episode_length,
                     config.max_episode_steps, sample_task_reset, k_reset)  # fmt: skip
        ended = s.ended
        new_slot = jax.random.randint(k_slot, (1,), 0, slots)
        steps = ts.env_steps + 1
        ts = ts.replace(
            real=replay.insert(ts.real, s.transitions),
            env_state=s.env_state,
            episode_return=s.episode_return,
            episode_length=s.episode_length,
            episode_slot=jnp.where(ended, new_slot, ts.episode_slot),
            rng=rng,
            env_steps=steps,
        )
        due = (steps >= config.warmup_steps) & (steps % mb.model_train_every == 0)
        ts, imagined = jax.lax.cond(
            due, refit_and_imagine, lambda t, k: (t, jnp.zeros((), jnp.int32)), ts, k_model
        )
        ready = (steps >= config.warmup_steps) & (jnp.sum(ts.model_buffer.size) > 0)

        def do_updates(ts: MBTrainState) -> tuple[MBTrainState, dict]:
            keys = jax.random.split(k_update, mb.agent_updates_per_step)
            ts, metrics = jax.lax.scan(agent_update, ts, keys)
            return ts, {k: jnp.mean(v) for k, v in metrics.items()}

        def skip(ts: MBTrainState) -> tuple[MBTrainState, dict]:
            return ts, {k: jnp.zeros(()) for k in names}

        ts, update_metrics = jax.lax.cond(ready, do_updates, skip, ts)
        out = {
            **update_metrics,
            "updated": ready.astype(jnp.float32),
            "refit": due.astype(jnp.float32),
            "imagined": imagined.astype(jnp.float32),
            "episodes_finished": jnp.sum(ended.astype(jnp.float32)),
            "finished_return_sum": s.finished_return,
        }
        return ts, out

    def train_chunk(ts: MBTrainState) -> tuple[MBTrainState, dict]:
        ts, metrics = jax.lax.scan(iteration, ts, None, length=iterations)
        summary = summarize_chunk(metrics, names, mb.agent_updates_per_step)
        summary["model_fits"] = jnp.sum(metrics["refit"])
        summary["imagined_transitions"] = jnp.sum(metrics["imagined"])
        summary["rollout_length"] = rollout_length(ts.env_steps).astype(jnp.float32)
        summary["model_holdout_mse"] = jnp.mean(ts.ensemble.holdout_mse[ts.ensemble.elites])
        summary["model_holdout_mse_members"] = ts.ensemble.holdout_mse
        summary["model_elites"] = ts.ensemble.elites
        summary["model_epochs"] = ts.ensemble.last_epochs.astype(jnp.float32)
        summary["model_buffer_size"] = jnp.sum(ts.model_buffer.size).astype(jnp.float32)
        return ts, summary

    evaluator = make_evaluator(env, sac.control, config.max_episode_steps, False,
                               config.eval_episodes)  # fmt: skip

    def evaluate(ts: MBTrainState, key: jax.Array, tasks: envs.Task) -> EvalResult:
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
        parts={"refit": refit, "imagine": imagine, "agent_update": agent_update},
    )

"""One training program for every algorithm (sac, mbpo, mbmpo), composed of stages.

``make_train(config)`` returns a :class:`Trainer` whose pure functions are

* ``init(key) -> TrainState``: one nested pytree (agent, collector, data, model, meta, counters);
* ``train_chunk(state) -> (state, metrics)``: ``eval_every / num_envs`` iterations in one
  ``lax.scan``, compiled once. Each iteration runs the stages

  1. **collect** (``acting.collect_step``): exploration actions (random during warm-up, then the
     policy's own sampling or OU noise on its control; mbmpo acts with the adapted policy of each
     episode's task slot), one step of every environment, episode bookkeeping and resets with a
     task drawn from the run's task set;
  2. **store**: the transitions into the real replay buffer, the observation statistics;
  3. **model phase** (mbpo, mbmpo): every ``model_train_every`` env steps after warm-up, fit the
     dynamics ensemble on the real data, roll the policy out in it from real start states (one
     slot per elite: each trajectory stays on one member) and insert the alive imagined
     transitions into that slot's model buffer;
  4. **agent update**: ``updates_per_step`` updates on batches from the replay (sac) or from the
     95% model / 5% real mix (mbpo: a SAC update; mbmpo: the MAML meta step of ``maml`` with the
     slots as tasks, in the same slot of the program).

  Warm-up gating, the model refit and the updates are ``lax.cond``s on the unbatched step
  counter, so the same program runs before and after them;
* ``evaluate(state, key, tasks) -> EvalResult``: deterministic episodes (``evaluation``).

Observation normalization (``sac.normalize_obs``) applies to what the agent sees in every
algorithm: acting, the agent's batches and the policy inside imagined rollouts; the dynamics
model and the termination functions work on raw observations.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import State as EnvState
from flax import struct

import minatt_jax.envs as envs
from minatt_jax import acting, imagination, replay
from minatt_jax import min_attention as ma
from minatt_jax import normalizer as obs_norm
from minatt_jax.config import TrainConfig, replace_fields
from minatt_jax.dynamics_ensemble import Ensemble, EnsembleState, make_ensemble
from minatt_jax.evaluation import EvalResult, deterministic_of, make_evaluator
from minatt_jax.maml import MetaStep, Trajectories, make_meta_step
from minatt_jax.replay import Transitions
from minatt_jax.sac import SAC, SACState, make_sac


@struct.dataclass
class Collector:
    """The training environments and their episode bookkeeping (batched over ``num_envs``)."""

    env_state: EnvState
    episode_return: jax.Array  # (num_envs,) running returns of the current episodes
    episode_length: jax.Array  # (num_envs,)
    episode_slot: jax.Array  # (num_envs,) mbmpo: the adapted policy acting in the episode
    ou_noise: jax.Array  # (num_envs, act_dim) OU exploration noise state
    discounted_return: jax.Array | None = None  # (num_envs,) reward normalization; else None


@struct.dataclass
class Data:
    """What has been collected or imagined, and the observation statistics."""

    real: replay.ReplayBuffer
    model: replay.ReplayBuffer | None  # per-slot buffers (slots, capacity); None for sac
    normalizer: obs_norm.Normalizer
    return_stats: obs_norm.Normalizer | None = None  # discounted-return variance; None when off


@struct.dataclass
class MetaState:
    """MB-MPO's adapted policies and its inner step size (data: populations sweep it)."""

    adapted: Any  # theta'_i per slot (slots, ...) from the last meta step
    inner_lr: jax.Array  # beta of theta' = theta - beta grad L_i(theta)


@struct.dataclass
class TrainState:
    """Everything a run needs to continue exactly: saved whole, item by item, in checkpoints."""

    agent: SACState
    collector: Collector
    data: Data
    model: EnsembleState | None  # the dynamics ensemble (mbpo, mbmpo)
    meta: MetaState | None  # mbmpo only
    rng: jax.Array
    env_steps: jax.Array  # total env steps taken (all environments)
    imagined: jax.Array  # total imagined transitions stored

    def parameter_groups(self) -> dict[str, Any]:
        """The parameters checked for non-finite values after every chunk."""
        groups = {"actor parameters": self.agent.actor_params,
                  "critic parameters": self.agent.critic_params}  # fmt: skip
        if self.model is not None:
            groups["model parameters"] = self.model.params
        return groups

    def policy_items(self) -> tuple[Any, Any]:
        """What a policy snapshot holds: the actor's parameters and the observation normalizer."""
        return self.agent.actor_params, self.data.normalizer

    def with_data(self, values: dict[str, jax.Array]) -> TrainState:
        """This state with its data fields (MA weight, learning rates, inner step) set."""

        def lr(opt_state: Any, value: jax.Array) -> Any:
            hyper = dict(opt_state.hyperparams)
            hyper["learning_rate"] = jnp.asarray(value, hyper["learning_rate"].dtype)
            return opt_state._replace(hyperparams=hyper)

        agent = self.agent.replace(
            ma_alpha=values["ma.alpha"],
            ma_terms=values["ma.terms"],
            actor_opt=lr(self.agent.actor_opt, values["sac.actor_lr"]),
            critic_opt=lr(self.agent.critic_opt, values["sac.critic_lr"]),
            entropy_opt=lr(self.agent.entropy_opt, values["sac.entropy_lr"]),
        )
        meta = self.meta
        if meta is not None:
            meta = meta.replace(inner_lr=values["mb.meta_inner_lr"])
        return self.replace(agent=agent, meta=meta)


class Trainer(NamedTuple):
    """The pure functions of a training run, and what they were built from."""

    config: TrainConfig
    env: envs.LocomotionEnv
    sac: SAC | None  # None for dreamer (its learner is parts["agent"])
    task_set: envs.Task
    init: Callable[[jax.Array], TrainState]
    train_chunk: Callable[[TrainState], tuple[TrainState, dict]]
    evaluate: Callable[[TrainState, jax.Array, envs.Task], EvalResult]
    steps_per_chunk: int
    ensemble: Ensemble | None
    meta_step: MetaStep | None
    # Stages on a whole state, (state, key) -> state or (state, out), for timing breakdowns.
    parts: dict[str, Callable]


def make_agent(config: TrainConfig, env: envs.LocomotionEnv) -> SAC:
    """The SAC agent of a (resolved) configuration for ``env``."""
    return make_sac(env.observation_size, env.action_size, config.sac, config.ma, config.caps)


def make_meta(config: TrainConfig, sac: SAC) -> MetaStep:
    """The MB-MPO meta step of a (resolved) configuration: its own inner and outer steps."""
    mb = config.mb
    return make_meta_step(sac, mb.meta_inner_lr, mb.meta_first_order, mb.meta_inner,
                          config.sac.gamma, outer=mb.meta_outer, max_kl=mb.trpo_max_kl)  # fmt: skip


# Configuration fields that live in the train state as data (per-member values in a
# population; changeable on resume): changing them never recompiles the program.
DATA_FIELDS = ("seed", "ma.alpha", "sac.actor_lr", "sac.critic_lr", "sac.entropy_lr",
               "mb.meta_inner_lr")  # fmt: skip


def config_field(config: TrainConfig, dotted: str) -> Any:
    """The value of a dotted field name (``"ma.alpha"``) of a configuration."""
    value: Any = config
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def data_values(config: TrainConfig) -> dict[str, np.ndarray]:
    """The member's values of the data fields that live in the train state (float32), and
    ``"ma.terms"``: its MA mode's (feedback, temporal) weights (``min_attention.term_weights``),
    data to a population whose members differ in mode (a run's own program computes its mode's
    terms alone, so a resume does not change the mode)."""
    values = {k: np.float32(config_field(config, k)) for k in DATA_FIELDS if k != "seed"}
    values["ma.terms"] = np.asarray(ma.term_weights(config.ma.mode), np.float32)
    return values


def program_config(config: TrainConfig) -> TrainConfig:
    """The configuration with its data fields at fixed values: equal for runs and population
    members that can share one compiled program. The MA mode is data too (``data_values``'
    ``"ma.terms"``) to a population, which computes the union of its members' terms."""
    fixed = {"seed": 0, "ma.alpha": 0.0, "ma.mode": "full", "sac.actor_lr": 1.0,
             "sac.critic_lr": 1.0, "sac.entropy_lr": 1.0, "mb.meta_inner_lr": 0.0}  # fmt: skip
    return replace_fields(config, fixed)


def run_program_config(config: TrainConfig) -> TrainConfig:
    """The configuration a single run's program is built from: ``program_config`` but for the
    MA mode and whether MA is on (a run computes its own mode's terms alone, none at alpha 0),
    and a fixed length (the runner's loop reads it, the program does not). Runs that differ in
    seed, length or data values (``data_values``, set after ``init``) share it."""
    on = {"ma.alpha": 1.0 if config.ma.active else 0.0, "ma.mode": config.ma.mode,
          "total_steps": 1}  # fmt: skip
    return replace_fields(program_config(config), on)


def with_data(state: Any, values: dict[str, jax.Array]) -> Any:
    """A member's state with its data fields set (each algorithm's state knows where)."""
    return state.with_data(values)


def training_tasks(config: TrainConfig, env: envs.LocomotionEnv) -> envs.Task:
    """The stacked tasks a run trains on: its custom ``tasks`` or its named ``task_set``."""
    tasks, _ = envs.resolve_tasks(env, config.task_set, config.tasks)
    return envs.stack_tasks(tasks)


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
    # Simulator steps that went non-finite, were reset and not learned from.
    summary["env_non_finite_resets"] = jnp.sum(metrics["env_non_finite"])
    summary["updates"] = jnp.sum(metrics["updated"]) * updates_per_step
    return summary


def scan_iterations(
    iteration: Callable[[Any, jax.Array, str | None], tuple[Any, dict]],
    ts: Any,
    start: jax.Array,
    steps_per_iteration: int,
    iterations: int,
    members: bool,
) -> tuple[Any, dict]:
    """``iterations`` calls of ``iteration(state, env_step, members_axis)`` from env step
    ``start``, in one ``lax.scan``; returns the state and the per-iteration metrics. The env step
    is unbatched, so the schedule's ``lax.cond``s stay branches. With ``members`` the state has a
    leading population axis: each iteration is vmapped over it (axis name ``"members"``, which
    the resets' predicate is reduced over) and the metrics come back member-first."""
    if members:
        step = jax.vmap(lambda t, s: iteration(t, s, "members"), in_axes=(0, None),
                        axis_name="members")  # fmt: skip
    else:
        step = lambda t, s: iteration(t, s, None)  # noqa: E731

    def body(state: Any, i: jax.Array) -> tuple[Any, dict]:
        return step(state, start + i * steps_per_iteration)

    ts, metrics = jax.lax.scan(body, ts, jnp.arange(iterations, dtype=jnp.int32))
    if members:
        metrics = jax.tree.map(lambda x: jnp.moveaxis(x, 0, 1), metrics)
    return ts, metrics


def make_train(config: TrainConfig) -> Trainer:
    """Builds the environment, agent, optional model and meta step, and the jitted stages."""
    if not config.is_resolved:
        raise ValueError("make_train needs a resolved configuration: call config.resolve first")
    if config.algo == "dreamer":
        from minatt_jax.dreamer.training import make_dreamer_train

        return make_dreamer_train(config)
    env = envs.make(config.env, config.physics)
    task_set = training_tasks(config, env)
    obs_dim, act_dim = env.observation_size, env.action_size
    sac = make_agent(config, env)
    model_based, meta = config.model_based, config.algo == "mbmpo"
    mb = config.mb
    n = config.num_envs
    norm_on = config.sac.normalize_obs
    reward_norm = config.sac.normalize_reward
    batch = config.sac.batch_size
    ensemble = make_ensemble(obs_dim, act_dim, config.model) if model_based else None
    meta_step = make_meta(config, sac) if meta else None
    slots = config.model.num_elites
    per_slot = mb.rollout_batch // slots
    max_len = mb.rollout_schedule[3]
    real_count = int(round(mb.real_ratio * batch))
    # MB-MPO splits the agent batch over the tasks: each task's support and query batches hold
    # batch / slots transitions (at least 16), real_ratio of them real.
    task_batch = max(batch // slots, 16)
    task_real = int(round(mb.real_ratio * task_batch))

    def normalize(norm: obs_norm.Normalizer, obs: jax.Array) -> jax.Array:
        return obs_norm.normalize(norm, obs, norm_on)

    def normalize_batch(data: Data, b: Transitions) -> Transitions:
        """What the agent learns from: normalized observations (``normalize_obs``) and
        rewards on the return's running scale (``normalize_reward``)."""
        norm = data.normalizer
        return b.replace(obs=normalize(norm, b.obs), next_obs=normalize(norm, b.next_obs),
                         reward=obs_norm.scale_reward(data.return_stats, b.reward))  # fmt: skip

    def reset_envs(key: jax.Array) -> EnvState:
        return acting.reset_with_tasks(env, task_set, n, key)

    @jax.jit
    def init_compiled(key: jax.Array) -> TrainState:
        if model_based:
            k_agent, k_model, k_env, k_run = jax.random.split(key, 4)
        else:
            (k_agent, k_env, k_run), k_model = jax.random.split(key, 3), None
        agent = sac.init(k_agent)
        meta_state = None
        if meta:
            adapted = jax.tree.map(
                lambda p: jnp.broadcast_to(p, (slots, *p.shape)), agent.actor_params
            )
            meta_state = MetaState(adapted, jnp.asarray(mb.meta_inner_lr, jnp.float32))
        model_buffer = None
        if model_based:
            capacity = mb.model_buffer_size // slots
            model_buffer = replay.init_slot_buffers(slots, capacity, obs_dim, act_dim)
        return TrainState(
            agent=agent,
            collector=Collector(
                env_state=reset_envs(k_env),
                episode_return=jnp.zeros((n,)),
                episode_length=jnp.zeros((n,), jnp.int32),
                episode_slot=jnp.zeros((n,), jnp.int32),
                ou_noise=jnp.zeros((n, act_dim)),
                discounted_return=jnp.zeros((n,)) if reward_norm else None,
            ),
            data=Data(
                real=replay.init_buffer(config.buffer_size, obs_dim, act_dim),
                model=model_buffer,
                normalizer=obs_norm.init_normalizer(obs_dim),
                return_stats=obs_norm.init_normalizer(1) if reward_norm else None,
            ),
            model=ensemble.init(k_model) if model_based else None,
            meta=meta_state,
            rng=k_run,
            env_steps=jnp.zeros((), jnp.int32),
            imagined=jnp.zeros((), jnp.int32),
        )

    def init(key: jax.Array) -> TrainState:
        # Compiled (an eager MJX reset takes tens of seconds). Every leaf then gets its own
        # buffer: the state is donated to train_chunk, and donation fails when one buffer
        # appears twice (XLA may return one buffer for equal outputs). The copies stay
        # committed to the device, as jit keys its cache on committed-ness.
        ts = init_compiled(key)
        return jax.device_put(jax.tree.map(lambda x: jnp.array(x, copy=True), ts), jax.devices()[0])

    # ---- collect --------------------------------------------------------------------------
    def act(ts: TrainState, key: jax.Array, steps: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Exploration actions for every environment and the new OU state (``steps``: env steps
        taken before this one, the unbatched schedule counter)."""
        k_random, k_policy, k_ou = jax.random.split(key, 3)
        c = ts.collector
        obs = normalize(ts.data.normalizer, c.env_state.obs)
        if meta:  # each episode acts with its slot's adapted policy
            params = jax.tree.map(lambda p: p[c.episode_slot], ts.meta.adapted)
            axis = 0
        else:
            params, axis = ts.agent.actor_params, None
        ou = c.ou_noise
        if config.noise == "ou":
            ou = ou - config.ou_theta * ou + config.ou_sigma * jax.random.normal(k_ou, ou.shape)
            control = jax.vmap(sac.control, in_axes=(axis, 0))(params, obs)
            policy_action = jnp.clip(control + ou, -1.0, 1.0)
        else:
            keys = jax.random.split(k_policy, n)
            policy_action = jax.vmap(sac.sample, in_axes=(axis, 0, 0))(params, obs, keys)
        random_action = jax.random.uniform(k_random, (n, act_dim), minval=-1.0, maxval=1.0)
        warm = steps < config.warmup_steps
        return jnp.where(warm, random_action, policy_action), ou

    def collect(
        ts: TrainState, keys: tuple[jax.Array, ...], steps: jax.Array, members_axis: str | None
    ) -> tuple[TrainState, acting.CollectStep]:
        k_act, k_reset, k_slot = keys
        action, ou = act(ts, k_act, steps)
        c = ts.collector
        s = acting.collect_step(env, c.env_state, action, c.episode_return, c.episode_length,
                                config.max_episode_steps, reset_envs, k_reset,
                                members_axis)  # fmt: skip
        slot = c.episode_slot
        if meta:
            slot = jnp.where(s.ended, jax.random.randint(k_slot, (n,), 0, slots), slot)
        disc = c.discounted_return
        if reward_norm:  # the return G <- gamma G + r, zeroed after an episode's last step
            disc = config.sac.gamma * disc + jnp.where(s.finite, s.transitions.reward, 0.0)
        collector = Collector(
            env_state=s.env_state,
            episode_return=s.episode_return,
            episode_length=s.episode_length,
            episode_slot=slot,
            ou_noise=jnp.where(s.ended[:, None], 0.0, ou),
            discounted_return=disc,
        )
        ts = ts.replace(collector=collector, env_steps=ts.env_steps + n)
        if reward_norm:
            stats = obs_norm.update(ts.data.return_stats, disc[:, None])
            collector = collector.replace(discounted_return=jnp.where(s.ended, 0.0, disc))
            ts = ts.replace(collector=collector, data=ts.data.replace(return_stats=stats))
        return ts, s

    # ---- store ----------------------------------------------------------------------------
    def store(data: Data, transitions: Transitions, finite: jax.Array) -> Data:
        """Stores the finite transitions (a non-finite simulator step is never learned from)."""
        normalizer = data.normalizer
        if norm_on:
            updated = obs_norm.update(normalizer, transitions.next_obs)
            normalizer = jax.tree.map(lambda a, b: jnp.where(jnp.all(finite), a, b),
                                      updated, normalizer)  # fmt: skip
        real = replay.insert_masked(data.real, transitions, finite.astype(jnp.float32))
        return data.replace(real=real, normalizer=normalizer)

    # ---- model phase ----------------------------------------------------------------------
    def rollout_length(env_steps: jax.Array) -> jax.Array:
        return jnp.asarray(mb.rollout_length(env_steps // mb.epoch_length), jnp.int32)

    def imagined_policy(norm: obs_norm.Normalizer) -> Callable:
        return lambda params, obs, key: sac.sample(params, normalize(norm, obs), key)

    def refit(ts: TrainState, key: jax.Array) -> TrainState:
        model, _ = ensemble.fit(ts.model, ts.data.real.data, ts.data.real.size, key)
        return ts.replace(model=model)

    def imagine(
        ts: TrainState, key: jax.Array, steps: jax.Array | None = None
    ) -> tuple[TrainState, jax.Array]:
        steps = ts.env_steps if steps is None else steps
        k_start, k_roll = jax.random.split(key)
        real = ts.data.real
        idx = jax.random.randint(k_start, (slots, per_slot), 0, jnp.maximum(real.size, 1))
        rollouts, alive = imagination.imagine(
            ensemble, ts.model, ts.model.elites, imagined_policy(ts.data.normalizer),
            ts.agent.actor_params, env.terminated, real.data.obs[idx],
            rollout_length(steps), max_len, k_roll, mb.obs_clip,
        )  # fmt: skip
        model_buffer = replay.insert_slots(ts.data.model, rollouts, alive)
        count = jnp.sum(alive).astype(jnp.int32)
        ts = ts.replace(data=ts.data.replace(model=model_buffer), imagined=ts.imagined + count)
        return ts, count

    def model_phase(
        ts: TrainState, key: jax.Array, steps: jax.Array
    ) -> tuple[TrainState, jax.Array]:
        k_fit, k_imagine = jax.random.split(key)
        return imagine(refit(ts, k_fit), k_imagine, steps)

    def model_due(steps: jax.Array) -> jax.Array:
        """A refit is due when the last step crossed a multiple of ``model_train_every``."""
        crossed = steps // mb.model_train_every > (steps - n) // mb.model_train_every
        return (steps >= config.warmup_steps) & crossed

    # ---- agent update ---------------------------------------------------------------------
    def meta_tasks(ts: TrainState, key: jax.Array) -> tuple[Any, Transitions]:
        """Support and query data per task (slot): mixed batches, or VPG trajectories."""
        data, norm = ts.data, ts.data.normalizer
        k_support, k_query = jax.random.split(key)

        def slot_batch(slot, k):
            b = replay.sample_mixed(data.model, data.real, k, task_batch, task_real, slot)
            return normalize_batch(data, b)

        queries = jax.vmap(slot_batch)(jnp.arange(slots), jax.random.split(k_query, slots))
        if mb.meta_inner == "vpg":
            # Fresh trajectories of the current policy in each task's model (REINFORCE data).
            k_start, k_roll = jax.random.split(k_support)
            idx = jax.random.randint(k_start, (slots, task_batch), 0,
                                     jnp.maximum(data.real.size, 1))  # fmt: skip
            rollouts, alive = imagination.imagine(
                ensemble, ts.model, ts.model.elites, imagined_policy(norm), ts.agent.actor_params,
                env.terminated, data.real.data.obs[idx], jnp.asarray(mb.vpg_horizon),
                mb.vpg_horizon, k_roll, mb.obs_clip,
            )  # fmt: skip
            return Trajectories(data=normalize_batch(data, rollouts), alive=alive), queries
        supports = jax.vmap(slot_batch)(jnp.arange(slots), jax.random.split(k_support, slots))
        return supports, queries

    def agent_update(ts: TrainState, key: jax.Array) -> tuple[TrainState, dict]:
        """One agent update: SAC on replay or mixed data, or the MB-MPO meta step."""
        k_batch, k_update = jax.random.split(key)
        data = ts.data
        if model_based:
            k_batch, k_tasks = jax.random.split(k_batch)
            b = replay.sample_mixed(data.model, data.real, k_batch, batch, real_count)
        else:
            b = replay.sample(data.real, k_batch, batch)
        b = normalize_batch(data, b)
        if not meta:
            agent, metrics = sac.update(ts.agent, b, k_update)
            return ts.replace(agent=agent), metrics
        supports, queries = meta_tasks(ts, k_tasks)
        agent, adapted, metrics = meta_step.update(
            ts.agent, b, supports, queries, k_update, ts.meta.inner_lr
        )
        return ts.replace(agent=agent, meta=ts.meta.replace(adapted=adapted)), metrics

    # The schedule is a function of the env-step counter alone, so that in a population (all
    # members at the same step) every predicate is unbatched and its lax.cond stays a branch.
    every = mb.model_train_every
    first_fit = -(-max(-(-config.warmup_steps // every), 1) * every // n) * n

    def updates_ready(steps: jax.Array) -> jax.Array:
        """Updates start after warm-up once there is data to sample: a full batch of real
        transitions (sac) or the first model phase (mbpo, mbmpo)."""
        if model_based:
            return steps >= first_fit
        return (steps >= config.warmup_steps) & (jnp.minimum(steps, config.buffer_size) >= batch)

    # Metric names come from the update itself (its output structure), not a hand-kept list.
    abstract = jax.eval_shape(init_compiled, jax.random.PRNGKey(0))
    names = tuple(jax.eval_shape(agent_update, abstract, jax.random.PRNGKey(0))[1])

    def update_agent(ts: TrainState, key: jax.Array, steps: jax.Array) -> tuple[TrainState, dict]:
        def do_updates(ts: TrainState) -> tuple[TrainState, dict]:
            keys = jax.random.split(key, config.updates_per_step)
            ts, metrics = jax.lax.scan(agent_update, ts, keys)
            return ts, {k: jnp.mean(metrics[k]) for k in names}

        def skip(ts: TrainState) -> tuple[TrainState, dict]:
            return ts, {k: jnp.zeros(()) for k in names}

        ready = updates_ready(steps)
        ts, metrics = jax.lax.cond(ready, do_updates, skip, ts)
        return ts, {**metrics, "updated": ready.astype(jnp.float32)}

    # ---- one iteration, one chunk ---------------------------------------------------------
    def iteration(
        ts: TrainState, steps_before: jax.Array, members_axis: str | None = None
    ) -> tuple[TrainState, dict]:
        """One env step of every environment, storage, the model phase when due and the agent
        updates; ``steps_before`` is the (unbatched) env-step counter before the step."""
        if model_based:
            rng, k_act, k_reset, k_slot, k_model, k_update = jax.random.split(ts.rng, 6)
        else:
            rng, k_act, k_reset, k_update = jax.random.split(ts.rng, 4)
            k_slot = k_model = None
        ts = ts.replace(rng=rng)
        ts, s = collect(ts, (k_act, k_reset, k_slot), steps_before, members_axis)
        ts = ts.replace(data=store(ts.data, s.transitions, s.finite))
        steps = steps_before + n
        out = {}
        if model_based:
            due = model_due(steps)
            ts, imagined = jax.lax.cond(
                due,
                model_phase,
                lambda t, k, s: (t, jnp.zeros((), jnp.int32)),
                ts, k_model, steps,
            )  # fmt: skip
            out = {"refit": due.astype(jnp.float32), "imagined": imagined.astype(jnp.float32)}
        ts, update_metrics = update_agent(ts, k_update, steps)
        out.update(
            update_metrics,
            episodes_finished=jnp.sum((s.ended & s.finite).astype(jnp.float32)),
            finished_return_sum=s.finished_return,
            env_non_finite=jnp.sum((~s.finite).astype(jnp.float32)),
        )
        return ts, out

    iterations = config.eval_every // n

    def chunk_summary(ts: TrainState, metrics: dict) -> dict:
        """One member's chunk metrics (per-iteration outputs -> summary)."""
        summary = summarize_chunk(metrics, names, config.updates_per_step)
        if model_based:
            model = ts.model
            summary["model_fits"] = jnp.sum(metrics["refit"])
            summary["imagined_transitions"] = jnp.sum(metrics["imagined"])
            summary["rollout_length"] = rollout_length(ts.env_steps).astype(jnp.float32)
            summary["model_holdout_mse"] = jnp.mean(model.holdout_mse[model.elites])
            summary["model_holdout_mse_members"] = model.holdout_mse
            summary["model_elites"] = model.elites
            summary["model_epochs"] = model.last_epochs.astype(jnp.float32)
            summary["model_buffer_size"] = jnp.sum(ts.data.model.size).astype(jnp.float32)
        return summary

    def run_chunk(ts: TrainState, start: jax.Array, members: bool) -> tuple[TrainState, dict]:
        """``iterations`` iterations from env step ``start`` (``scan_iterations``)."""
        ts, metrics = scan_iterations(iteration, ts, start, n, iterations, members)
        return ts, (jax.vmap(chunk_summary) if members else chunk_summary)(ts, metrics)

    def train_chunk(ts: TrainState) -> tuple[TrainState, dict]:
        return run_chunk(ts, ts.env_steps, members=False)

    evaluator = make_evaluator(env, deterministic_of(sac.control, norm_on),
                               config.max_episode_steps, config.eval_episodes)  # fmt: skip

    def evaluate(ts: TrainState, key: jax.Array, tasks: envs.Task) -> EvalResult:
        return evaluator(ts.agent.actor_params, ts.data.normalizer, key, tasks)

    parts: dict[str, Callable] = {
        "agent_update": agent_update,
        "run_chunk": run_chunk,
        "init_state": init_compiled,
    }
    if model_based:
        parts.update(refit=refit, imagine=imagine)
    return Trainer(
        config=config,
        env=env,
        sac=sac,
        task_set=task_set,
        init=init,
        train_chunk=jax.jit(train_chunk, donate_argnums=0),
        evaluate=evaluate,
        steps_per_chunk=config.eval_every,
        ensemble=ensemble,
        meta_step=meta_step,
        parts=parts,
    )

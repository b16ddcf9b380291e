"""``--algo sac``: soft actor-critic with minimum attention, and the off-policy building blocks that
the model-based agents (``mbpo``, ``mbmpo``) compose with their model phase.

One iteration of the training program, for all ``num_envs`` environments at once:

* **collect**: exploration actions (random during warm-up, then the policy's own sampling or OU
  noise on its control), one step of every environment through ``acting.collect_step``
  (episode bookkeeping, resets with a task drawn from the run's task set);
* **store**: the finite transitions into the real replay, the observation statistics;
* **update**: ``updates_per_step`` SAC updates (``minatt_jax.sac``) on replay batches once
  warm-up is over and a batch is there; a ``lax.cond`` on the unbatched step counter.

Observation normalization (``sac.normalize_obs``) applies to what the agent sees: acting, its
batches and the policy inside imagined rollouts; the dynamics model and the termination functions
of the model-based agents work on raw observations.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from brax.envs.base import State as EnvState
from flax import struct

from minatt_jax import acting, replay
from minatt_jax import normalizer as obs_norm
from minatt_jax.agents import registry
from minatt_jax.agents.base import (
    Adapter,
    Agent,
    NumpyForm,
    PolicyFamily,
    abstract_hyper,
    mlp_numpy_form,
    zeros_like_shapes,
)
from minatt_jax.evaluation import deterministic_of
from minatt_jax.replay import Transitions
from minatt_jax.sac import HYPER, SAC, SACConfig, make_sac

# The SAC settings group (sac, mbpo and mbmpo own it); the smoke preset's networks are small.
SAC_SETTINGS = registry.SettingsGroup(
    "sac", SACConfig, presets={"smoke": {"hidden": (32, 32), "batch_size": 64}}
)


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
    """MB-MPO's adapted policies theta'_i per slot (slots, ...) from the last meta step."""

    adapted: Any


@struct.dataclass
class TrainState:
    """Everything an off-policy run needs to continue exactly: saved whole, item by item."""

    agent: Any  # SACState (its ``hyper`` holds the swept values)
    collector: Collector
    data: Data
    model: Any  # the dynamics ensemble's state (mbpo, mbmpo); None for sac
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


def learner(config: Any, env: Any) -> SAC:
    """The SAC learner of a (resolved) configuration for ``env``."""
    return make_sac(env.observation_size, env.action_size, config.sac, config.ma, config.caps)


def policy_family(config: Any, env: Any) -> PolicyFamily:
    """The feedforward tanh-Gaussian actor on (optionally normalized) observations."""
    sac = learner(config, env)
    shapes = jax.eval_shape(sac.init, jax.random.PRNGKey(0), abstract_hyper(HYPER))
    actor = zeros_like_shapes(shapes.actor_params)
    norm = obs_norm.init_normalizer(env.observation_size)
    normalize = config.sac.normalize_obs

    def numpy_form(params: Any, norm: obs_norm.Normalizer) -> NumpyForm:
        """The actor MLP (relu hidden layers; mean and log-std out) and the normalizer."""
        return mlp_numpy_form(params["params"]["MLP_0"], "relu", norm, normalize)

    return PolicyFamily(
        agent=sac,
        like=(actor, norm),
        checkpoint_items={"agent/actor_params": actor, "data/normalizer": norm},
        from_items=lambda parts: (parts["agent/actor_params"], parts["data/normalizer"]),
        deterministic=deterministic_of(sac.control, normalize),
        stochastic=lambda p, n: acting.stochastic(sac.sample, sac.control, p, n, normalize),
        recurrent=False,
        export=numpy_form,
    )


class OffPolicy(NamedTuple):
    """The off-policy stages of one configuration, shared by sac, mbpo and mbmpo."""

    sac: SAC
    init: Callable[..., TrainState]
    collect: Callable[..., tuple[TrainState, acting.CollectStep, dict]]
    store: Callable[[TrainState, acting.CollectStep], TrainState]
    normalize: Callable[[obs_norm.Normalizer, jax.Array], jax.Array]
    normalize_batch: Callable[[Data, Transitions], Transitions]
    summarize: Callable[[TrainState, dict], dict]
    policy: PolicyFamily


def off_policy(
    config: Any,
    env: Any,
    task_set: Any,
    acting_params: Callable[[TrainState], tuple[Any, int | None]] | None = None,
    next_slot: Callable[[jax.Array, jax.Array, jax.Array], jax.Array] | None = None,
) -> OffPolicy:
    """The stages every off-policy agent shares. ``acting_params(state) -> (params, vmap axis)``
    chooses the parameters that act (default: the actor's); ``next_slot(slot, ended, key)``
    draws the acting slot of new episodes (mbmpo)."""
    sac = learner(config, env)
    obs_dim, act_dim = env.observation_size, env.action_size
    n = config.num_envs
    norm_on = config.sac.normalize_obs
    reward_norm = config.sac.normalize_reward

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

    def init(k_agent: jax.Array, k_env: jax.Array, k_run: jax.Array, hyper: dict,
             model: Any = None, model_buffer: Any = None) -> TrainState:  # fmt: skip
        return TrainState(
            agent=sac.init(k_agent, hyper),
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
            model=model,
            meta=None,
            rng=k_run,
            env_steps=jnp.zeros((), jnp.int32),
            imagined=jnp.zeros((), jnp.int32),
        )

    def act(ts: TrainState, key: jax.Array, steps: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Exploration actions for every environment and the new OU state (``steps``: env steps
        taken before this one, the unbatched schedule counter)."""
        k_random, k_policy, k_ou = jax.random.split(key, 3)
        c = ts.collector
        obs = normalize(ts.data.normalizer, c.env_state.obs)
        if acting_params is None:
            params, axis = ts.agent.actor_params, None
        else:
            params, axis = acting_params(ts)
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
        ts: TrainState, keys: dict[str, jax.Array], steps: jax.Array, members_axis: str | None
    ) -> tuple[TrainState, acting.CollectStep, dict]:
        action, ou = act(ts, keys["act"], steps)
        c = ts.collector
        s = acting.collect_step(env, c.env_state, action, c.episode_return, c.episode_length,
                                config.episode_limit, reset_envs, keys["reset"],
                                members_axis)  # fmt: skip
        slot = c.episode_slot
        if next_slot is not None:
            slot = next_slot(slot, s.ended, keys["slot"])
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
        ts = ts.replace(collector=collector)
        if reward_norm:
            stats = obs_norm.update(ts.data.return_stats, disc[:, None])
            collector = collector.replace(discounted_return=jnp.where(s.ended, 0.0, disc))
            ts = ts.replace(collector=collector, data=ts.data.replace(return_stats=stats))
        metrics = {
            "episodes_finished": jnp.sum((s.ended & s.finite).astype(jnp.float32)),
            "finished_return_sum": s.finished_return,
            "env_non_finite": jnp.sum((~s.finite).astype(jnp.float32)),
        }
        return ts, s, metrics

    def store(ts: TrainState, s: acting.CollectStep) -> TrainState:
        """Stores the finite transitions (a non-finite simulator step is never learned from)."""
        data, transitions, finite = ts.data, s.transitions, s.finite
        normalizer = data.normalizer
        if norm_on:
            updated = obs_norm.update(normalizer, transitions.next_obs)
            normalizer = jax.tree.map(lambda a, b: jnp.where(jnp.all(finite), a, b),
                                      updated, normalizer)  # fmt: skip
        real = replay.insert_masked(data.real, transitions, finite.astype(jnp.float32))
        return ts.replace(data=data.replace(real=real, normalizer=normalizer))

    def summarize(ts: TrainState, metrics: dict) -> dict:
        """Update metrics averaged over the iterations that updated, the mean return of the
        episodes that finished, and counts."""
        updated = jnp.maximum(jnp.sum(metrics["updated"]), 1.0)
        names = [k for k in metrics if k.startswith("loss/")]
        summary = {k[5:]: jnp.sum(metrics[k] * metrics["updated"]) / updated for k in names}
        episodes = jnp.sum(metrics["episodes_finished"])
        summary["train_episode_return"] = jnp.where(
            episodes > 0, jnp.sum(metrics["finished_return_sum"]) / jnp.maximum(episodes, 1), 0.0
        )
        summary["train_episodes"] = episodes
        # Simulator steps that went non-finite, were reset and not learned from.
        summary["env_non_finite_resets"] = jnp.sum(metrics["env_non_finite"])
        summary["updates"] = jnp.sum(metrics["updated"]) * config.updates_per_step
        return summary

    return OffPolicy(sac, init, collect, store, normalize, normalize_batch, summarize,
                     policy_family(config, env))  # fmt: skip


def gated_updates(
    config: Any, agent_update: Callable, ready: Callable[[jax.Array], jax.Array], abstract: Any
) -> Callable[[TrainState, jax.Array, jax.Array], tuple[TrainState, dict]]:
    """``updates_per_step`` agent updates under a ``lax.cond`` on the unbatched step counter
    (``ready(steps)``); their metrics come back named ``loss/<name>`` (the names from the update
    itself, not a hand-kept list) with ``updated``."""
    names = tuple(jax.eval_shape(agent_update, abstract, jax.random.PRNGKey(0))[1])

    def update(ts: TrainState, key: jax.Array, steps: jax.Array) -> tuple[TrainState, dict]:
        def do_updates(ts: TrainState) -> tuple[TrainState, dict]:
            keys = jax.random.split(key, config.updates_per_step)
            ts, metrics = jax.lax.scan(agent_update, ts, keys)
            return ts, {f"loss/{k}": jnp.mean(metrics[k]) for k in names}

        def skip(ts: TrainState) -> tuple[TrainState, dict]:
            return ts, {f"loss/{k}": jnp.zeros(()) for k in names}

        is_ready = ready(steps)
        ts, metrics = jax.lax.cond(is_ready, do_updates, skip, ts)
        return ts, {**metrics, "updated": is_ready.astype(jnp.float32)}

    return update


def make(config: Any, env: Any, task_set: Any) -> Agent:
    """The sac agent of a resolved configuration (see the module docstring)."""
    parts = off_policy(config, env, task_set)
    sac, batch = parts.sac, config.sac.batch_size

    def init(key: jax.Array, hyper: dict) -> TrainState:
        k_agent, k_env, k_run = jax.random.split(key, 3)
        return parts.init(k_agent, k_env, k_run, hyper)

    def agent_update(ts: TrainState, key: jax.Array) -> tuple[TrainState, dict]:
        k_batch, k_update = jax.random.split(key)
        b = parts.normalize_batch(ts.data, replay.sample(ts.data.real, k_batch, batch))
        agent, metrics = sac.update(ts.agent, b, k_update)
        return ts.replace(agent=agent), metrics

    def ready(steps: jax.Array) -> jax.Array:
        """After warm-up, once a full batch of real transitions is there."""
        return (steps >= config.warmup_steps) & (jnp.minimum(steps, config.buffer_size) >= batch)

    abstract = jax.eval_shape(init, jax.random.PRNGKey(0), abstract_hyper(HYPER))
    gated = gated_updates(config, agent_update, ready, abstract)

    def update(ts: TrainState, keys: dict, steps: jax.Array) -> tuple[TrainState, dict]:
        return gated(ts, keys["update"], steps)

    return Agent(keys=("act", "reset", "update"), init=init, collect=parts.collect,
                 store=parts.store, update=update, summarize=parts.summarize,
                 policy=parts.policy, parts={"agent_update": agent_update})  # fmt: skip


def learner_items(config: Any, sac: SAC, hyper_names: Any) -> dict[str, Any]:
    """The checkpoint items of the learner alone (templates), for a meta-test: the agent, and
    the return statistics its rewards were scaled by."""
    shapes = jax.eval_shape(sac.init, jax.random.PRNGKey(0), abstract_hyper(hyper_names))
    like = {"agent": zeros_like_shapes(shapes)}
    if config.sac.normalize_reward:
        like["data/return_stats"] = obs_norm.init_normalizer(1)
    return like


def adapter(config: Any, env: Any, family: PolicyFamily, settings: Any) -> Adapter:
    """A meta-test step of sac: ``updates_per_step`` SAC updates (actor, critics, entropy; MA
    included) on batches drawn from the collected episodes."""
    sac = family.agent
    batch = config.sac.batch_size
    capacity = settings.shots * config.episode_limit
    norm_on = config.sac.normalize_obs
    like = learner_items(config, sac, HYPER)

    def prepare(parts: dict, normalizer: Any, traj: acting.Trajectory, key: jax.Array,
                refit: bool) -> Any:  # fmt: skip
        data, valid = flat_transitions(traj)
        buffer = collected_buffer(env, capacity, data, valid)
        return buffer, normalizer, parts.get("data/return_stats")

    @jax.jit
    def step(agent: Any, context: Any, key: jax.Array) -> Any:
        buffer, normalizer, return_stats = context

        def one(agent, k):
            k_batch, k_sac = jax.random.split(k)
            b = replay.sample(buffer, k_batch, batch)
            b = as_learned(b, normalizer, return_stats, norm_on)
            return sac.update(agent, b, k_sac)[0], None

        keys = jax.random.split(key, settings.updates_per_step)
        return jax.lax.scan(one, agent, keys)[0]

    return Adapter(like=like, prepare=prepare, step=step,
                   policy_params=lambda agent: agent.actor_params)  # fmt: skip


def flat_transitions(traj: acting.Trajectory) -> tuple[Transitions, jax.Array]:
    """Collected episodes' transitions and alive mask, flattened to (episodes * steps,)."""
    flat = lambda x: x.reshape((-1,) + x.shape[2:])  # noqa: E731
    return jax.tree.map(flat, traj.transitions()), flat(traj.alive)


def collected_buffer(env: Any, capacity: int, data: Transitions, valid: jax.Array) -> Any:
    """A replay buffer holding the alive collected transitions."""
    empty = replay.init_buffer(capacity, env.observation_size, env.action_size)
    return replay.insert_masked(empty, data, valid)


def as_learned(b: Transitions, normalizer: Any, return_stats: Any, norm_on: bool) -> Transitions:
    """A batch as the run's agent learned from it (observation and reward scales)."""
    return b.replace(obs=obs_norm.normalize(normalizer, b.obs, norm_on),
                     next_obs=obs_norm.normalize(normalizer, b.next_obs, norm_on),
                     reward=obs_norm.scale_reward(return_stats, b.reward))  # fmt: skip


# SAC applies MA in every placement; as SAC treats entropy by default (the reading study's choice).
PLACEMENTS = ("entropy", "actor_loss", "reward")

SPEC = registry.register(
    registry.AgentSpec(
        name="sac",
        make=make,
        policy=policy_family,
        hyper=HYPER,
        groups=(SAC_SETTINGS,),
        defaults=lambda config: {"task_set": "nominal", "updates_per_step": 1},
        adapter=adapter,
        placements=PLACEMENTS,
    )
)

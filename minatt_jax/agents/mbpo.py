"""``--algo mbpo``: SAC on a 95% model / 5% real mix of transitions, the model phase inside its
update, and the model-based building blocks ``mbmpo`` shares.

The agent's ``update`` runs, after the ``sac`` agent's collect and store:

1. **model phase**, every ``model_train_every`` env steps after warm-up: fit the dynamics
   ensemble on the real data, roll the policy out in it from real start states (one slot per
   elite: each trajectory stays on one member) and insert the alive imagined transitions into
   that slot's model buffer;
2. ``updates_per_step`` SAC updates on mixed batches (``mb.real_ratio`` real), from the first
   model phase on.

Both are ``lax.cond``s on the unbatched step counter, so the same program runs before and after
them, and in a population every member takes the same branch.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from minatt_jax import acting, imagination, replay
from minatt_jax import normalizer as obs_norm
from minatt_jax.agents import registry
from minatt_jax.agents.base import Adapter, Agent, PolicyFamily, abstract_hyper
from minatt_jax.agents.sac import (
    PLACEMENTS,
    SAC_SETTINGS,
    OffPolicy,
    TrainState,
    as_learned,
    collected_buffer,
    flat_transitions,
    gated_updates,
    learner_items,
    off_policy,
    policy_family,
)
from minatt_jax.dynamics_ensemble import Ensemble, ModelConfig, make_ensemble
from minatt_jax.fields import check, setting
from minatt_jax.maml import MetaStep, Trajectories, make_meta_step
from minatt_jax.replay import Transitions
from minatt_jax.sac import HYPER as SAC_HYPER


@dataclasses.dataclass(frozen=True)
class MBConfig:
    """The model-based loop (mbpo, mbmpo): defaults are the paper's appendix / MBPO hopper values.

    Attributes:
      epoch_length: env steps per epoch (the rollout-length schedule counts epochs).
      model_train_every: env steps between model fits (each followed by a rollout).
      rollout_batch: start states per rollout (split evenly over the slots).
      rollout_schedule: (start_epoch, end_epoch, min_len, max_len): the rollout length grows
        linearly from min_len to max_len between the two epochs (official MBPO's and mbrl-lib's
        hopper schedule, epochs 20 -> 150, length 1 -> 15; minatt-jax's earlier default ended at
        epoch 100).
      model_buffer_size: capacity of the imagined-transition buffer (all slots together).
      real_ratio: fraction of each agent batch drawn from real data (the rest from the model).
      obs_clip: imagined observations are clipped to [-obs_clip, obs_clip].
      meta_inner_lr: beta of the MAML inner step theta' = theta - beta grad L_i(theta).
      meta_first_order: drop the inner gradient's dependence on theta (first-order MAML).
      meta_inner: inner-step objective, "sac" (the SAC actor loss) or "vpg" (REINFORCE on
        imagined trajectories of ``vpg_horizon`` steps from ``task batch`` start states).
      meta_outer: outer step, "sac" (Adam on the meta objective) or "trpo" (a trust-region step
        on it with KL <= ``trpo_max_kl``).
    """

    epoch_length: int = setting(1000, ge=1)
    model_train_every: int = setting(250, ge=1)
    rollout_batch: int = setting(100_000, ge=1, why="MBPO's hopper value")
    rollout_schedule: tuple[int, int, int, int] = setting(
        (20, 150, 1, 15), length=4, item={"kind": int, "ge": 0}
    )
    model_buffer_size: int = setting(2_000_000, ge=1)
    real_ratio: float = setting(0.05, ge=0, le=1)
    obs_clip: float = setting(100.0, gt=0)
    meta_inner_lr: float = setting(1e-3, ge=0, le=1, why="the paper appendix's beta")
    meta_first_order: bool = setting(False, why="second-order MAML, as the paper")
    meta_inner: str = setting("sac", choices=("sac", "vpg"), why="the paper's Algorithm 1")
    vpg_horizon: int = setting(10, ge=1)
    meta_outer: str = setting("sac", choices=("sac", "trpo"), why="the paper's Algorithm 1")
    trpo_max_kl: float = setting(0.01, gt=0)

    def __post_init__(self) -> None:
        check(self, "mb")
        start, end, lo, hi = self.rollout_schedule
        if not (0 < lo <= hi and start <= end):
            raise ValueError("mb.rollout_schedule must be (start_epoch, end_epoch, min_len, "
                             "max_len) with start <= end and 0 < min <= max, got "
                             f"{self.rollout_schedule}")  # fmt: skip

    def rollout_length(self, epoch):
        """The scheduled rollout length at ``epoch`` (works on ints and traced arrays)."""
        start, end, lo, hi = self.rollout_schedule
        frac = (epoch - start) / max(end - start, 1)
        frac = frac * (frac > 0)
        frac = frac - (frac - 1) * (frac > 1)
        return (lo + frac * (hi - lo)) // 1


# The model-based groups (mbpo and mbmpo own them with SAC's). The cpu preset caps model fits to
# fit a CPU, and why (measured, benchmarks/meta_step.py): at most 10 "epochs" of at most 20
# minibatches, warm-started from the last fit (one 7 x 4x200 minibatch takes 13-19 ms; full-data
# epochs with early stopping take 20-40 s per fit, 1-2 h over the 180 fits of a 50K run).
MODEL_SETTINGS = registry.SettingsGroup("model", ModelConfig, presets={
    "smoke": {"ensemble_size": 3, "num_elites": 2, "hidden": (32, 32),
              "weight_decay": (2.5e-5, 5e-5, 1e-4), "batch_size": 64, "max_holdout": 200,
              "max_epochs": 3},
    "cpu": {"max_epochs": 10, "max_batches_per_epoch": 20},
})  # fmt: skip
MB_SETTINGS = registry.SettingsGroup("mb", MBConfig, presets={
    "smoke": {"epoch_length": 100, "model_train_every": 100, "rollout_batch": 64,
              "rollout_schedule": (0, 2, 1, 3), "model_buffer_size": 2_000},
})  # fmt: skip
GROUPS = (SAC_SETTINGS, MODEL_SETTINGS, MB_SETTINGS)

HYPER = {**SAC_HYPER, "inner_lr": "mb.meta_inner_lr"}  # inner_lr: the meta-test's inner step
KEYS = ("act", "reset", "slot", "model", "update")


class ModelBased(NamedTuple):
    """The model phase of one configuration and what the model-based agents share."""

    base: OffPolicy
    ensemble: Ensemble
    init: Callable[..., TrainState]
    update: Callable[[Callable], Callable]  # agent_update -> the agent's update
    summarize: Callable[[TrainState, dict], dict]
    imagined_policy: Callable
    refit: Callable
    imagine: Callable
    slots: int


def model_based(
    config: Any,
    env: Any,
    task_set: Any,
    meta_init: Callable[[Any], Any] | None = None,
    **off_policy_hooks: Any,
) -> ModelBased:
    """The model phase and the mixed-data schedule around an off-policy learner;
    ``meta_init(agent_state)`` makes the initial meta state (mbmpo)."""
    base = off_policy(config, env, task_set, **off_policy_hooks)
    sac, mb, n = base.sac, config.mb, config.num_envs
    obs_dim, act_dim = env.observation_size, env.action_size
    ensemble = make_ensemble(obs_dim, act_dim, config.model)
    slots = config.model.num_elites
    per_slot = mb.rollout_batch // slots
    max_len = mb.rollout_schedule[3]

    def init(key: jax.Array, hyper: dict) -> TrainState:
        k_agent, k_model, k_env, k_run = jax.random.split(key, 4)
        capacity = mb.model_buffer_size // slots
        buffers = replay.init_slot_buffers(slots, capacity, obs_dim, act_dim)
        ts = base.init(k_agent, k_env, k_run, hyper, model=ensemble.init(k_model),
                       model_buffer=buffers)  # fmt: skip
        return ts.replace(meta=meta_init(ts.agent)) if meta_init is not None else ts

    def rollout_length(env_steps: jax.Array) -> jax.Array:
        return jnp.asarray(mb.rollout_length(env_steps // mb.epoch_length), jnp.int32)

    def imagined_policy(norm: Any) -> Callable:
        return lambda params, obs, key: sac.sample(params, base.normalize(norm, obs), key)

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

    # The schedule is a function of the env-step counter alone (unbatched in a population).
    every = mb.model_train_every
    first_fit = -(-max(-(-config.warmup_steps // every), 1) * every // n) * n

    def update(agent_update: Callable) -> Callable:
        abstract = jax.eval_shape(init, jax.random.PRNGKey(0), abstract_hyper(HYPER))
        gated = gated_updates(config, agent_update, lambda steps: steps >= first_fit, abstract)

        def run(ts: TrainState, keys: dict, steps: jax.Array) -> tuple[TrainState, dict]:
            due = model_due(steps)
            ts, imagined = jax.lax.cond(
                due, model_phase, lambda t, k, s: (t, jnp.zeros((), jnp.int32)),
                ts, keys["model"], steps,
            )  # fmt: skip
            ts, metrics = gated(ts, keys["update"], steps)
            return ts, {"refit": due.astype(jnp.float32),
                        "imagined": imagined.astype(jnp.float32), **metrics}  # fmt: skip

        return run

    def summarize(ts: TrainState, metrics: dict) -> dict:
        summary = base.summarize(ts, metrics)
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

    return ModelBased(base, ensemble, init, update, summarize, imagined_policy, refit, imagine,
                      slots)  # fmt: skip


def mixed_batch(mbs: ModelBased, config: Any, ts: TrainState, key: jax.Array) -> Transitions:
    """An agent batch: ``mb.real_ratio`` real transitions, the rest imagined, as learned."""
    batch = config.sac.batch_size
    real_count = int(round(config.mb.real_ratio * batch))
    b = replay.sample_mixed(ts.data.model, ts.data.real, key, batch, real_count)
    return mbs.base.normalize_batch(ts.data, b)


def make(config: Any, env: Any, task_set: Any) -> Agent:
    """The mbpo agent of a resolved configuration (see the module docstring)."""
    mbs = model_based(config, env, task_set)
    sac = mbs.base.sac

    def agent_update(ts: TrainState, key: jax.Array) -> tuple[TrainState, dict]:
        k_batch, k_update = jax.random.split(key)
        k_batch, _ = jax.random.split(k_batch)  # the meta step's task key (mbmpo's layout)
        agent, metrics = sac.update(ts.agent, mixed_batch(mbs, config, ts, k_batch), k_update)
        return ts.replace(agent=agent), metrics

    return Agent(keys=KEYS, init=mbs.init, collect=mbs.base.collect, store=mbs.base.store,
                 update=mbs.update(agent_update), summarize=mbs.summarize,
                 policy=mbs.base.policy,
                 parts={"agent_update": agent_update, "refit": mbs.refit,
                        "imagine": mbs.imagine})  # fmt: skip


def model_adapter(config: Any, env: Any, family: PolicyFamily, settings: Any,
                  meta: MetaStep, hyper_names: Any, vpg: bool) -> Adapter:  # fmt: skip
    """A meta-test step of a model-based agent: the ensemble is refitted once on the collected
    episodes (when the inner step reads the model: VPG's trajectories or MA's rollout temporal
    term); each step imagines transitions of the current policy in it from collected states
    (one slot per elite) and applies the inner step theta <- theta - beta grad L(theta) on each
    slot's data, averaged over slots (beta: the learner's ``hyper["inner_lr"]``)."""
    sac = family.agent
    ensemble = make_ensemble(env.observation_size, env.action_size, config.model)
    norm_on = config.sac.normalize_obs
    horizon = config.mb.vpg_horizon if vpg else 1
    slots = config.model.num_elites
    per_slot = max(config.sac.batch_size // slots, 16)
    capacity = settings.shots * config.episode_limit
    reads_model = vpg or config.ma.temporal == "rollout"
    like = learner_items(config, sac, hyper_names)
    like["model"] = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype),
                                 jax.eval_shape(ensemble.init, jax.random.PRNGKey(0)))  # fmt: skip

    @jax.jit
    def fit(ens_state: Any, data: Transitions, valid: jax.Array, key: jax.Array) -> Any:
        buffer = collected_buffer(env, capacity, data, valid)
        return ensemble.fit(ens_state, buffer.data, buffer.size, key)[0]

    def prepare(parts: dict, normalizer: Any, traj: acting.Trajectory, key: jax.Array,
                refit: bool) -> Any:  # fmt: skip
        data, valid = flat_transitions(traj)
        model = parts["model"]
        if refit and reads_model and settings.adapt_steps > 0:
            model = fit(model, data, valid, key)
        return model, data, valid, normalizer, parts.get("data/return_stats")

    @jax.jit
    def step(agent: Any, context: Any, key: jax.Array) -> Any:
        ens_state, data, valid, normalizer, return_stats = context
        k_start, k_roll, k_inner = jax.random.split(key, 3)
        count = jnp.maximum(jnp.sum(valid).astype(jnp.int32), 1)
        order = jnp.argsort(valid <= 0, stable=True)
        idx = order[jax.random.randint(k_start, (slots, per_slot), 0, count)]
        policy = lambda p, obs, k: sac.sample(  # noqa: E731
            p, obs_norm.normalize(normalizer, obs, norm_on), k
        )
        rollouts, alive = imagination.imagine(
            ensemble, ens_state, ens_state.elites, policy, agent.actor_params, env.terminated,
            data.obs[idx], jnp.asarray(horizon), horizon, k_roll, config.mb.obs_clip,
        )  # fmt: skip
        rollouts = as_learned(rollouts, normalizer, return_stats, norm_on)
        if vpg:
            supports = Trajectories(data=rollouts, alive=alive)
        else:  # one step from real states: every transition is taken
            supports = jax.tree.map(lambda x: x[:, 0], rollouts)
        adapted = jax.vmap(lambda s, k: meta.adapt(agent.actor_params, agent, s, k)[0])(
            supports, jax.random.split(k_inner, slots)
        )
        return agent.replace(actor_params=jax.tree.map(lambda a: jnp.mean(a, axis=0), adapted))

    return Adapter(like=like, prepare=prepare, step=step, parts={"refit": fit},
                   policy_params=lambda agent: agent.actor_params)  # fmt: skip


def adapter(config: Any, env: Any, family: PolicyFamily, settings: Any) -> Adapter:
    """mbpo has no meta step: its meta-test adapts with the SAC inner step at its inner_lr."""
    meta = make_meta_step(family.agent)
    return model_adapter(config, env, family, settings, meta, HYPER, vpg=False)


def model_based_defaults(config: Any) -> dict[str, Any]:
    """Two agent updates per env step (the paper's appendix), min(5, ensemble size) elites (as
    MBPO), and the buffer checks."""
    slots = config.model.num_elites or min(5, config.model.ensemble_size)
    max_len = config.mb.rollout_schedule[3]
    if config.mb.rollout_batch < slots:
        raise ValueError(
            f"mb.rollout_batch ({config.mb.rollout_batch}) must be >= model.num_elites ({slots})"
        )
    if config.mb.rollout_batch // slots * max_len > config.mb.model_buffer_size // slots:
        raise ValueError(
            f"mb.model_buffer_size ({config.mb.model_buffer_size}) must hold one rollout: "
            f">= mb.rollout_batch x max rollout length = {config.mb.rollout_batch * max_len}"
        )
    return {"updates_per_step": 2, "model.num_elites": slots}


SPEC = registry.register(
    registry.AgentSpec(
        name="mbpo",
        make=make,
        policy=policy_family,
        hyper=HYPER,
        groups=GROUPS,
        defaults=lambda config: {"task_set": "nominal", **model_based_defaults(config)},
        adapter=adapter,
        placements=PLACEMENTS,
    )
)

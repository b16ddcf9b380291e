"""``--algo mbmpo``: MB-MPO with SAC (the paper's Algorithm 1), minimum attention in every loss.

The ``mbpo`` agent's collection and model phase, with two changes: each training episode acts with
the adapted policy theta'_i of a slot i drawn when it starts (the slots are the elite ensemble
members: the tasks), and the agent update is the MAML meta step of ``minatt_jax.maml``: for every
slot an inner step on its support data (SAC actor loss on mixed batches, or VPG on imagined
trajectories), an outer step (Adam or TRPO) on the mean of the adapted policies' losses on the
query data. The batch is split over the slots: each slot's support and query batches hold
batch / slots transitions (at least 16), ``mb.real_ratio`` of them real. The inner step size is
the learner's ``hyper["inner_lr"]``.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from minatt_jax import imagination, replay
from minatt_jax.agents import registry
from minatt_jax.agents.base import Adapter, Agent, PolicyFamily
from minatt_jax.agents.mbpo import (
    GROUPS,
    HYPER,
    KEYS,
    mixed_batch,
    model_adapter,
    model_based,
    model_based_defaults,
)
from minatt_jax.agents.sac import PLACEMENTS, MetaState, TrainState, policy_family
from minatt_jax.maml import MetaStep, Trajectories, make_meta_step
from minatt_jax.replay import Transitions
from minatt_jax.sac import SAC


def meta_step(config: Any, sac: SAC) -> MetaStep:
    """The configuration's meta step: its inner and outer steps."""
    mb = config.mb
    return make_meta_step(sac, mb.meta_first_order, mb.meta_inner, config.sac.gamma,
                          outer=mb.meta_outer, max_kl=mb.trpo_max_kl)  # fmt: skip


def make(config: Any, env: Any, task_set: Any) -> Agent:
    """The mbmpo agent of a resolved configuration (see the module docstring)."""
    slots = config.model.num_elites
    n, mb, batch = config.num_envs, config.mb, config.sac.batch_size

    def acting_params(ts: TrainState) -> tuple[Any, int]:
        """Each episode acts with its slot's adapted policy."""
        return jax.tree.map(lambda p: p[ts.collector.episode_slot], ts.meta.adapted), 0

    def next_slot(slot: jax.Array, ended: jax.Array, key: jax.Array) -> jax.Array:
        return jnp.where(ended, jax.random.randint(key, (n,), 0, slots), slot)

    def meta_init(agent: Any) -> MetaState:
        return MetaState(jax.tree.map(lambda p: jnp.broadcast_to(p, (slots, *p.shape)),
                                      agent.actor_params))  # fmt: skip

    mbs = model_based(config, env, task_set, meta_init=meta_init, acting_params=acting_params,
                      next_slot=next_slot)  # fmt: skip
    sac = mbs.base.sac
    meta = meta_step(config, sac)
    task_batch = max(batch // slots, 16)
    task_real = int(round(mb.real_ratio * task_batch))

    def meta_tasks(ts: TrainState, key: jax.Array) -> tuple[Any, Transitions]:
        """Support and query data per task (slot): mixed batches, or VPG trajectories."""
        data, norm = ts.data, ts.data.normalizer
        k_support, k_query = jax.random.split(key)

        def slot_batch(slot, k):
            b = replay.sample_mixed(data.model, data.real, k, task_batch, task_real, slot)
            return mbs.base.normalize_batch(data, b)

        queries = jax.vmap(slot_batch)(jnp.arange(slots), jax.random.split(k_query, slots))
        if mb.meta_inner == "vpg":
            # Fresh trajectories of the current policy in each task's model (REINFORCE data).
            k_start, k_roll = jax.random.split(k_support)
            idx = jax.random.randint(k_start, (slots, task_batch), 0,
                                     jnp.maximum(data.real.size, 1))  # fmt: skip
            rollouts, alive = imagination.imagine(
                mbs.ensemble, ts.model, ts.model.elites, mbs.imagined_policy(norm),
                ts.agent.actor_params, env.terminated, data.real.data.obs[idx],
                jnp.asarray(mb.vpg_horizon), mb.vpg_horizon, k_roll, mb.obs_clip,
            )  # fmt: skip
            rollouts = mbs.base.normalize_batch(data, rollouts)
            return Trajectories(data=rollouts, alive=alive), queries
        supports = jax.vmap(slot_batch)(jnp.arange(slots), jax.random.split(k_support, slots))
        return supports, queries

    def agent_update(ts: TrainState, key: jax.Array) -> tuple[TrainState, dict]:
        """Critic step on a mixed batch, then the meta actor step over the slots."""
        k_batch, k_update = jax.random.split(key)
        k_batch, k_tasks = jax.random.split(k_batch)
        b = mixed_batch(mbs, config, ts, k_batch)
        supports, queries = meta_tasks(ts, k_tasks)
        agent, adapted, metrics = meta.update(ts.agent, b, supports, queries, k_update)
        return ts.replace(agent=agent, meta=ts.meta.replace(adapted=adapted)), metrics

    return Agent(keys=KEYS, init=mbs.init, collect=mbs.base.collect, store=mbs.base.store,
                 update=mbs.update(agent_update), summarize=mbs.summarize,
                 policy=mbs.base.policy,
                 parts={"agent_update": agent_update, "refit": mbs.refit,
                        "imagine": mbs.imagine})  # fmt: skip


def adapter(config: Any, env: Any, family: PolicyFamily, settings: Any) -> Adapter:
    """The meta-test adapts with the run's own inner step (objective, first order or not)."""
    meta = meta_step(config, family.agent)
    vpg = config.mb.meta_inner == "vpg"
    return model_adapter(config, env, family, settings, meta, HYPER, vpg=vpg)


SPEC = registry.register(
    registry.AgentSpec(
        name="mbmpo",
        make=make,
        policy=policy_family,
        hyper=HYPER,
        groups=GROUPS,
        # Meta-training collects data across the training tasks.
        defaults=lambda config: {"task_set": "train", **model_based_defaults(config)},
        adapter=adapter,
        placements=PLACEMENTS,
    )
)

"""The MB-MPO meta step with SAC: MAML inner steps per task, an outer SAC update through them.

Tasks are the dynamics-ensemble members (their imagined data). For task i, with the SAC actor loss
L_i (including the MA penalty) on task i's data:

    inner:  theta'_i = theta - beta * grad L_i(theta; support_i)      (vmapped over tasks)
    outer:  theta <- Adam step on  mean_i L_i(theta'_i(theta); query_i)

The outer gradient flows through theta'_i (second order, the default): it contains the Hessian
term -beta * H_i g_i. ``first_order=True`` stops the gradient at grad L_i (first-order MAML),
so the outer gradient is just the mean of the gradients at the adapted parameters.
The critics get a plain SAC update on the mixed batch; the entropy coefficient follows the
adapted policies' entropy on the query data.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from minatt_jax.replay import Transitions
from minatt_jax.sac import SAC, SACState


class MetaStep(NamedTuple):
    """The meta objective (for tests) and the full meta update."""

    adapt: Callable[[Any, SACState, Transitions, jax.Array], tuple[Any, jax.Array]]
    meta_loss: Callable[..., tuple[jax.Array, dict]]
    update: Callable[..., tuple[SACState, Any, dict]]


def make_meta_step(sac: SAC, inner_lr: float, first_order: bool = False) -> MetaStep:
    """Builds the MAML-over-SAC meta step for a SAC agent."""

    def adapt(
        actor_params: Any, agent: SACState, support: Transitions, key: jax.Array
    ) -> tuple[Any, jax.Array]:
        """One inner step on one task's support batch; returns (theta', inner loss)."""

        def loss(p):
            return sac.actor_loss(p, agent, support, key)[0]

        inner_loss, grads = jax.value_and_grad(loss)(actor_params)
        if first_order:
            grads = jax.lax.stop_gradient(grads)
        adapted = jax.tree.map(lambda p, g: p - inner_lr * g, actor_params, grads)
        return adapted, inner_loss

    def meta_loss(
        actor_params: Any,
        agent: SACState,
        supports: Transitions,
        queries: Transitions,
        key: jax.Array,
    ) -> tuple[jax.Array, dict]:
        """mean_i L_i(theta'_i) over tasks (leading axis of supports and queries)."""
        tasks = supports.reward.shape[0]

        def task(support, query, k):
            k_in, k_out = jax.random.split(k)
            adapted, inner_loss = adapt(actor_params, agent, support, k_in)
            outer_loss, (metrics, mean_logp) = sac.actor_loss(adapted, agent, query, k_out)
            return outer_loss, (inner_loss, metrics, mean_logp, adapted)

        outer, (inner, metrics, logps, adapted) = jax.vmap(task)(
            supports, queries, jax.random.split(key, tasks)
        )
        aux = {
            "meta_inner_loss": jnp.mean(inner),
            "meta_outer_loss": jnp.mean(outer),
            "mean_logp": jnp.mean(logps),
            "adapted": adapted,
            **{k: jnp.mean(v) for k, v in metrics.items()},
        }
        return jnp.mean(outer), aux

    def update(
        agent: SACState,
        critic_batch: Transitions,
        supports: Transitions,
        queries: Transitions,
        key: jax.Array,
    ) -> tuple[SACState, Any, dict]:
        """Critic step, then the meta actor step; returns (agent, adapted params, metrics)."""
        k_critic, k_actor = jax.random.split(key)
        agent, c_metrics = sac.critic_step(agent, critic_batch, k_critic)
        (_, aux), grads = jax.value_and_grad(meta_loss, has_aux=True)(
            agent.actor_params, agent, supports, queries, k_actor
        )
        adapted = aux.pop("adapted")
        mean_logp = aux.pop("mean_logp")
        agent = sac.finish_actor_step(agent, grads, mean_logp)
        metrics = {**c_metrics, **aux, "entropy_coef": jnp.exp(agent.log_entropy_coef)}
        return agent, adapted, metrics

    return MetaStep(adapt=adapt, meta_loss=meta_loss, update=update)

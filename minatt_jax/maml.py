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

``inner="vpg"`` replaces the inner objective by vanilla policy gradient (REINFORCE) on imagined
trajectories of task i sampled with theta: L_i(theta) = -mean(log pi_theta(a_t|s_t) A_t) + MA
penalty, A_t the discounted return-to-go minus its mean over the task's trajectories at step t,
normalized; the MA penalty is taken at the trajectories' start states (random real states).

``outer="trpo"`` replaces the outer Adam step by a trust-region step on the same meta objective:
the natural-gradient direction F^-1 g by conjugate gradient (F = the Hessian of the mean KL between
the old and new policy on the query states, by Fisher-vector products), scaled to KL = max_kl,
then a backtracking line search that accepts the first step that lowers the objective and keeps
the KL within max_kl (no step if none does).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from minatt_jax import min_attention as ma
from minatt_jax.replay import Transitions
from minatt_jax.sac import SAC, SACState

INNER_ALGOS = ("sac", "vpg")
OUTER_ALGOS = ("sac", "trpo")


class Trajectories(NamedTuple):
    """Imagined trajectories of one task for the VPG inner step: (steps, n, ...) and alive."""

    data: Transitions
    alive: jax.Array


class MetaStep(NamedTuple):
    """The meta objective (for tests) and the full meta update."""

    adapt: Callable[..., tuple[Any, jax.Array]]
    meta_loss: Callable[..., tuple[jax.Array, dict]]
    update: Callable[..., tuple[SACState, Any, dict]]


def vpg_loss(sac: SAC, gamma: float) -> Callable[..., jax.Array]:
    """The REINFORCE inner objective with the MA penalty (see the module docstring)."""

    def loss(actor_params: Any, agent: SACState, traj: Trajectories, key: jax.Array) -> jax.Array:
        data, alive = traj.data, traj.alive  # (steps, n, ...)

        def discount(carry, x):
            r, a = x
            g = a * (r + gamma * carry)
            return g, g

        _, returns = jax.lax.scan(discount, jnp.zeros_like(data.reward[0]),
                                  (data.reward, alive), reverse=True)  # fmt: skip
        count = jnp.maximum(jnp.sum(alive, axis=1, keepdims=True), 1.0)
        baseline = jnp.sum(returns * alive, axis=1, keepdims=True) / count
        adv = (returns - baseline) * alive
        adv = adv / (jnp.sqrt(jnp.sum(adv**2) / jnp.maximum(jnp.sum(alive), 1.0)) + 1e-6)
        logp = sac.log_prob(actor_params, data.obs, data.action)
        pg = -jnp.sum(alive * logp * jax.lax.stop_gradient(adv)) / jnp.maximum(jnp.sum(alive), 1.0)
        if sac.regularizer.ma_config.active:
            pen, _ = ma.penalty(
                sac.regularizer.ma_config, sac.control, actor_params, data.obs[0], key,
                prev_params=agent.prev_actor_params, next_obs=data.next_obs[0],
                update_step=agent.updates, alpha=agent.hyper["alpha"],
                terms=agent.hyper["ma_terms"],
            )  # fmt: skip
            pg = pg + pen
        return pg

    return loss


def make_meta_step(
    sac: SAC,
    first_order: bool = False,
    inner: str = "sac",
    gamma: float = 0.99,
    outer: str = "sac",
    max_kl: float = 0.01,
    cg_iters: int = 10,
    backtracks: int = 10,
) -> MetaStep:
    """Builds the MAML meta step (inner "sac" or "vpg"; outer "sac" or "trpo") for SAC. The
    inner step size beta is the agent's ``hyper["inner_lr"]`` (a population sweeps it)."""
    if inner not in INNER_ALGOS:
        raise ValueError(f"inner algorithm must be one of {INNER_ALGOS}, got {inner!r}")
    if outer not in OUTER_ALGOS:
        raise ValueError(f"outer algorithm must be one of {OUTER_ALGOS}, got {outer!r}")
    inner_objective = vpg_loss(sac, gamma) if inner == "vpg" else None

    def adapt(
        actor_params: Any,
        agent: SACState,
        support: Any,
        key: jax.Array,
    ) -> tuple[Any, jax.Array]:
        """One inner step on one task's support data with beta = ``agent.hyper["inner_lr"]``;
        returns (theta', inner loss)."""
        beta = agent.hyper["inner_lr"]

        def loss(p):
            if inner_objective is not None:
                return inner_objective(p, agent, support, key)
            return sac.actor_loss(p, agent, support, key)[0]

        inner_loss, grads = jax.value_and_grad(loss)(actor_params)
        if first_order:
            grads = jax.lax.stop_gradient(grads)
        adapted = jax.tree.map(lambda p, g: p - beta * g, actor_params, grads)
        return adapted, inner_loss

    def meta_loss(
        actor_params: Any,
        agent: SACState,
        supports: Transitions,
        queries: Transitions,
        key: jax.Array,
    ) -> tuple[jax.Array, dict]:
        """mean_i L_i(theta'_i) over tasks (leading axis of supports and queries)."""
        tasks = queries.reward.shape[0]

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
        (loss, aux), grads = jax.value_and_grad(meta_loss, has_aux=True)(
            agent.actor_params, agent, supports, queries, k_actor
        )
        adapted = aux.pop("adapted")
        mean_logp = aux.pop("mean_logp")
        if outer == "trpo":
            new_params, trpo_metrics = trust_region_step(
                agent, supports, queries, k_actor, grads, loss
            )
            aux.update(trpo_metrics)
            agent = sac.finish_actor_step(agent, None, mean_logp, new_actor_params=new_params)
        else:
            agent = sac.finish_actor_step(agent, grads, mean_logp)
        metrics = {**c_metrics, **aux, "entropy_coef": jnp.exp(agent.log_entropy_coef)}
        return agent, adapted, metrics

    def trust_region_step(agent, supports, queries, key, grads, loss):
        """TRPO on the meta objective (see the module docstring)."""
        old = agent.actor_params
        flat_old, unravel = ravel_pytree(old)
        states = queries.obs.reshape((-1, queries.obs.shape[-1]))
        old_mean, old_log_std = jax.lax.stop_gradient(sac.dist(old, states))

        def kl(flat):
            mean, log_std = sac.dist(unravel(flat), states)
            var_ratio = jnp.exp(2 * (old_log_std - log_std))
            terms = var_ratio + jnp.square(mean - old_mean) * jnp.exp(-2 * log_std)
            return jnp.mean(jnp.sum(0.5 * (terms - 1.0) + log_std - old_log_std, axis=-1))

        def fvp(v):
            return jax.jvp(jax.grad(kl), (flat_old,), (v,))[1] + 1e-2 * v

        g = ravel_pytree(grads)[0]

        def cg_body(_, carry):
            x, r, p, rr = carry
            fp = fvp(p)
            a = rr / jnp.maximum(jnp.dot(p, fp), 1e-12)
            x, r = x + a * p, r - a * fp
            rr_new = jnp.dot(r, r)
            return x, r, r + (rr_new / jnp.maximum(rr, 1e-12)) * p, rr_new

        direction, *_ = jax.lax.fori_loop(
            0, cg_iters, cg_body, (jnp.zeros_like(g), g, g, jnp.dot(g, g))
        )
        shs = jnp.dot(direction, fvp(direction))
        full_step = -jnp.sqrt(2.0 * max_kl / jnp.maximum(shs, 1e-12)) * direction

        def objective(flat):
            return meta_loss(unravel(flat), agent, supports, queries, key)[0]

        def try_step(j, carry):
            accepted, best = carry
            candidate = flat_old + (0.5**j) * full_step
            ok = (objective(candidate) < loss) & (kl(candidate) <= max_kl) & ~accepted
            return accepted | ok, jnp.where(ok, candidate, best)

        accepted, flat_new = jax.lax.fori_loop(
            0, backtracks, try_step, (jnp.zeros((), bool), flat_old)
        )
        metrics = {"trpo_accepted": accepted.astype(jnp.float32), "trpo_kl": kl(flat_new)}
        return unravel(flat_new), metrics

    return MetaStep(adapt=adapt, meta_loss=meta_loss, update=update)

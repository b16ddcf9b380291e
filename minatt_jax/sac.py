"""Soft actor-critic with the minimum-attention regularizer: losses and one composed update.

``make_sac`` builds three losses as pure functions of their parameters and a batch:

* critic: 0.5 sum_i (Q_i(s, a) - y)^2, y = r + gamma (1 - d) (min_j Q'_j(s', a') - ent log pi);
* actor: E[ent * log pi(a|s) - min_i Q_i(s, a)] + the regularizer's actor penalty;
* entropy: -log(ent) * (log pi + target entropy) (automatic temperature);

and composes them in ``update``: reward transform -> critic step -> actor step -> entropy and
target-critic steps. The smoothness penalties enter through one argument, the ``Regularizer``
that ``min_attention.make_regularizer`` builds: MA in the actor loss (``placement="actor_loss"``),
MA as a batch transform of the rewards before the critic loss (``placement="reward"``), MA as SAC
treats entropy (``placement="entropy"``: in the actor loss and, at the next state, subtracted from
the soft value in the critic target), CAPS in
the actor loss. MB-MPO's meta step replaces only the actor step (``maml``), reusing the rest.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from minatt_jax import min_attention as ma
from minatt_jax.fields import check, setting
from minatt_jax.networks import (
    Actor,
    TwinCritic,
    sample_tanh_gaussian,
    tanh_gaussian_log_prob,
)
from minatt_jax.replay import Transitions


@dataclasses.dataclass(frozen=True)
class SACConfig:
    """SAC settings (paper appendix): 256x256 ReLU, Adam 3e-4, gamma 0.99, tau 0.005.

    ``normalize_reward``: the paper's "rewards were normalized during training", read as the
    common running scale of the return (as gym's ``NormalizeReward`` / baselines'
    ``VecNormalize``): every environment keeps its discounted return G <- gamma G + r (zeroed
    when an episode ends), the running variance of G over all steps is tracked, and the rewards
    of every SAC batch (real, imagined, adaptation) are divided by sqrt(var + 1e-8), not
    shifted. MA's reward placement then subtracts its penalty from the scaled reward.
    """

    hidden: tuple[int, ...] = setting((256, 256), min_length=1, item={"kind": int, "ge": 1})
    actor_lr: float = setting(3e-4, ge=0, le=1)
    critic_lr: float = setting(3e-4, ge=0, le=1)
    entropy_lr: float = setting(3e-4, ge=0, le=1)
    gamma: float = setting(0.99, ge=0, lt=1)
    tau: float = setting(0.005, gt=0, le=1)
    batch_size: int = setting(256, ge=1)
    init_entropy_coef: float = setting(1.0, gt=0)
    target_entropy: float | None = setting(None, kind=float, optional=True)  # None = -act_dim
    log_std_min: float = setting(-20.0)
    log_std_max: float = setting(2.0)
    normalize_obs: bool = setting(False, why="raw observations, as the paper")
    normalize_reward: bool = setting(False, why="the reading study's best SAC arm ran without it")

    def __post_init__(self) -> None:
        check(self, "sac")
        if not self.log_std_min < self.log_std_max:
            raise ValueError(f"sac.log_std_min ({self.log_std_min}) must be below "
                             f"sac.log_std_max ({self.log_std_max})")  # fmt: skip


@struct.dataclass
class SACState:
    """All SAC parameters and optimizer states (part of the train-state pytree)."""

    actor_params: Any
    critic_params: Any
    target_critic_params: Any
    log_entropy_coef: jax.Array
    actor_opt: Any
    critic_opt: Any
    entropy_opt: Any
    prev_actor_params: Any  # parameters before the last actor update (MA temporal term)
    updates: jax.Array
    # Every value a population sweeps, read here by the losses (``agents.base``): "alpha" (MA's
    # weight), "ma_terms" (the MA mode's (feedback, temporal) 0/1 weights), "actor_lr",
    # "critic_lr", "entropy_lr"; MB-MPO adds "inner_lr".
    hyper: dict[str, jax.Array]


class SAC(NamedTuple):
    """The functions of a SAC agent for fixed dimensions and settings."""

    init: Callable[[jax.Array, dict[str, jax.Array]], SACState]
    update: Callable[[SACState, Transitions, jax.Array], tuple[SACState, dict]]
    control: Callable[[Any, jax.Array], jax.Array]  # deterministic u(params, obs)
    sample: Callable[[Any, jax.Array, jax.Array], jax.Array]  # (params, obs, key) -> action
    # The pieces of ``update``, for algorithms that replace the actor step (MB-MPO's meta step):
    critic_step: Callable[[SACState, Transitions, jax.Array], tuple[SACState, dict]]
    actor_loss: Callable[..., tuple[jax.Array, tuple[dict, jax.Array]]]
    finish_actor_step: Callable[[SACState, Any, jax.Array], SACState]
    log_prob: Callable[[Any, jax.Array, jax.Array], jax.Array]  # (params, obs, action)
    dist: Callable[[Any, jax.Array], tuple[jax.Array, jax.Array]]  # pre-tanh (mean, log_std)
    regularizer: ma.Regularizer


HYPER = {"alpha": "ma.alpha", "ma_terms": "ma.mode", "actor_lr": "sac.actor_lr",
         "critic_lr": "sac.critic_lr", "entropy_lr": "sac.entropy_lr"}  # fmt: skip


def with_learning_rate(opt_state: Any, lr: jax.Array) -> Any:
    """An ``optax.inject_hyperparams`` state with its learning rate set to ``lr`` (the state's
    ``hyper`` value: the optimizer state's copy only mirrors it)."""
    hyper = dict(opt_state.hyperparams)
    hyper["learning_rate"] = jnp.asarray(lr, hyper["learning_rate"].dtype)
    return opt_state._replace(hyperparams=hyper)


def make_sac(
    obs_dim: int,
    act_dim: int,
    config: SACConfig,
    ma_config: ma.MAConfig,
    caps_config: ma.CAPSConfig | None = None,
) -> SAC:
    """Builds a SAC agent; ``update`` takes a batch of (already normalized) transitions."""
    actor = Actor(config.hidden, act_dim, config.log_std_min, config.log_std_max)
    critic = TwinCritic(config.hidden)
    # The learning rates are the state's hyper values (a population sweeps them per member),
    # set into the optimizer state before each step.
    adam = optax.inject_hyperparams(optax.adam)
    actor_tx = critic_tx = entropy_tx = adam(learning_rate=0.0)
    target_entropy = -float(act_dim) if config.target_entropy is None else config.target_entropy

    def control(params: Any, obs: jax.Array) -> jax.Array:
        mean, _ = actor.apply(params, obs)
        return jnp.tanh(mean)

    regularizer = ma.make_regularizer(control, ma_config, caps_config)

    def sample(params: Any, obs: jax.Array, key: jax.Array) -> jax.Array:
        mean, log_std = actor.apply(params, obs)
        return sample_tanh_gaussian(key, mean, log_std)[0]

    def log_prob(params: Any, obs: jax.Array, action: jax.Array) -> jax.Array:
        mean, log_std = actor.apply(params, obs)
        return tanh_gaussian_log_prob(mean, log_std, action)

    def init(key: jax.Array, hyper: dict[str, jax.Array]) -> SACState:
        """Fresh parameters and optimizer states; ``hyper``: the values named in ``HYPER`` (MB-MPO:
        and ``"inner_lr"``), required: none defaults."""
        k_actor, k_critic = jax.random.split(key)
        obs = jnp.zeros((1, obs_dim))
        actor_params = actor.init(k_actor, obs)
        critic_params = critic.init(k_critic, obs, jnp.zeros((1, act_dim)))
        log_ent = jnp.log(jnp.asarray(config.init_entropy_coef, jnp.float32))
        return SACState(
            actor_params=actor_params,
            critic_params=critic_params,
            # Copies: a train state must not hold one buffer twice (it is donated to the step).
            target_critic_params=jax.tree.map(jnp.copy, critic_params),
            log_entropy_coef=log_ent,
            actor_opt=with_learning_rate(actor_tx.init(actor_params), hyper["actor_lr"]),
            critic_opt=with_learning_rate(critic_tx.init(critic_params), hyper["critic_lr"]),
            entropy_opt=with_learning_rate(entropy_tx.init(log_ent), hyper["entropy_lr"]),
            prev_actor_params=jax.tree.map(jnp.copy, actor_params),
            updates=jnp.zeros((), jnp.int32),
            hyper={k: jnp.asarray(v, jnp.float32) for k, v in hyper.items()},
        )

    def shape_rewards(state: SACState, batch: Transitions, key: jax.Array) -> Transitions:
        """The reward placement of MA: a batch transform before the critic loss."""
        _, k_shape = jax.random.split(key)
        reward = regularizer.shape_rewards(
            state.actor_params, batch.obs, batch.next_obs, batch.reward, k_shape,
            state.prev_actor_params, alpha=state.hyper["alpha"], terms=state.hyper["ma_terms"],
        )  # fmt: skip
        return batch.replace(reward=reward)

    def critic_loss(critic_params, state: SACState, batch: Transitions, key: jax.Array):
        k_next, k_value = jax.random.split(key)
        mean, log_std = actor.apply(state.actor_params, batch.next_obs)
        next_action, next_logp = sample_tanh_gaussian(k_next, mean, log_std)
        q_next = critic.apply(state.target_critic_params, batch.next_obs, next_action)
        ent = jnp.exp(state.log_entropy_coef)
        # The entropy-like placement of MA: its penalty at s' is paid like ent * log pi(a'|s').
        ma_next = regularizer.next_value_penalty(
            state.actor_params, batch.next_obs, k_value, state.prev_actor_params,
            alpha=state.hyper["alpha"], terms=state.hyper["ma_terms"],
        )  # fmt: skip
        v_next = jnp.min(q_next, axis=0) - ent * next_logp - ma_next
        target = batch.reward + config.gamma * (1.0 - batch.terminal) * v_next
        q = critic.apply(critic_params, batch.obs, batch.action)
        loss = 0.5 * jnp.mean(jnp.sum(jnp.square(q - jax.lax.stop_gradient(target)), axis=0))
        return loss, {"critic_loss": loss, "q_mean": jnp.mean(q)}

    def actor_loss(actor_params, state: SACState, batch: Transitions, key: jax.Array):
        k_sample, k_ma, k_caps = jax.random.split(key, 3)
        mean, log_std = actor.apply(actor_params, batch.obs)
        action, logp = sample_tanh_gaussian(k_sample, mean, log_std)
        q = jnp.min(critic.apply(state.critic_params, batch.obs, action), axis=0)
        ent = jnp.exp(state.log_entropy_coef)
        sac_loss = jnp.mean(ent * logp - q)
        pen, reg_metrics = regularizer.actor_penalty(
            actor_params, batch.obs, batch.next_obs, (k_ma, k_caps),
            prev_params=state.prev_actor_params, update_step=state.updates,
            controls=jnp.tanh(mean), alpha=state.hyper["alpha"], terms=state.hyper["ma_terms"],
        )  # fmt: skip
        metrics = {"actor_loss": sac_loss, "entropy": -jnp.mean(logp), **reg_metrics}
        return sac_loss + pen, (metrics, jnp.mean(logp))

    def entropy_loss(log_ent: jax.Array, mean_logp: jax.Array) -> jax.Array:
        return -log_ent * jax.lax.stop_gradient(mean_logp + target_entropy)

    def critic_step(state: SACState, batch: Transitions, key: jax.Array) -> tuple[SACState, dict]:
        """The reward transform, then one critic gradient step."""
        batch = shape_rewards(state, batch, key)
        (_, c_metrics), c_grads = jax.value_and_grad(critic_loss, has_aux=True)(
            state.critic_params, state, batch, key
        )
        critic_opt = with_learning_rate(state.critic_opt, state.hyper["critic_lr"])
        c_updates, critic_opt = critic_tx.update(c_grads, critic_opt, state.critic_params)
        critic_params = optax.apply_updates(state.critic_params, c_updates)
        return state.replace(critic_params=critic_params, critic_opt=critic_opt), c_metrics

    def finish_actor_step(
        state: SACState, a_grads: Any, mean_logp: jax.Array, new_actor_params: Any = None
    ) -> SACState:
        """Applies actor gradients (Adam), or sets ``new_actor_params`` when given (a step made
        elsewhere, e.g. TRPO), then the entropy-coefficient and target-critic updates."""
        if new_actor_params is None:
            actor_opt = with_learning_rate(state.actor_opt, state.hyper["actor_lr"])
            a_updates, actor_opt = actor_tx.update(a_grads, actor_opt, state.actor_params)
            actor_params = optax.apply_updates(state.actor_params, a_updates)
        else:
            actor_params, actor_opt = new_actor_params, state.actor_opt

        e_grad = jax.grad(entropy_loss)(state.log_entropy_coef, mean_logp)
        entropy_opt = with_learning_rate(state.entropy_opt, state.hyper["entropy_lr"])
        e_updates, entropy_opt = entropy_tx.update(e_grad, entropy_opt)
        log_ent = optax.apply_updates(state.log_entropy_coef, e_updates)
        target = optax.incremental_update(
            state.critic_params, state.target_critic_params, config.tau
        )
        return state.replace(
            actor_params=actor_params,
            actor_opt=actor_opt,
            prev_actor_params=state.actor_params,
            log_entropy_coef=log_ent,
            entropy_opt=entropy_opt,
            target_critic_params=target,
            updates=state.updates + 1,
        )

    def update(state: SACState, batch: Transitions, key: jax.Array) -> tuple[SACState, dict]:
        k_critic, k_actor = jax.random.split(key)
        state, c_metrics = critic_step(state, batch, k_critic)
        (_, (a_metrics, mean_logp)), a_grads = jax.value_and_grad(actor_loss, has_aux=True)(
            state.actor_params, state, batch, k_actor
        )
        new_state = finish_actor_step(state, a_grads, mean_logp)
        metrics = {
            **c_metrics, **a_metrics, "entropy_coef": jnp.exp(new_state.log_entropy_coef)
        }  # fmt: skip
        return new_state, metrics

    return SAC(
        init=init,
        update=update,
        control=control,
        sample=sample,
        critic_step=critic_step,
        actor_loss=actor_loss,
        finish_actor_step=finish_actor_step,
        log_prob=log_prob,
        dist=lambda params, obs: actor.apply(params, obs),
        regularizer=regularizer,
    )

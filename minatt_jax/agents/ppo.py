"""``--algo ppo``: proximal policy optimization (clipped surrogate, GAE) with minimum attention,
over many environments in one program.

Every iteration of the training program steps all ``num_envs`` environments with actions sampled
from a tanh-squashed Gaussian policy and writes the step into a rollout of ``H`` iterations,
``H = ppo.batch_size x ppo.minibatches / num_envs x ppo.unroll_length`` (brax's batch: as many
sequences of ``unroll_length`` steps as ``batch_size x minibatches``). When the rollout is full,
one update (a ``lax.cond`` on the unbatched step counter, so a population is one program):

1. the rewards scaled by ``ppo.reward_scaling`` (and, with ``ma.placement=reward``, lowered by
   the MA penalty of the policy that acted); generalized advantage estimation over each
   environment's ``H`` steps (``gae``), bootstrapped at time limits and at the rollout's end;
2. ``ppo.epochs`` passes over the rollout in ``ppo.minibatches`` shuffled minibatches, each an
   Adam step on the clipped surrogate (``clipped_surrogate``), the value loss, the entropy bonus
   and the MA penalty of the deterministic control u(x) = tanh(mean(x)) (``ma.placement=
   actor_loss``, the default).

Observations are normalized by their running statistics (``ppo.normalize_obs``). Settings follow
brax's published PPO configurations (``brax/training`` colab): halfcheetah's (unroll 20, 8
epochs, discount 0.95, learning rate 3e-4, entropy 1e-3, reward scale 1) and, for hopper, those
of its other locomotion tasks (unroll 5, 4 epochs, discount 0.97, entropy 1e-2, reward scale 10;
the colab trains hopper with SAC); 4 x 32 swish policy and 5 x 256 swish value networks, clip
0.3, GAE lambda 0.95, advantages normalized per minibatch. Deviations: the GAE runs over the
whole rollout of each environment (brax cuts it into sequences of ``unroll_length``); the entropy
bonus is the pre-tanh Gaussian's (brax samples the squashed one). The ``cpu`` preset keeps those
values with 32 environments and a batch of 64 sequences x 8 minibatches (10,240 env steps per
update); ``paper`` is brax's own (2,048 environments).

Meta-test adaptation: ``updates_per_step`` minibatch steps of the same loss per adaptation step,
on the new task's collected episodes (advantages from the trained value function).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from minatt_jax import acting
from minatt_jax import min_attention as ma
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
from minatt_jax.fields import check, setting
from minatt_jax.networks import ACTIVATIONS, MLP
from minatt_jax.sac import with_learning_rate


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO's settings (the ``ppo`` group; brax's names in parentheses).

    Attributes:
      policy_hidden: the policy MLP's hidden layers.
      value_hidden: the value MLP's hidden layers.
      activation: the hidden layers' activation of both networks.
      unroll_length: steps per sequence (unroll_length).
      batch_size: sequences per minibatch (batch_size).
      minibatches: minibatches per pass over a rollout (num_minibatches).
      epochs: passes over each rollout (num_updates_per_batch).
      lr: Adam's learning rate (learning_rate).
      entropy_cost: weight of the entropy bonus (entropy_cost).
      clip: the surrogate's clipping epsilon (clipping_epsilon).
      gamma: the discount (discounting).
      gae_lambda: lambda of the generalized advantage estimate (gae_lambda).
      value_cost: weight of the value loss (vf_loss_coefficient).
      reward_scaling: rewards are multiplied by it for learning (reward_scaling).
      normalize_obs: act on observations normalized by running statistics.
      normalize_advantage: advantages normalized per minibatch.
      max_grad_norm: clip the gradient's global norm to it (0: no clipping).
    """

    policy_hidden: tuple[int, ...] = setting((32, 32, 32, 32), min_length=1,
                                             item={"kind": int, "ge": 1})  # fmt: skip
    value_hidden: tuple[int, ...] = setting((256,) * 5, min_length=1, item={"kind": int, "ge": 1})
    activation: str = setting("swish", choices=tuple(ACTIVATIONS))
    unroll_length: int = setting(20, ge=1)
    batch_size: int = setting(64, ge=1)
    minibatches: int = setting(8, ge=1)
    epochs: int = setting(8, ge=1)
    lr: float = setting(3e-4, gt=0, le=1)
    entropy_cost: float = setting(1e-3, ge=0, le=10)
    clip: float = setting(0.3, gt=0, le=1)
    gamma: float = setting(0.95, ge=0, lt=1)
    gae_lambda: float = setting(0.95, ge=0, le=1)
    value_cost: float = setting(0.5, ge=0)
    reward_scaling: float = setting(1.0, gt=0)
    normalize_obs: bool = setting(True)
    normalize_advantage: bool = setting(True)
    max_grad_norm: float = setting(0.0, ge=0)

    def __post_init__(self) -> None:
        check(self, "ppo")


HYPER = {"alpha": "ma.alpha", "ma_terms": "ma.mode", "lr": "ppo.lr",
         "entropy_cost": "ppo.entropy_cost"}  # fmt: skip
PLACEMENTS = ("actor_loss", "reward")
STD_MIN = 1e-3  # the policy's std is softplus(raw) + STD_MIN (brax's NormalTanhDistribution)


def gae(
    rewards: jax.Array,
    values: jax.Array,
    next_values: jax.Array,
    terminal: jax.Array,
    ended: jax.Array,
    gamma: float,
    lam: float,
) -> tuple[jax.Array, jax.Array]:
    """Generalized advantage estimates and value targets over a time-major rollout (T, ...):
    delta_t = r_t + gamma (1 - terminal_t) V(s'_t) - V(s_t), A_t = delta_t + gamma lam
    (1 - ended_t) A_{t+1}; an episode that ended by its time limit (ended, not terminal) is
    bootstrapped with V(s'_t) and does not pass its advantage back across the reset."""
    deltas = rewards + gamma * (1.0 - terminal) * next_values - values

    def back(carry: jax.Array, t: tuple) -> tuple[jax.Array, jax.Array]:
        delta, end = t
        advantage = delta + gamma * lam * (1.0 - end) * carry
        return advantage, advantage

    _, advantages = jax.lax.scan(back, jnp.zeros_like(deltas[0]), (deltas, ended), reverse=True)
    return advantages, advantages + values


def clipped_surrogate(
    log_prob: jax.Array, old_log_prob: jax.Array, advantage: jax.Array, clip: float
) -> tuple[jax.Array, jax.Array]:
    """The negated clipped surrogate per sample, -min(r A, clip(r, 1 - eps, 1 + eps) A) with
    r = exp(log_prob - old_log_prob), and whether the clip was active."""
    ratio = jnp.exp(log_prob - old_log_prob)
    clipped = jnp.clip(ratio, 1.0 - clip, 1.0 + clip)
    return -jnp.minimum(ratio * advantage, clipped * advantage), jnp.abs(ratio - 1.0) > clip


class Batch(NamedTuple):
    """What one PPO loss reads per sample (normalized observations, pre-tanh actions)."""

    obs: jax.Array
    next_obs: jax.Array
    raw_action: jax.Array
    old_log_prob: jax.Array
    advantage: jax.Array
    target: jax.Array
    valid: jax.Array


@struct.dataclass
class Learner:
    params: dict  # {"policy": ..., "value": ...}
    opt_state: Any
    prev_policy: Any  # policy parameters before the last step (MA's temporal term)
    updates: jax.Array
    hyper: dict


@struct.dataclass
class Rollout:
    """The iterations since the last update, (H, num_envs, ...)."""

    obs: jax.Array
    next_obs: jax.Array
    raw_action: jax.Array
    log_prob: jax.Array
    reward: jax.Array
    terminal: jax.Array
    ended: jax.Array
    valid: jax.Array  # a finite simulator step


@struct.dataclass
class PPOState:
    agent: Learner
    env_state: Any
    episode_return: jax.Array
    episode_length: jax.Array
    rollout: Rollout
    normalizer: obs_norm.Normalizer
    rng: jax.Array
    env_steps: jax.Array

    def parameter_groups(self) -> dict:
        return {"policy parameters": self.agent.params["policy"],
                "value parameters": self.agent.params["value"]}  # fmt: skip

    def policy_items(self) -> tuple:
        return self.agent.params["policy"], self.normalizer


class Learning(NamedTuple):
    """PPO's pure functions for one configuration (training and adaptation share them)."""

    init: Any
    distribution: Any  # (policy params, x) -> (mean, std)
    control: Any  # (policy params, x) -> tanh(mean)
    value: Any  # (value params, x) -> V
    log_prob: Any  # (mean, std, raw action) -> Gaussian log-density
    step: Any  # (learner, Batch, key) -> (learner, metrics): one minibatch step
    regularizer: ma.Regularizer


def learning(config: Any, obs_dim: int, act_dim: int) -> Learning:
    """The networks, losses and minibatch step of a (resolved) configuration."""
    p = config.ppo
    policy_net = MLP(p.policy_hidden, 2 * act_dim, p.activation)
    value_net = MLP(p.value_hidden, 1, p.activation)
    adam = optax.inject_hyperparams(optax.adam)(learning_rate=0.0)
    tx = optax.chain(optax.clip_by_global_norm(p.max_grad_norm), adam) if p.max_grad_norm else adam

    def distribution(params: Any, x: jax.Array) -> tuple[jax.Array, jax.Array]:
        mean, raw = jnp.split(policy_net.apply(params, x), 2, axis=-1)
        return mean, jax.nn.softplus(raw) + STD_MIN

    def control(params: Any, x: jax.Array) -> jax.Array:
        return jnp.tanh(distribution(params, x)[0])

    def value(params: Any, x: jax.Array) -> jax.Array:
        return value_net.apply(params, x)[..., 0]

    def log_prob(mean: jax.Array, std: jax.Array, raw: jax.Array) -> jax.Array:
        # The tanh's Jacobian is a function of the raw action alone: it cancels in the ratio.
        z = (raw - mean) / std
        return jnp.sum(-0.5 * z**2 - jnp.log(std) - 0.5 * jnp.log(2 * jnp.pi), axis=-1)

    regularizer = ma.make_regularizer(control, config.ma)

    def init(key: jax.Array, hyper: dict) -> Learner:
        k_policy, k_value = jax.random.split(key)
        x = jnp.zeros((1, obs_dim))
        params = {"policy": policy_net.init(k_policy, x), "value": value_net.init(k_value, x)}
        opt_state = tx.init(params)
        return Learner(params, _with_lr(opt_state, hyper["lr"]),
                       jax.tree.map(jnp.copy, params["policy"]), jnp.zeros((), jnp.int32),
                       {k: jnp.asarray(v, jnp.float32) for k, v in hyper.items()})  # fmt: skip

    def loss(params: dict, learner: Learner, b: Batch, key: jax.Array) -> tuple:
        mean, std = distribution(params["policy"], b.obs)
        advantage = b.advantage
        weight = b.valid / jnp.maximum(jnp.sum(b.valid), 1.0)
        if p.normalize_advantage:
            centred = advantage - jnp.sum(weight * advantage)
            advantage = centred / (jnp.sqrt(jnp.sum(weight * centred**2)) + 1e-8)
        surrogate, clipped = clipped_surrogate(log_prob(mean, std, b.raw_action), b.old_log_prob,
                                               advantage, p.clip)  # fmt: skip
        policy_loss = jnp.sum(weight * surrogate)
        value_loss = 0.5 * p.value_cost * jnp.sum(weight * (value(params["value"], b.obs)
                                                            - b.target) ** 2)  # fmt: skip
        entropy = jnp.sum(weight * jnp.sum(0.5 * jnp.log(2 * jnp.pi * jnp.e * std**2), -1))
        penalty, ma_metrics = regularizer.actor_penalty(
            params["policy"], b.obs, b.next_obs, (key, key), learner.prev_policy,
            learner.updates, alpha=learner.hyper["alpha"], terms=learner.hyper["ma_terms"],
        )  # fmt: skip
        total = policy_loss + value_loss - learner.hyper["entropy_cost"] * entropy + penalty
        return total, {"policy_loss": policy_loss, "value_loss": value_loss, "entropy": entropy,
                       "clip_fraction": jnp.sum(weight * clipped), **ma_metrics}  # fmt: skip

    def step(learner: Learner, b: Batch, key: jax.Array) -> tuple[Learner, dict]:
        grads, metrics = jax.grad(loss, has_aux=True)(learner.params, learner, b, key)
        opt_state = _with_lr(learner.opt_state, learner.hyper["lr"])
        updates, opt_state = tx.update(grads, opt_state, learner.params)
        params = optax.apply_updates(learner.params, updates)
        learner = learner.replace(params=params, opt_state=opt_state,
                                  prev_policy=learner.params["policy"],
                                  updates=learner.updates + 1)  # fmt: skip
        return learner, metrics

    return Learning(init, distribution, control, value, log_prob, step, regularizer)


def _with_lr(opt_state: Any, lr: jax.Array) -> Any:
    """The optimizer state with Adam's learning rate set (chained after clipping or alone)."""
    if isinstance(opt_state, tuple) and not hasattr(opt_state, "hyperparams"):
        return (*opt_state[:-1], with_learning_rate(opt_state[-1], lr))
    return with_learning_rate(opt_state, lr)


def advantages_of(lrn: Learning, learner: Learner, x: jax.Array, x_next: jax.Array,
                  raw: jax.Array, reward: jax.Array, terminal: jax.Array, ended: jax.Array,
                  key: jax.Array, config: Any) -> tuple[jax.Array, jax.Array]:  # fmt: skip
    """Advantages and value targets of a time-major rollout (T, n, ...): rewards scaled and,
    with MA's reward placement, lowered by the penalty of the policy that acted."""
    p, shape = config.ppo, reward.shape
    flat = lambda a: a.reshape((-1,) + a.shape[2:])  # noqa: E731
    policy = learner.params["policy"]
    rewards = lrn.regularizer.shape_rewards(
        policy, flat(x), flat(x_next), flat(reward) * p.reward_scaling, key, learner.prev_policy,
        alpha=learner.hyper["alpha"], terms=learner.hyper["ma_terms"],
    ).reshape(shape)  # fmt: skip
    values = lrn.value(learner.params["value"], x)
    next_values = lrn.value(learner.params["value"], x_next)
    return gae(rewards, values, next_values, terminal, ended, p.gamma, p.gae_lambda)


def rollout_iterations(config: Any) -> int:
    """H: the iterations (env steps of every environment) per update."""
    p = config.ppo
    return p.batch_size * p.minibatches // config.num_envs * p.unroll_length


def policy_family(config: Any, env: Any) -> PolicyFamily:
    """The tanh-Gaussian policy on normalized observations; numpy export of its MLP."""
    lrn = learning(config, env.observation_size, env.action_size)
    shapes = jax.eval_shape(lrn.init, jax.random.PRNGKey(0), abstract_hyper(HYPER))
    policy = zeros_like_shapes(shapes.params["policy"])
    norm = obs_norm.init_normalizer(env.observation_size)
    normalize = config.ppo.normalize_obs

    def stochastic(params: Any, normalizer: Any) -> acting.Policy:
        def act(x: jax.Array, key: jax.Array) -> jax.Array:
            mean, std = lrn.distribution(params, x)
            return jnp.tanh(mean + std * jax.random.normal(key, mean.shape))

        return acting.Policy(act=act, control=lambda x: lrn.control(params, x),
                             prepare=acting.deterministic(lrn.control, params, normalizer,
                                                          normalize).prepare)  # fmt: skip

    def numpy_form(params: Any, normalizer: Any) -> NumpyForm:
        return mlp_numpy_form(params["params"], config.ppo.activation, normalizer, normalize)

    return PolicyFamily(
        agent=lrn,
        like=(policy, norm),
        checkpoint_items={"agent/params/policy": policy, "normalizer": norm},
        from_items=lambda parts: (parts["agent/params/policy"], parts["normalizer"]),
        deterministic=lambda params, n: acting.deterministic(lrn.control, params, n, normalize),
        stochastic=stochastic,
        recurrent=False,
        export=numpy_form,
    )


def defaults(config: Any) -> dict[str, Any]:
    """The training task set, one update slot per iteration, and the batch's divisibility."""
    p, n = config.ppo, config.num_envs
    if (p.batch_size * p.minibatches) % n:
        raise ValueError(f"ppo.batch_size x ppo.minibatches ({p.batch_size * p.minibatches}) "
                         f"must be a multiple of num_envs ({n})")  # fmt: skip
    if (config.eval_every // n) % rollout_iterations(config):
        raise ValueError(f"eval_every ({config.eval_every}) must hold whole updates of "
                         f"{rollout_iterations(config) * n} env steps (ppo.batch_size x "
                         "ppo.minibatches x ppo.unroll_length)")  # fmt: skip
    return {"task_set": "nominal", "updates_per_step": 1}


def make(config: Any, env: Any, task_set: Any) -> Agent:
    """The ppo agent of a resolved configuration (see the module docstring)."""
    p, n = config.ppo, config.num_envs
    obs_dim, act_dim = env.observation_size, env.action_size
    lrn = learning(config, obs_dim, act_dim)
    horizon = rollout_iterations(config)
    samples = horizon * n
    minibatch = samples // p.minibatches

    def normalize(norm: Any, obs: jax.Array) -> jax.Array:
        return obs_norm.normalize(norm, obs, p.normalize_obs)

    def reset(key: jax.Array) -> Any:
        return acting.reset_with_tasks(env, task_set, n, key)

    def init(key: jax.Array, hyper: dict) -> PPOState:
        k_agent, k_env, k_run = jax.random.split(key, 3)
        zeros = lambda *shape: jnp.zeros((horizon, n, *shape))  # noqa: E731
        rollout = Rollout(zeros(obs_dim), zeros(obs_dim), zeros(act_dim), zeros(), zeros(),
                          zeros(), zeros(), zeros())  # fmt: skip
        return PPOState(lrn.init(k_agent, hyper), reset(k_env), jnp.zeros((n,)),
                        jnp.zeros((n,), jnp.int32), rollout, obs_norm.init_normalizer(obs_dim),
                        k_run, jnp.zeros((), jnp.int32))  # fmt: skip

    def collect(ts: PPOState, keys: dict, steps: jax.Array, members_axis: str | None) -> tuple:
        mean, std = lrn.distribution(ts.agent.params["policy"],
                                     normalize(ts.normalizer, ts.env_state.obs))  # fmt: skip
        raw = mean + std * jax.random.normal(keys["act"], mean.shape)
        c = acting.collect_step(env, ts.env_state, jnp.tanh(raw), ts.episode_return,
                                ts.episode_length, config.episode_limit, reset, keys["reset"],
                                members_axis)  # fmt: skip
        t, i = c.transitions, (steps // n) % horizon
        finite = c.finite.astype(jnp.float32)
        row = Rollout(t.obs, t.next_obs, raw, lrn.log_prob(mean, std, raw),
                      jnp.where(c.finite, t.reward, 0.0), t.terminal.astype(jnp.float32),
                      c.ended.astype(jnp.float32), finite)  # fmt: skip
        rollout = jax.tree.map(lambda buf, x: buf.at[i].set(jnp.where(jnp.isfinite(x), x, 0.0)),
                               ts.rollout, row)  # fmt: skip
        ts = ts.replace(env_state=c.env_state, episode_return=c.episode_return,
                        episode_length=c.episode_length, rollout=rollout)  # fmt: skip
        metrics = {"episode_return_sum": c.finished_return,
                   "episodes": jnp.sum((c.ended & c.finite).astype(jnp.float32)),
                   "env_non_finite": jnp.sum(1.0 - finite)}  # fmt: skip
        return ts, (t.next_obs, c.finite), metrics

    def store(ts: PPOState, collected: tuple) -> PPOState:
        next_obs, finite = collected
        if not p.normalize_obs:
            return ts
        updated = obs_norm.update(ts.normalizer, jnp.where(finite[:, None], next_obs, 0.0))
        keep = jnp.all(finite)
        return ts.replace(normalizer=jax.tree.map(lambda a, b: jnp.where(keep, a, b), updated,
                                                  ts.normalizer))  # fmt: skip

    def ppo_update(ts: PPOState, key: jax.Array) -> tuple[PPOState, dict]:
        r, learner = ts.rollout, ts.agent
        k_shape, k_epochs = jax.random.split(key)
        x, x_next = normalize(ts.normalizer, r.obs), normalize(ts.normalizer, r.next_obs)
        advantage, target = advantages_of(lrn, learner, x, x_next, r.raw_action, r.reward,
                                          r.terminal, r.ended, k_shape, config)  # fmt: skip
        flat = lambda a: a.reshape((samples,) + a.shape[2:])  # noqa: E731
        data = Batch(flat(x), flat(x_next), flat(r.raw_action), flat(r.log_prob),
                     flat(advantage), flat(target), flat(r.valid))  # fmt: skip

        def epoch(learner: Learner, k: jax.Array) -> tuple[Learner, dict]:
            k_perm, k_steps = jax.random.split(k)
            order = jax.random.permutation(k_perm, samples).reshape(p.minibatches, minibatch)
            batches = jax.tree.map(lambda a: a[order], data)
            keys = jax.random.split(k_steps, p.minibatches)
            return jax.lax.scan(lambda lr, xs: lrn.step(lr, *xs), learner, (batches, keys))

        learner, metrics = jax.lax.scan(epoch, learner, jax.random.split(k_epochs, p.epochs))
        metrics = {k: jnp.mean(v) for k, v in metrics.items()}
        return ts.replace(agent=learner), {**metrics, "updated": jnp.ones(())}

    abstract = jax.eval_shape(init, jax.random.PRNGKey(0), abstract_hyper(HYPER))
    names = jax.eval_shape(ppo_update, abstract, jax.random.PRNGKey(0))[1]

    def update(ts: PPOState, keys: dict, steps: jax.Array) -> tuple[PPOState, dict]:
        due = (steps // n) % horizon == 0  # the unbatched counter: one branch per population

        def skip(ts: PPOState, key: jax.Array) -> tuple[PPOState, dict]:
            return ts, {k: jnp.zeros(v.shape, v.dtype) for k, v in names.items()}

        return jax.lax.cond(due, ppo_update, skip, ts, keys["update"])

    def summarize(ts: PPOState, per: dict) -> dict:
        updated = per["updated"]
        count = jnp.maximum(jnp.sum(updated), 1.0)
        episodes = jnp.sum(per["episodes"])
        summary = {k: jnp.sum(per[k] * updated) / count for k in names if k != "updated"}
        return {**summary, "updates": jnp.sum(updated) * p.epochs * p.minibatches,
                "train_episodes": episodes, "env_non_finite_resets": jnp.sum(per["env_non_finite"]),
                "train_episode_return": jnp.sum(per["episode_return_sum"])
                / jnp.maximum(episodes, 1)}  # fmt: skip

    return Agent(keys=("act", "reset", "update"), init=init, collect=collect, store=store,
                 update=update, summarize=summarize, policy=policy_family(config, env),
                 parts={"update": ppo_update})  # fmt: skip


def adapter(config: Any, env: Any, family: PolicyFamily, settings: Any) -> Adapter:
    """A meta-test step of ppo: ``updates_per_step`` minibatch steps of the training loss on
    the new task's collected episodes (advantages from the trained value function)."""
    lrn = family.agent
    p = config.ppo
    shapes = jax.eval_shape(lrn.init, jax.random.PRNGKey(0), abstract_hyper(HYPER))
    size = settings.shots * config.episode_limit
    minibatch = min(size, p.batch_size * p.unroll_length)

    def prepare(parts: dict, normalizer: Any, traj: acting.Trajectory, key: jax.Array,
                refit: bool) -> Batch:  # fmt: skip
        learner = parts["agent"]
        norm = lambda o: obs_norm.normalize(normalizer, o, p.normalize_obs)  # noqa: E731
        x, x_next = norm(traj.obs), norm(traj.next_obs)  # (shots, T, ...)
        raw = jnp.arctanh(jnp.clip(traj.action, -1 + 1e-6, 1 - 1e-6))
        mean, std = lrn.distribution(learner.params["policy"], x)
        last = jnp.zeros_like(traj.done).at[:, -1].set(1.0)  # the collection's last step
        ended = jnp.maximum(last, traj.done)
        time_major = lambda a: jnp.swapaxes(a, 0, 1)  # noqa: E731
        advantage, target = advantages_of(
            lrn, learner, time_major(x), time_major(x_next), time_major(raw),
            time_major(traj.reward), time_major(traj.done), time_major(ended), key, config,
        )  # fmt: skip
        flat = lambda a: a.reshape((size,) + a.shape[2:])  # noqa: E731
        return Batch(flat(x), flat(x_next), flat(raw), flat(lrn.log_prob(mean, std, raw)),
                     flat(time_major(advantage)), flat(time_major(target)),
                     flat(traj.alive))  # fmt: skip

    @jax.jit
    def step(learner: Learner, batch: Batch, key: jax.Array) -> Learner:
        def one(learner: Learner, k: jax.Array) -> tuple[Learner, None]:
            k_rows, k_step = jax.random.split(k)
            rows = jax.random.choice(k_rows, size, (minibatch,), replace=False)
            return lrn.step(learner, jax.tree.map(lambda a: a[rows], batch), k_step)[0], None

        return jax.lax.scan(one, learner, jax.random.split(key, settings.updates_per_step))[0]

    return Adapter(like={"agent": zeros_like_shapes(shapes)}, prepare=prepare, step=step,
                   policy_params=lambda learner: learner.params["policy"])  # fmt: skip


def preset_settings(preset: str, env: str) -> dict[str, Any]:
    """What a preset sets for PPO (see the module docstring): brax's hopper-like settings on
    hopper and walker2d, its halfcheetah settings elsewhere; the batch by preset."""
    hopper_like = env in ("hopper", "walker2d")
    sizes = {
        "smoke": {
            "num_envs": 4,
            "eval_every": 320,
            "total_steps": 640,
            "ppo.batch_size": 4,
            "ppo.minibatches": 2,
            "ppo.unroll_length": 8,
            "ppo.epochs": 2,
            "ppo.policy_hidden": (16, 16),
            "ppo.value_hidden": (32, 32),
        },
        "cpu": {"num_envs": 32, "eval_every": 102_400, "total_steps": 2_048_000},
        "paper": {
            "num_envs": 2048,
            "eval_every": 2_621_440 if hopper_like else 5_242_880,
            "total_steps": 52_428_800,
            "ppo.minibatches": 32,
            "ppo.batch_size": 1024 if hopper_like else 512,
        },
    }[preset]
    shape = ({"ppo.unroll_length": 5, "ppo.epochs": 4, "ppo.gamma": 0.97,
              "ppo.entropy_cost": 1e-2, "ppo.reward_scaling": 10.0} if hopper_like
             else {"ppo.unroll_length": 20, "ppo.epochs": 8, "ppo.gamma": 0.95,
                   "ppo.entropy_cost": 1e-3, "ppo.reward_scaling": 1.0})  # fmt: skip
    if preset == "cpu" and hopper_like:
        shape = {**shape, "ppo.batch_size": 256}  # 256 x 8 sequences of 5 steps, as halfcheetah's
    return {**shape, **sizes}


SPEC = registry.register(
    registry.AgentSpec(
        name="ppo",
        make=make,
        policy=policy_family,
        hyper=HYPER,
        groups=(registry.SettingsGroup("ppo", PPOConfig),),
        defaults=defaults,
        adapter=adapter,
        placements=PLACEMENTS,
        preset_settings=preset_settings,
    )
)

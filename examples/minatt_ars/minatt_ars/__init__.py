"""``--algo ars``: augmented random search (Mania, Guy and Recht, 2018, "Simple random search
provides a competitive approach to reinforcement learning", its V2 with normalized states) of a
linear policy u(x) = tanh(W x + b), with minimum attention, as a minatt-jax plugin.

Every iteration of the training program steps ``2 * ars.directions`` environments: environment
2k acts with the parameters theta + noise * delta_k, environment 2k + 1 with theta - noise *
delta_k, and each adds its (shaped) rewards to its fitness. Every ``ars.horizon`` iterations the
update moves theta along the directions whose fitness differs most,

    theta <- theta + step_size / (top * sigma_R) * sum_k (R_k+ - R_k-) delta_k,

then takes one gradient step of size ``step_size`` on the minimum-attention penalty of the
states the window visited, and draws new directions. Fitness windows run across episode ends
(the environments reset as usual), so the schedule is a ``lax.cond`` on the unbatched step
counter and a population of ARS members is one program.

Minimum attention enters in two placements (``PLACEMENTS``): "actor_loss", the gradient step on
the penalty after each search step, and "reward", each step's reward lowered by the penalty of
the perturbed policy that acted. The agent owns its settings (the ``ars`` group, ``ARSConfig``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from minatt_jax import acting
from minatt_jax import min_attention as ma
from minatt_jax import normalizer as obs_norm
from minatt_jax.agents import registry
from minatt_jax.agents.base import Agent, NumpyForm, PolicyFamily, no_adaptation
from minatt_jax.fields import check, setting


@dataclasses.dataclass(frozen=True)
class ARSConfig:
    """Augmented random search's settings (the ``ars`` group; the paper's names).

    Attributes:
      directions: search directions per update (N); the run steps 2 N environments.
      top: the update uses the ``top`` directions of largest max(R+, R-) (b; 0: all N).
      step_size: the step size alpha of the search step and of the penalty's gradient step.
      noise: the exploration noise nu of the perturbations theta +- nu delta.
      horizon: iterations (env steps of every environment) per fitness window.
      normalize_obs: act on states normalized by their running mean and variance (ARS V2).
    """

    directions: int = setting(4, ge=1)
    top: int = setting(0, ge=0)
    step_size: float = setting(0.02, gt=0, le=10)
    noise: float = setting(0.03, gt=0)
    horizon: int = setting(50, ge=1)
    normalize_obs: bool = setting(True)

    def __post_init__(self) -> None:
        check(self, "ars")
        if self.top > self.directions:
            raise ValueError(f"ars.top ({self.top}) must be at most ars.directions "
                             f"({self.directions})")  # fmt: skip


HYPER = {"alpha": "ma.alpha", "ma_terms": "ma.mode", "step_size": "ars.step_size"}
PLACEMENTS = ("actor_loss", "reward")


@struct.dataclass
class Learner:
    params: dict  # {"W": (act, obs), "b": (act,)}
    prev_params: dict  # before the last update (MA's temporal term)
    updates: jax.Array
    hyper: dict  # what a population sweeps (HYPER)


@struct.dataclass
class ARSState:
    """The whole training state of an ARS run (one pytree; checkpointed item by item)."""

    agent: Learner
    env_state: Any
    episode_return: jax.Array  # (n,)
    episode_length: jax.Array  # (n,)
    fitness: jax.Array  # (n,) the window's summed (shaped) rewards per environment
    deltas: dict  # the window's directions, {"W": (N, act, obs), "b": (N, act)}
    window_obs: jax.Array  # (horizon, n, obs) the window's states (MA's gradient step)
    window_next: jax.Array  # (horizon, n, obs) and their successors
    normalizer: obs_norm.Normalizer
    rng: jax.Array
    env_steps: jax.Array

    def parameter_groups(self) -> dict:
        return {"policy parameters": self.agent.params}

    def policy_items(self) -> tuple:
        return self.agent.params, self.normalizer


def control(params: dict, x: jax.Array) -> jax.Array:
    """The deterministic control u(x) = tanh(W x + b) of a (normalized) state x."""
    return jnp.tanh(params["W"] @ x + params["b"])


def policy_family(config: Any, env: Any) -> PolicyFamily:
    """The linear policy on normalized states: acting, checkpoint items, numpy export."""
    act_dim, obs_dim = env.action_size, env.observation_size
    like = {"W": np.zeros((act_dim, obs_dim), np.float32), "b": np.zeros((act_dim,), np.float32)}
    norm = obs_norm.init_normalizer(obs_dim)
    normalize = config.ars.normalize_obs

    def deterministic(params: dict, normalizer: Any) -> acting.Policy:
        return acting.deterministic(control, params, normalizer, normalize)

    def numpy_form(params: dict, normalizer: Any) -> NumpyForm:
        # One layer, no hidden activation: tanh of W x + b is the loader's output transform.
        kernel, bias = np.asarray(params["W"], np.float32).T, np.asarray(params["b"], np.float32)
        return NumpyForm([(kernel, bias)], "identity", np.asarray(normalizer.mean),
                         np.asarray(normalizer.var), normalize)  # fmt: skip

    return PolicyFamily(
        agent=None,
        like=(like, norm),
        checkpoint_items={"agent/params": like, "normalizer": norm},
        from_items=lambda parts: (parts["agent/params"], parts["normalizer"]),
        deterministic=deterministic,
        stochastic=deterministic,  # ARS explores by perturbing parameters, not actions
        recurrent=False,
        export=numpy_form,
    )


def defaults(config: Any) -> dict[str, Any]:
    """The training task set, one update slot per env step, and the environment count."""
    s, n = config.ars, config.num_envs
    if n != 2 * s.directions:
        raise ValueError(f"ars steps 2 x ars.directions environments: set num_envs to "
                         f"{2 * s.directions} (num_envs is {n})")  # fmt: skip
    if config.eval_every // n < s.horizon:
        raise ValueError(f"eval_every ({config.eval_every}) must cover one fitness window "
                         f"(ars.horizon x num_envs = {s.horizon * n})")  # fmt: skip
    return {"task_set": "nominal", "updates_per_step": 1}


def make(config: Any, env: Any, task_set: Any) -> Agent:
    """The ars agent of a resolved configuration (see the module docstring)."""
    s = config.ars
    n, obs_dim, act_dim = config.num_envs, env.observation_size, env.action_size
    top = s.top or s.directions
    regularizer = ma.make_regularizer(control, config.ma)

    def normalize(norm: Any, obs: jax.Array) -> jax.Array:
        return obs_norm.normalize(norm, obs, s.normalize_obs)

    def draw_deltas(key: jax.Array) -> dict:
        k_w, k_b = jax.random.split(key)
        return {"W": jax.random.normal(k_w, (s.directions, act_dim, obs_dim)),
                "b": jax.random.normal(k_b, (s.directions, act_dim))}  # fmt: skip

    def perturbed(params: dict, deltas: dict) -> dict:
        """(n, ...) parameters: +delta_k for environment 2k, -delta_k for 2k + 1."""
        sign = jnp.tile(jnp.asarray([1.0, -1.0]), s.directions)
        return jax.tree.map(lambda p, d: p + s.noise * sign.reshape((n,) + (1,) * p.ndim)
                            * jnp.repeat(d, 2, axis=0), params, deltas)  # fmt: skip

    def reset(key: jax.Array) -> Any:
        return acting.reset_with_tasks(env, task_set, n, key)

    def init(key: jax.Array, hyper: dict) -> ARSState:
        k_env, k_delta, k_run = jax.random.split(key, 3)
        params = {"W": jnp.zeros((act_dim, obs_dim)), "b": jnp.zeros((act_dim,))}
        window = jnp.zeros((s.horizon, n, obs_dim))
        return ARSState(
            agent=Learner(params, jax.tree.map(jnp.copy, params), jnp.zeros((), jnp.int32),
                          {k: jnp.asarray(v, jnp.float32) for k, v in hyper.items()}),
            env_state=reset(k_env), episode_return=jnp.zeros((n,)),
            episode_length=jnp.zeros((n,), jnp.int32), fitness=jnp.zeros((n,)),
            deltas=draw_deltas(k_delta), window_obs=window, window_next=window,
            normalizer=obs_norm.init_normalizer(obs_dim), rng=k_run,
            env_steps=jnp.zeros((), jnp.int32),
        )  # fmt: skip

    def collect(ts: ARSState, keys: dict, steps: jax.Array, members_axis: str | None) -> tuple:
        learner = ts.agent
        acting_params = perturbed(learner.params, ts.deltas)
        x = normalize(ts.normalizer, ts.env_state.obs)
        action = jax.vmap(control)(acting_params, x)
        c = acting.collect_step(env, ts.env_state, action, ts.episode_return, ts.episode_length,
                                config.episode_limit, reset, keys["reset"],
                                members_axis)  # fmt: skip
        t = c.transitions
        x_next = normalize(ts.normalizer, t.next_obs)

        def shaped(params: dict, obs: jax.Array, nxt: jax.Array, reward: jax.Array) -> jax.Array:
            # MA's reward placement: the penalty of the perturbed policy that acted (identity
            # in the other placements).
            return regularizer.shape_rewards(
                params, obs[None], nxt[None], reward[None], keys["ma"], learner.prev_params,
                alpha=learner.hyper["alpha"], terms=learner.hyper["ma_terms"],
            )[0]  # fmt: skip

        rewards = jax.vmap(shaped)(acting_params, x, x_next, t.reward)
        i = (steps // n) % s.horizon
        ts = ts.replace(
            env_state=c.env_state, episode_return=c.episode_return,
            episode_length=c.episode_length,
            fitness=ts.fitness + jnp.where(c.finite, rewards, 0.0),
            window_obs=ts.window_obs.at[i].set(x), window_next=ts.window_next.at[i].set(x_next),
        )  # fmt: skip
        metrics = {"episode_return_sum": c.finished_return,
                   "episodes": jnp.sum((c.ended & c.finite).astype(jnp.float32))}  # fmt: skip
        return ts, t.next_obs, metrics

    def store(ts: ARSState, next_obs: jax.Array) -> ARSState:
        finite = jnp.all(jnp.isfinite(next_obs))
        updated = obs_norm.update(ts.normalizer, jnp.where(finite, next_obs, 0.0))
        return ts.replace(normalizer=jax.tree.map(lambda a, b: jnp.where(finite, a, b),
                                                  updated, ts.normalizer))  # fmt: skip

    def search_step(ts: ARSState, key: jax.Array) -> tuple[ARSState, dict]:
        learner = ts.agent
        plus, minus = ts.fitness[0::2], ts.fitness[1::2]
        order = jnp.argsort(-jnp.maximum(plus, minus))[:top]
        diff = (plus - minus)[order]
        sigma = jnp.std(jnp.concatenate([plus[order], minus[order]])) + 1e-8
        step = learner.hyper["step_size"]
        params = jax.tree.map(
            lambda p, d: p + step / (top * sigma) * jnp.tensordot(diff, d[order], axes=1),
            learner.params, ts.deltas,
        )  # fmt: skip

        # MA's actor placement: one gradient step on the penalty of the window's states.
        def penalty(p: dict) -> tuple[jax.Array, dict]:
            obs = ts.window_obs.reshape(-1, obs_dim)
            nxt = ts.window_next.reshape(-1, obs_dim)
            return regularizer.actor_penalty(
                p, obs, nxt, (key, key), learner.params, learner.updates,
                alpha=learner.hyper["alpha"], terms=learner.hyper["ma_terms"],
            )  # fmt: skip

        grads, parts = jax.grad(penalty, has_aux=True)(params)
        params = jax.tree.map(lambda p, g: p - step * g, params, grads)
        learner = learner.replace(params=params, prev_params=learner.params,
                                  updates=learner.updates + 1)  # fmt: skip
        ts = ts.replace(agent=learner, fitness=jnp.zeros_like(ts.fitness),
                        deltas=draw_deltas(jax.random.fold_in(key, 1)))  # fmt: skip
        return ts, {"fitness_spread": sigma,
                    "ma_penalty": jnp.asarray(parts.get("ma_penalty", 0.0), jnp.float32),
                    "updated": jnp.ones(())}  # fmt: skip

    def update(ts: ARSState, keys: dict, steps: jax.Array) -> tuple[ARSState, dict]:
        due = (steps // n) % s.horizon == 0  # the unbatched counter: one branch per population

        def skip(ts: ARSState, key: jax.Array) -> tuple[ARSState, dict]:
            zero = jnp.zeros(())
            return ts, {"fitness_spread": zero, "ma_penalty": zero, "updated": zero}

        return jax.lax.cond(due, search_step, skip, ts, keys["update"])

    def summarize(ts: ARSState, per: dict) -> dict:
        episodes = jnp.sum(per["episodes"])
        updates = jnp.maximum(jnp.sum(per["updated"]), 1.0)
        return {
            "train_episode_return": jnp.sum(per["episode_return_sum"]) / jnp.maximum(episodes, 1),
            "train_episodes": episodes,
            "fitness_spread": jnp.sum(per["fitness_spread"]) / updates,
            "ma_penalty": jnp.sum(per["ma_penalty"]) / updates,
            "updates": jnp.sum(per["updated"]),
        }

    return Agent(keys=("reset", "ma", "update"), init=init, collect=collect, store=store,
                 update=update, summarize=summarize, policy=policy_family(config, env))  # fmt: skip


SPEC = registry.register(
    registry.AgentSpec(
        name="ars",
        make=make,
        policy=policy_family,
        hyper=HYPER,
        # The smoke preset: 2 directions (4 environments), short windows.
        groups=(
            registry.SettingsGroup(
                "ars",
                ARSConfig,
                presets={
                    "smoke": {"directions": 2, "horizon": 25},
                },
            ),
        ),  # fmt: skip
        defaults=defaults,
        adapter=no_adaptation,
        placements=PLACEMENTS,
        # num_envs is a common field: the agent's presets set it to 2 x directions.
        preset_settings=lambda preset, env: {"num_envs": 4 if preset == "smoke" else 8},
    )
)

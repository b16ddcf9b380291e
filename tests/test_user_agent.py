"""A user's own agent, defined in this file alone, trains through the library unchanged.

The agent: a linear-tanh policy u(x) = tanh(W x + b) with Gaussian exploration, trained by
REINFORCE on each step's reward (a contextual-bandit reading: the simplest policy gradient), with
the library's minimum-attention regularizer on its actor loss. It is registered under
``"toy_reinforce"`` and then trained as a 2-member population (alpha 0 and 5) through the
generic training program, checkpointed, resumed exactly and evaluated, with no module of the
library changed.
"""

from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from minatt_jax import acting, population, runner
from minatt_jax import min_attention as ma
from minatt_jax.agents import registry
from minatt_jax.agents.base import Agent, PolicyFamily
from minatt_jax.config import PRESETS, resolve, with_overrides
from minatt_jax.fields import check, setting
from minatt_jax.replay import Transitions

SIGMA = 0.3  # exploration noise of the Gaussian policy


@dataclasses.dataclass(frozen=True)
class ToySettings:
    """The toy agent's own settings (``--set toy.lr=...``).

    Attributes:
      lr: the policy's gradient step size.
    """

    lr: float = setting(1e-2, gt=0, le=10)

    def __post_init__(self) -> None:
        check(self, "toy")


@struct.dataclass
class Learner:
    params: dict
    prev_params: dict  # before the last update (MA's temporal term)
    updates: jax.Array
    hyper: dict  # "alpha", "ma_terms", "lr": what a population sweeps


@struct.dataclass
class ToyState:
    agent: Learner
    env_state: object
    episode_return: jax.Array
    episode_length: jax.Array
    rng: jax.Array
    env_steps: jax.Array
    last: object  # the last collected transitions (what the update learns from)

    def parameter_groups(self) -> dict:
        return {"policy parameters": self.agent.params}

    def policy_items(self) -> tuple:
        return self.agent.params, {}


def control(params: dict, x: jax.Array) -> jax.Array:
    return jnp.tanh(x @ params["W"].T + params["b"])


def policy_family(config, env) -> PolicyFamily:
    like = {"W": np.zeros((env.action_size, env.observation_size), np.float32),
            "b": np.zeros((env.action_size,), np.float32)}  # fmt: skip
    return PolicyFamily(
        agent=None,
        like=(like, {}),
        checkpoint_items={"agent/params": like},
        from_items=lambda parts: (parts["agent/params"], {}),
        deterministic=lambda p, _: acting.deterministic(control, p),
        stochastic=lambda p, _: acting.Policy(
            act=lambda x, k: jnp.clip(
                control(p, x) + SIGMA * jax.random.normal(k, (len(p["b"]),)), -1.0, 1.0
            ),  # fmt: skip
            control=lambda x: control(p, x),
        ),
        recurrent=False,
    )


def make(config, env, task_set, lazy: bool = False) -> Agent:
    """The toy agent; ``lazy`` calls only the actor hook (an agent that drops the penalty under
    the reward placement, which the training program refuses)."""
    n, obs_dim, act_dim = config.num_envs, env.observation_size, env.action_size
    regularizer = ma.make_regularizer(control, config.ma)

    def reset(key):
        return acting.reset_with_tasks(env, task_set, n, key)

    def init(key, hyper):
        k_w, k_env, k_run = jax.random.split(key, 3)
        params = {"W": 0.01 * jax.random.normal(k_w, (act_dim, obs_dim)), "b": jnp.zeros(act_dim)}
        zeros = jnp.zeros((n,))
        empty = Transitions(jnp.zeros((n, obs_dim)), jnp.zeros((n, act_dim)), zeros,
                                   jnp.zeros((n, obs_dim)), zeros)  # fmt: skip
        return ToyState(
            agent=Learner(params, jax.tree.map(jnp.copy, params), jnp.zeros((), jnp.int32),
                          {k: jnp.asarray(v, jnp.float32) for k, v in hyper.items()}),
            env_state=reset(k_env), episode_return=zeros, episode_length=zeros.astype(jnp.int32),
            rng=k_run, env_steps=jnp.zeros((), jnp.int32), last=empty,
        )  # fmt: skip

    def collect(ts, keys, steps, members_axis):
        mean = control(ts.agent.params, ts.env_state.obs)
        noise = SIGMA * jax.random.normal(keys["act"], mean.shape)
        action = jnp.clip(mean + noise, -1.0, 1.0)
        s = acting.collect_step(env, ts.env_state, action, ts.episode_return,
                                ts.episode_length, config.max_episode_steps, reset,
                                keys["reset"], members_axis)  # fmt: skip
        ts = ts.replace(env_state=s.env_state, episode_return=s.episode_return,
                        episode_length=s.episode_length)  # fmt: skip
        return ts, s.transitions, {"episode_return_sum": s.finished_return,
                                   "episodes": jnp.sum(s.ended.astype(jnp.float32))}  # fmt: skip

    def store(ts, transitions):
        return ts.replace(last=transitions)

    def update(ts, keys, steps):
        learner, batch = ts.agent, ts.last

        def loss(params):
            mean = control(params, batch.obs)
            logp = -jnp.sum(jnp.square(batch.action - mean), -1) / (2 * SIGMA**2)
            k = (keys["update"], keys["update"])
            hyper = {"alpha": learner.hyper["alpha"], "terms": learner.hyper["ma_terms"]}
            if lazy:
                penalty, metrics = regularizer.actor_penalty(
                    params, batch.obs, batch.next_obs, k, learner.prev_params, learner.updates,
                    **hyper,
                )  # fmt: skip
                rewards = batch.reward
            else:  # the one hook: every piece of MA for this batch, placed as configured
                placed = regularizer.apply(
                    params,
                    batch.obs,
                    batch.next_obs,
                    batch.reward,
                    k,
                    learner.prev_params,
                    learner.updates,
                    **hyper,
                )
                penalty, rewards, metrics = placed.actor_penalty, placed.rewards, placed.metrics
            advantage = rewards - jnp.mean(rewards)
            return -jnp.mean(logp * advantage) + penalty, metrics

        (value, metrics), grads = jax.value_and_grad(loss, has_aux=True)(learner.params)
        params = jax.tree.map(lambda p, g: p - learner.hyper["lr"] * g, learner.params, grads)
        learner = learner.replace(params=params, prev_params=learner.params,
                                  updates=learner.updates + 1)  # fmt: skip
        return ts.replace(agent=learner), {"loss": value, **metrics}

    def summarize(ts, per_iteration):
        episodes = jnp.sum(per_iteration["episodes"])
        return {
            "loss": jnp.mean(per_iteration["loss"]),
            "ma_penalty": jnp.mean(per_iteration.get("ma_penalty", 0.0)),
            "ma_reward_penalty": jnp.mean(per_iteration.get("ma_reward_penalty", 0.0)),
            "train_episode_return": jnp.sum(per_iteration["episode_return_sum"])
            / jnp.maximum(episodes, 1),
            "updates": jnp.asarray(per_iteration["loss"].shape[0], jnp.float32),
        }

    return Agent(keys=("act", "reset", "update"), init=init, collect=collect, store=store,
                 update=update, summarize=summarize, policy=policy_family(config, env))  # fmt: skip


SPEC = registry.register(
    registry.AgentSpec(
        name="toy_reinforce",
        make=make,
        policy=policy_family,
        # The step size is the agent's own setting, swept like alpha.
        hyper={"alpha": "ma.alpha", "ma_terms": "ma.mode", "lr": "toy.lr"},
        groups=(registry.SettingsGroup("toy", ToySettings),),
        defaults=lambda config: {"task_set": "nominal", "updates_per_step": 1},
    )
)

registry.register(
    dataclasses.replace(SPEC, name="toy_lazy", make=lambda c, e, t: make(c, e, t, lazy=True))
)

BASE = with_overrides(PRESETS["smoke"], algo="toy_reinforce", total_steps=200, eval_every=100,
                      warmup_steps=0, max_episode_steps=50, toy_lr=1e-3)  # fmt: skip


@pytest.mark.slow
def test_a_users_agent_trains_in_a_population_with_ma_and_resumes_exactly(tmp_path):
    assert "toy_reinforce" in registry.names()
    members = population.expand(BASE, [0], ["ma.alpha=0,5"])
    assert population.groups(members) == [[0, 1]]  # one program: alpha is a hyper value
    whole = population.train_population(members, str(tmp_path / "whole"), ["ma.alpha"])
    # MA is on for the alpha 5 member only, and it lowers the policy's feedback norm.
    assert whole[0]["ma_penalty"] == 0.0 < whole[1]["ma_penalty"]
    assert whole[1]["feedback_norm"] < whole[0]["feedback_norm"]
    assert all(np.isfinite(r["return"]) for r in whole)
    # Stopped after the first chunk, then resumed: the same records as the run in one go.
    half = [resolve(with_overrides(m, total_steps=100)) for m in members]
    population.train_population(half, str(tmp_path / "split"), ["ma.alpha"])
    population.train_population(members, str(tmp_path / "split"), ["ma.alpha"], resume=True)
    for name in ("toy_reinforce_alpha0_seed0", "toy_reinforce_alpha5_seed0"):
        a = runner.without_timings(runner.read_metrics(str(tmp_path / "whole" / name)))
        b = runner.without_timings(runner.read_metrics(str(tmp_path / "split" / name)))
        assert len(a) == 2 and a == b
    # A member reads back like any run: its policy evaluates through the registry.
    result = runner.evaluate_run(str(tmp_path / "whole" / "toy_reinforce_alpha5_seed0"),
                                 None, 2)  # fmt: skip
    assert result["step"] == 200 and np.isfinite(result["return"])
    assert result["feedback_norm"] == pytest.approx(whole[1]["feedback_norm"], rel=0.5)
    assert os.path.exists(tmp_path / "whole" / "population.json")


@pytest.mark.slow
def test_ma_is_applied_in_every_placement_the_agent_declares_and_refused_elsewhere(tmp_path):
    """The toy agent calls the regularizer's one hook (``apply``): under the actor and reward
    placements its training carries a nonzero penalty where MA is on; the entropy placement,
    which it does not declare, is refused by ``resolve``; an agent that calls only the actor
    hook is refused under the reward placement before it trains a step."""
    base = with_overrides(BASE, env="point_robot_dense", total_steps=100, eval_every=100,
                          ma_alpha=5.0)  # fmt: skip
    for placement, metric in (("actor_loss", "ma_penalty"), ("reward", "ma_reward_penalty")):
        config = resolve(with_overrides(base, ma_placement=placement))
        record = runner.train(config, str(tmp_path / placement), log=lambda m: None)
        assert record[metric] > 0, placement
        off = runner.train(resolve(with_overrides(config, ma_alpha=0.0)),
                           str(tmp_path / f"{placement}_off"), log=lambda m: None)  # fmt: skip
        assert off[metric] == 0, placement
    with pytest.raises(ValueError, match="toy_reinforce applies minimum attention in placement"):
        resolve(with_overrides(base, ma_placement="entropy"))
    lazy = resolve(with_overrides(base, algo="toy_lazy", ma_placement="reward"))
    with pytest.raises(runner.RunError, match="never calls the regularizer's shape_rewards"):
        runner.train(lazy, str(tmp_path / "lazy"), log=lambda m: None)
    assert not os.path.exists(tmp_path / "lazy" / "metrics.jsonl")

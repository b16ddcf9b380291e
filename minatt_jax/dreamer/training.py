"""DreamerV3's training program: collection, sequence replay and updates in one scanned chunk.

``make_dreamer_train(config)`` returns a ``training.Trainer`` (the runner, checkpoints and the CLI
treat it as any algorithm's). One iteration, for all ``num_envs`` environments at once:

1. **store** the current step (obs_t, the action before it, the reward on arriving at it,
   is_first, 1 - terminal) in each environment's ring of the sequence replay;
2. **act**: the posterior step of the RSSM on obs_t, then an action (uniform random during the
   warm-up, the actor's sample after it);
3. **step** the environments, except those whose episode ended at obs_t: they reset instead and
   their next stored step is the reset observation with is_first (DreamerV3's convention: the
   last observation of an episode is stored with its reward, the reset counts as a step);
4. **update**: after the warm-up, ``updates_per_iteration`` updates on (B, T) sequences, or one
   update every ``iterations_per_update`` iterations when the train ratio asks for fewer than one
   per iteration (train ratio = replayed steps per env step = updates x B x T / env steps).

Warm-up and the update schedule are ``lax.cond``s on the unbatched step counter; resets run under
a ``lax.cond`` only when some episode ended. Evaluation runs deterministic episodes of the agent's
recurrent policy (``DreamerAgent.policy``: posterior mode, tanh(mean)) through the evaluator of
every algorithm, the feedback norm with respect to the observation
(``DreamerAgent.observation_control``).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import State as EnvState
from flax import struct

import minatt_jax.envs as envs
from minatt_jax import acting
from minatt_jax.config import TrainConfig
from minatt_jax.dreamer.agent import AgentState, Batch, DreamerAgent, Latent, make_agent
from minatt_jax.evaluation import EvalResult, make_evaluator
from minatt_jax.replay import select_rows


@struct.dataclass
class SequenceReplay:
    """One ring of steps per environment (envs, capacity, ...); all rings advance together."""

    obs: jax.Array
    prev_action: jax.Array
    reward: jax.Array
    is_first: jax.Array
    cont: jax.Array
    position: jax.Array  # next slot to write (shared by the rings)
    size: jax.Array  # filled slots per ring

    @classmethod
    def create(cls, num_envs: int, capacity: int, obs_size: int, action_size: int):
        z = lambda *shape: jnp.zeros((num_envs, capacity, *shape), jnp.float32)  # noqa: E731
        zero = jnp.zeros((), jnp.int32)
        return cls(z(obs_size), z(action_size), z(), z(), z(), zero, zero)

    def add(self, step: Batch) -> SequenceReplay:
        """Writes one step of every environment (arrays (envs, ...))."""
        i = self.position
        put = lambda buf, x: buf.at[:, i].set(x)  # noqa: E731
        capacity = self.obs.shape[1]
        return self.replace(
            obs=put(self.obs, step.obs), prev_action=put(self.prev_action, step.prev_action),
            reward=put(self.reward, step.reward), is_first=put(self.is_first, step.is_first),
            cont=put(self.cont, step.cont), position=(i + 1) % capacity,
            size=jnp.minimum(self.size + 1, capacity),
        )  # fmt: skip

    def sample(self, key: jax.Array, batch_size: int, length: int) -> Batch:
        """``batch_size`` sequences of ``length`` consecutive steps, uniform over environments
        and start positions (in write order; a full ring's oldest step follows ``position``)."""
        k_env, k_start = jax.random.split(key)
        num_envs, capacity = self.obs.shape[:2]
        env = jax.random.randint(k_env, (batch_size,), 0, num_envs)
        start = jax.random.randint(k_start, (batch_size,), 0, self.size - length + 1)
        oldest = jnp.where(self.size < capacity, 0, self.position)
        index = (oldest + start[:, None] + jnp.arange(length)) % capacity
        take = lambda buf: buf[env[:, None], index]  # noqa: E731
        return Batch(take(self.obs), take(self.prev_action), take(self.reward),
                     take(self.is_first), take(self.cont))  # fmt: skip


def episode_sequences(traj: acting.Trajectory) -> tuple[Batch, jax.Array]:
    """Episodes (episodes, T, ...) from ``acting.unroll`` as replay steps in the replay's
    convention (obs_t, the action before it, the reward on arriving at it, is_first, 1 -
    terminal on arriving), with each episode's alive length."""
    zeros = jnp.zeros_like(traj.reward[:, :1])
    shift = lambda x, first: jnp.concatenate([first, x[:, :-1]], 1)  # noqa: E731
    batch = Batch(
        obs=traj.obs, prev_action=shift(traj.action, jnp.zeros_like(traj.action[:, :1])),
        reward=shift(traj.reward, zeros), is_first=jnp.zeros_like(traj.reward).at[:, 0].set(1.0),
        cont=shift(1.0 - traj.done, zeros + 1),
    )  # fmt: skip
    return batch, jnp.sum(traj.alive, -1).astype(jnp.int32)


def sample_episode_sequences(
    episodes: Batch, lengths: jax.Array, key: jax.Array, batch_size: int, length: int
) -> Batch:
    """``batch_size`` windows of ``length`` steps from the episodes' alive prefixes, uniform
    over episodes and start positions (an episode shorter than ``length`` gives its first
    ``length`` steps, those after its end included)."""
    k_episode, k_start = jax.random.split(key)
    which = jax.random.randint(k_episode, (batch_size,), 0, lengths.shape[0])
    last_start = jnp.maximum(lengths[which] - length, 0)
    start = jax.random.randint(k_start, (batch_size,), 0, last_start + 1)
    index = start[:, None] + jnp.arange(length)
    return jax.tree.map(lambda x: x[which[:, None], index], episodes)


@struct.dataclass
class DreamerCollector:
    """The environments, what is stored for their current step, and the policy's latents."""

    env_state: EnvState
    step: Batch  # (envs, ...) the current step's entry: obs, prev_action, reward, is_first, cont
    ended: jax.Array  # (envs,) the current step ends its episode: the next step resets
    latent: Latent  # (envs, ...)
    episode_return: jax.Array
    episode_length: jax.Array


@struct.dataclass
class DreamerTrainState:
    """Everything a DreamerV3 run needs to continue exactly (saved whole in checkpoints)."""

    agent: AgentState
    collector: DreamerCollector
    replay: SequenceReplay
    rng: jax.Array
    env_steps: jax.Array

    def parameter_groups(self) -> dict[str, Any]:
        """The parameters checked for non-finite values after every chunk."""
        params = self.agent.params
        names = {"world model": "world_model", "actor": "actor", "critic": "critic"}
        return {f"{label} parameters": params[key] for label, key in names.items()}

    def policy_items(self) -> tuple[Any, Any]:
        """What a policy snapshot holds: the world model and the actor (it acts on latents),
        and no observation normalizer (DreamerV3 reads symlog observations)."""
        params = self.agent.params
        return {"world_model": params["world_model"], "actor": params["actor"]}, {}

    def with_data(self, values: dict[str, jax.Array]) -> DreamerTrainState:
        """The state with its data fields set (the MA weight and mode; the SAC learning rates do
        not apply to DreamerV3)."""
        agent = self.agent.replace(alpha=jnp.asarray(values["ma.alpha"]),
                                   ma_terms=jnp.asarray(values["ma.terms"]))  # fmt: skip
        return self.replace(agent=agent)


def update_schedule(config: TrainConfig) -> tuple[int, int]:
    """(updates per iteration, iterations per update): the train ratio rounded to whole
    updates per iteration, or to one update every k iterations when it asks for less."""
    d = config.dreamer
    per_iteration = d.train_ratio * config.num_envs / (d.batch_size * d.batch_length)
    if per_iteration >= 1:
        return int(round(per_iteration)), 1
    return 1, int(round(1.0 / per_iteration))


def make_dreamer_train(config: TrainConfig) -> Any:
    """The DreamerV3 ``Trainer`` of a resolved configuration (see the module docstring)."""
    from minatt_jax.training import Trainer, scan_iterations, training_tasks

    env = envs.make(config.env, config.physics)
    d = config.dreamer
    obs_size, act_size, n = env.observation_size, env.action_size, config.num_envs
    agent: DreamerAgent = make_agent(obs_size, act_size, d, config.ma)
    task_set = training_tasks(config, env)
    capacity = max(config.buffer_size // n, d.batch_length)
    updates_per_iteration, iterations_per_update = update_schedule(config)
    iterations = config.eval_every // n
    bt = d.batch_size * d.batch_length
    # Updates need a full sequence in the rings; the warm-up (random actions) usually covers it.
    ready_at = max(config.warmup_steps, d.batch_length * n)

    def reset_envs(key: jax.Array) -> EnvState:
        return acting.reset_with_tasks(env, task_set, n, key)

    def first_step(env_state: EnvState) -> Batch:
        zeros = jnp.zeros((n,), jnp.float32)
        return Batch(env_state.obs, jnp.zeros((n, act_size)), zeros, jnp.ones((n,)), zeros + 1)

    def init(key: jax.Array) -> DreamerTrainState:
        k_agent, k_env, rng = jax.random.split(key, 3)
        env_state = reset_envs(k_env)
        zeros = jnp.zeros((n,), jnp.float32)
        collector = DreamerCollector(env_state, first_step(env_state), zeros > 1,
                                     agent.initial_latent((n,)), zeros, zeros)  # fmt: skip
        return DreamerTrainState(
            agent=agent.init(k_agent, config.ma.alpha), collector=collector,
            replay=SequenceReplay.create(n, capacity, obs_size, act_size), rng=rng,
            env_steps=jnp.zeros((), jnp.int32),
        )  # fmt: skip

    def collect(ts: DreamerTrainState, key: jax.Array, steps: jax.Array,
                members_axis: str | None = None):  # fmt: skip
        """One env step of every environment; in a population (``members_axis``) the resets'
        predicate is taken over all members, so the reset stays a branch (``acting``)."""
        k_obs, k_act, k_random, k_reset = jax.random.split(key, 4)
        col = ts.collector
        replay = ts.replay.add(col.step)
        params = ts.agent.params
        latent = agent.observe(params["world_model"], col.latent, col.step.obs,
                               col.step.prev_action, col.step.is_first, k_obs)  # fmt: skip
        policy_action = agent.act(params["actor"], latent, k_act)
        random_action = jax.random.uniform(k_random, (n, act_size), minval=-1.0, maxval=1.0)
        action = jnp.where(steps < config.warmup_steps, random_action, policy_action)
        stepped = jax.vmap(env.step)(col.env_state, action)
        length = col.episode_length + 1
        finite = jnp.isfinite(stepped.reward) & jnp.all(jnp.isfinite(stepped.obs), -1)
        ended_next = (stepped.done > 0) | (length >= config.max_episode_steps) | ~finite
        env_state = acting.reset_ended(col.ended, reset_envs, stepped, k_reset, members_axis)
        reward = jnp.where(finite, stepped.reward, 0.0)
        nxt = Batch(
            obs=jnp.where(finite[:, None], stepped.obs, col.step.obs), prev_action=action,
            reward=reward, is_first=jnp.zeros((n,)), cont=1.0 - stepped.done,
        )  # fmt: skip
        step = select_rows(col.ended, first_step(env_state), nxt)
        finished = ended_next & ~col.ended  # episodes that ended at this step
        finished_return = jnp.where(finished, col.episode_return + reward, 0.0)
        collector = DreamerCollector(
            env_state=env_state, step=step, ended=jnp.where(col.ended, False, ended_next),
            latent=latent,
            episode_return=jnp.where(col.ended | ended_next, 0.0, col.episode_return + reward),
            episode_length=jnp.where(col.ended, 0, length),
        )  # fmt: skip
        metrics = {"train_episode_return": jnp.sum(finished_return), "episodes": jnp.sum(finished),
                   "env_non_finite_resets": jnp.sum(~finite & ~col.ended)}  # fmt: skip
        return ts.replace(collector=collector, replay=replay), metrics

    def updates(
        agent_state: AgentState, replay: SequenceReplay, key: jax.Array
    ) -> tuple[AgentState, dict]:
        """The iteration's updates; only the agent state comes back (the replay is read)."""

        def one(state, k):
            k_sample, k_update = jax.random.split(k)
            batch = replay.sample(k_sample, d.batch_size, d.batch_length)
            return agent.update(state, batch, k_update)

        agent_state, metrics = jax.lax.scan(
            one, agent_state, jax.random.split(key, updates_per_iteration)
        )
        return agent_state, jax.tree.map(jnp.sum, metrics)

    def no_updates(
        agent_state: AgentState, replay: SequenceReplay, key: jax.Array
    ) -> tuple[AgentState, dict]:
        shapes = jax.eval_shape(updates, agent_state, replay, key)[1]
        return agent_state, jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    def iteration(ts: DreamerTrainState, steps: jax.Array,
                  members_axis: str | None = None) -> tuple[DreamerTrainState, dict]:  # fmt: skip
        rng, k_collect, k_update = jax.random.split(ts.rng, 3)
        ts, collect_metrics = collect(ts.replace(rng=rng), k_collect, steps, members_axis)
        due = (steps + n >= ready_at) & ((steps // n) % iterations_per_update == 0)
        agent_state, update_metrics = jax.lax.cond(
            due, updates, no_updates, ts.agent, ts.replay, k_update
        )
        ts = ts.replace(agent=agent_state, env_steps=ts.env_steps + n)
        count = jnp.where(due, updates_per_iteration, 0)
        return ts, {**collect_metrics, **update_metrics, "updates": count}

    def chunk_summary(per_iteration: dict) -> dict:
        totals = jax.tree.map(lambda x: jnp.sum(x, 0), per_iteration)
        done = jnp.maximum(totals.pop("updates"), 1)
        episodes = totals.pop("episodes")
        summary = {k: v / done for k, v in totals.items()
                   if k not in ("train_episode_return", "env_non_finite_resets")}  # fmt: skip
        summary["train_episode_return"] = totals["train_episode_return"] / jnp.maximum(episodes, 1)
        summary["env_non_finite_resets"] = totals["env_non_finite_resets"]
        summary["updates"] = jnp.sum(per_iteration["updates"])
        summary["train_ratio"] = summary["updates"] * bt / (iterations * n)
        return summary

    def run_chunk(
        ts: DreamerTrainState, start: jax.Array, members: bool = False
    ) -> tuple[DreamerTrainState, dict]:
        """``iterations`` iterations from env step ``start`` (``training.scan_iterations``)."""
        ts, per_iteration = scan_iterations(iteration, ts, start, n, iterations, members)
        return ts, (jax.vmap(chunk_summary) if members else chunk_summary)(per_iteration)

    def train_chunk(ts: DreamerTrainState) -> tuple[DreamerTrainState, dict]:
        return run_chunk(ts, ts.env_steps)

    evaluator = make_evaluator(env, lambda params, _: agent.policy(params, False),
                               config.max_episode_steps, config.eval_episodes)  # fmt: skip

    def evaluate(ts: DreamerTrainState, key: jax.Array, tasks: envs.Task) -> EvalResult:
        return evaluator(ts.policy_items()[0], {}, key, tasks)

    return Trainer(
        config=config, env=env, sac=None, task_set=task_set, init=jax.jit(init),
        train_chunk=jax.jit(train_chunk, donate_argnums=0), evaluate=evaluate,
        steps_per_chunk=iterations * n, ensemble=None, meta_step=None,
        parts={"init_state": init, "run_chunk": run_chunk,
               "agent": agent},
    )  # fmt: skip

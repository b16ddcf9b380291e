"""``--algo dreamer``: DreamerV3 with minimum attention on the actor (``minatt_jax.dreamer``).

One iteration, for all ``num_envs`` environments at once:

1. **collect**: the posterior step of the RSSM on obs_t, then an action (uniform random during the
   warm-up, the actor's sample after it); step the environments, except those whose episode ended
   at obs_t: they reset instead and their next stored step is the reset observation with
   is_first (DreamerV3's convention: the last observation of an episode is stored with its
   reward, the reset counts as a step);
2. **store** the step obs_t (the action before it, the reward on arriving at it, is_first,
   1 - terminal) in each environment's ring of the sequence replay;
3. **update**: after the warm-up, ``updates_per_iteration`` updates on (B, T) sequences, or one
   update every ``iterations_per_update`` iterations when the train ratio asks for fewer than one
   per iteration (train ratio = replayed steps per env step = updates x B x T / env steps).

Warm-up and the update schedule are ``lax.cond``s on the unbatched step counter; resets run under
a ``lax.cond`` only when some episode ended. Evaluation runs deterministic episodes of the
recurrent policy (``DreamerAgent.policy``: posterior mode, tanh(mean)), the feedback norm with
respect to the observation (``DreamerAgent.observation_control``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from brax.envs.base import State as EnvState
from flax import struct

from minatt_jax import acting
from minatt_jax.agents import registry
from minatt_jax.agents.base import (
    Adapter,
    Agent,
    PolicyFamily,
    abstract_hyper,
    zeros_like_shapes,
)
from minatt_jax.dreamer.agent import HYPER, AgentState, Batch, DreamerAgent, Latent, make_agent
from minatt_jax.dreamer.config import DreamerConfig
from minatt_jax.dreamer.replay import (
    SequenceReplay,
    episode_sequences,
    sample_episode_sequences,
)
from minatt_jax.replay import select_rows


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


class SequenceSource(NamedTuple):
    """What the updates replay: sequences of ``length`` steps drawn by ``sample(replay, key)``,
    and ``valid(env_steps)``, the (length,) mask of the steps whose world-model losses count
    (None: all). DreamerV3's (``windows``): uniform windows of ``dreamer.batch_length``."""

    length: int
    sample: Callable[[SequenceReplay, jax.Array], Batch]
    valid: Callable[[jax.Array], jax.Array | None]


def windows(config: Any) -> SequenceSource:
    """DreamerV3's replay: ``batch_size`` windows of ``batch_length`` steps, uniform over
    environments and start positions, every step's losses counted."""
    d = config.dreamer
    return SequenceSource(
        length=d.batch_length,
        sample=lambda replay, key: replay.sample(key, d.batch_size, d.batch_length),
        valid=lambda env_steps: None,
    )


def update_schedule(config: Any, length: int | None = None) -> tuple[int, int]:
    """(updates per iteration, iterations per update): the train ratio rounded to whole
    updates per iteration, or to one update every k iterations when it asks for less; replayed
    sequences are ``length`` steps long (default ``dreamer.batch_length``)."""
    d = config.dreamer
    length = d.batch_length if length is None else length
    per_iteration = d.train_ratio * config.num_envs / (d.batch_size * length)
    if per_iteration >= 1:
        return int(round(per_iteration)), 1
    return 1, int(round(1.0 / per_iteration))


def learner(config: Any, env: Any, head_states: int = 0, imag_starts: int = 0) -> DreamerAgent:
    """The DreamerV3 learner of a (resolved) configuration for ``env`` (``head_states`` and
    ``imag_starts``: ``dreamer.agent.make_agent``'s subsampling, MAMBA's)."""
    return make_agent(env.observation_size, env.action_size, config.dreamer, config.ma,
                      head_states, imag_starts)  # fmt: skip


def policy_family(config: Any, env: Any) -> PolicyFamily:
    """The recurrent world-model policy: the world model and the actor (no normalizer)."""
    agent = learner(config, env)
    params = zeros_like_shapes(jax.eval_shape(agent.init, jax.random.PRNGKey(0),
                                   abstract_hyper(HYPER)).params)  # fmt: skip
    names = ("world_model", "actor")
    return PolicyFamily(
        agent=agent,
        like=({name: params[name] for name in names}, {}),
        checkpoint_items={f"agent/params/{name}": params[name] for name in names},
        from_items=lambda parts: ({n: parts[f"agent/params/{n}"] for n in names}, {}),
        deterministic=lambda p, norm: agent.policy(p, False),
        stochastic=lambda p, norm: agent.policy(p, True),
        recurrent=True,
    )


def make(
    config: Any,
    env: Any,
    task_set: Any,
    source: SequenceSource | None = None,
    subsample: tuple[int, int] = (0, 0),
) -> Agent:
    """The dreamer agent of a resolved configuration (see the module docstring); ``source``
    (default ``windows(config)``) is what its updates replay and ``subsample`` the learner's
    (head states, imagination starts), for agents built on it."""
    d = config.dreamer
    source = windows(config) if source is None else source
    obs_size, act_size, n = env.observation_size, env.action_size, config.num_envs
    agent = learner(config, env, *subsample)
    capacity = max(config.buffer_size // n, source.length)
    updates_per_iteration, iterations_per_update = update_schedule(config, source.length)
    iterations = config.eval_every // n
    bt = d.batch_size * source.length
    # Updates need a full sequence in the rings; the warm-up (random actions) usually covers it.
    ready_at = max(config.warmup_steps, source.length * n)

    def reset_envs(key: jax.Array) -> EnvState:
        return acting.reset_with_tasks(env, task_set, n, key)

    def first_step(env_state: EnvState) -> Batch:
        zeros = jnp.zeros((n,), jnp.float32)
        return Batch(env_state.obs, jnp.zeros((n, act_size)), zeros, jnp.ones((n,)), zeros + 1)

    def init(key: jax.Array, hyper: dict) -> DreamerTrainState:
        k_agent, k_env, rng = jax.random.split(key, 3)
        env_state = reset_envs(k_env)
        zeros = jnp.zeros((n,), jnp.float32)
        collector = DreamerCollector(env_state, first_step(env_state), zeros > 1,
                                     agent.initial_latent((n,)), zeros, zeros)  # fmt: skip
        return DreamerTrainState(
            agent=agent.init(k_agent, hyper), collector=collector,
            replay=SequenceReplay.create(n, capacity, obs_size, act_size), rng=rng,
            env_steps=jnp.zeros((), jnp.int32),
        )  # fmt: skip

    def collect(ts: DreamerTrainState, keys: dict, steps: jax.Array,
                members_axis: str | None = None):  # fmt: skip
        """One env step of every environment; the step to store is the current one (obs_t)."""
        k_obs, k_act, k_random, k_reset = jax.random.split(keys["collect"], 4)
        col = ts.collector
        params = ts.agent.params
        latent = agent.observe(params["world_model"], col.latent, col.step.obs,
                               col.step.prev_action, col.step.is_first, k_obs)  # fmt: skip
        policy_action = agent.act(params["actor"], latent, k_act)
        random_action = jax.random.uniform(k_random, (n, act_size), minval=-1.0, maxval=1.0)
        action = jnp.where(steps < config.warmup_steps, random_action, policy_action)
        stepped, length, finite, ended_next = acting.step_envs(
            env, col.env_state, action, col.episode_length, config.episode_limit
        )
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
        return ts.replace(collector=collector), col.step, metrics

    def store(ts: DreamerTrainState, step: Batch) -> DreamerTrainState:
        return ts.replace(replay=ts.replay.add(step))

    def updates(
        agent_state: AgentState, replay: SequenceReplay, key: jax.Array, steps: jax.Array
    ) -> tuple[AgentState, dict]:
        """The iteration's updates; only the agent state comes back (the replay is read)."""
        mask = source.valid(steps)
        valid = None if mask is None else jnp.broadcast_to(mask, (d.batch_size, source.length))

        def one(state, k):
            k_sample, k_update = jax.random.split(k)
            return agent.update(state, source.sample(replay, k_sample), k_update, valid)

        agent_state, metrics = jax.lax.scan(
            one, agent_state, jax.random.split(key, updates_per_iteration)
        )
        return agent_state, jax.tree.map(jnp.sum, metrics)

    def no_updates(
        agent_state: AgentState, replay: SequenceReplay, key: jax.Array, steps: jax.Array
    ) -> tuple[AgentState, dict]:
        shapes = jax.eval_shape(updates, agent_state, replay, key, steps)[1]
        return agent_state, jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    def update(ts: DreamerTrainState, keys: dict, steps_after: jax.Array):
        steps = steps_after - n
        due = (steps + n >= ready_at) & ((steps // n) % iterations_per_update == 0)
        agent_state, update_metrics = jax.lax.cond(
            due, updates, no_updates, ts.agent, ts.replay, keys["update"], steps_after
        )
        count = jnp.where(due, updates_per_iteration, 0)
        return ts.replace(agent=agent_state), {**update_metrics, "updates": count}

    def summarize(ts: DreamerTrainState, per_iteration: dict) -> dict:
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

    return Agent(keys=("collect", "update"), init=init, collect=collect, store=store,
                 update=update, summarize=summarize, policy=policy_family(config, env),
                 parts={"agent": agent, "source": source})  # fmt: skip


def adapter(config: Any, env: Any, family: PolicyFamily, settings: Any) -> Adapter:
    """DreamerV3's meta-test step: ``updates_per_step`` updates (world model, actor, critic, MA
    included) on windows of the run's sequence length sampled from the collected episodes."""
    agent_fns, d = family.agent, config.dreamer
    shapes = jax.eval_shape(agent_fns.init, jax.random.PRNGKey(0), abstract_hyper(HYPER))

    def prepare(parts: dict, normalizer: Any, traj: acting.Trajectory, key: jax.Array,
                refit: bool) -> Any:  # fmt: skip
        return episode_sequences(traj)

    @jax.jit
    def step(agent: Any, context: Any, key: jax.Array) -> Any:
        episodes, lengths = context

        def one(agent, k):
            k_batch, k_update = jax.random.split(k)
            batch = sample_episode_sequences(episodes, lengths, k_batch, d.batch_size,
                                             d.batch_length)  # fmt: skip
            return agent_fns.update(agent, batch, k_update)[0], None

        return jax.lax.scan(one, agent, jax.random.split(key, settings.updates_per_step))[0]

    def policy_params(agent: Any) -> dict:
        return {"world_model": agent.params["world_model"], "actor": agent.params["actor"]}

    return Adapter(like={"agent": zeros_like_shapes(shapes)}, prepare=prepare, step=step,
                   policy_params=policy_params)  # fmt: skip


# DreamerV3 at toy size in the smoke preset (the program's structure, in seconds); in the cpu
# preset at a size a CPU trains in an hour (benchmarks/dreamer_update.py: the official size1m
# with 16 x 64 batches runs 1.4 updates/s on a 2-core x86-64 CPU, a day per 100K steps at train
# ratio 1024): half the recurrent state, sequences of 32, train ratio 256 (one update per 2 env
# steps). Everything else is the official proprioceptive setting.
DREAMER_SETTINGS = registry.SettingsGroup("dreamer", DreamerConfig, presets={
    "smoke": {"deter": 32, "hidden": 16, "stoch": 4, "classes": 4, "blocks": 2, "units": 32,
              "layers": 2, "bins": 41, "batch_size": 4, "batch_length": 16, "imag_length": 5,
              "train_ratio": 64.0, "warmup": 10},
    "cpu": {"deter": 256, "batch_length": 32, "train_ratio": 256.0},
})  # fmt: skip
# MA enters DreamerV3's actor loss; its critic's lambda-returns carry no entropy term, so the
# SAC-like "entropy" placement has no second half here, and the reward placement is not wired.
PLACEMENTS = ("actor_loss",)


# Fields the dreamer group held before MAMBA owned them (0 in every DreamerV3 run).
MAMBA_FIELDS = ("head_states", "imag_starts", "wm_horizon_start", "wm_horizon_full_at")


def read_stored(stored: dict[str, Any]) -> dict[str, Any]:
    """Runs written before the agent declared its placements recorded the default "entropy",
    which applied MA in DreamerV3's actor loss alone: they read as "actor_loss". The dreamer
    group's former MAMBA fields are dropped where they are 0 (MAMBA's reading moves them)."""
    if stored.get("ma", {}).get("placement") == "entropy":
        stored = {**stored, "ma": {**stored["ma"], "placement": "actor_loss"}}
    group = stored.get("dreamer", {})
    if stored.get("algo") == "dreamer" and any(group.get(k) == 0 for k in MAMBA_FIELDS):
        stored = {**stored, "dreamer": {k: v for k, v in group.items()
                                        if not (k in MAMBA_FIELDS and v == 0)}}  # fmt: skip
    return stored


SPEC = registry.register(
    registry.AgentSpec(
        name="dreamer",
        make=make,
        policy=policy_family,
        hyper=HYPER,
        groups=(DREAMER_SETTINGS,),
        defaults=lambda config: {"task_set": "nominal", "updates_per_step": 1},
        adapter=adapter,
        recurrent=True,
        placements=PLACEMENTS,
        read_stored=read_stored,
    )
)

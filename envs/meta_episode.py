"""Meta-episodes: k episodes of one task back to back, for agents that adapt in context.

A meta-RL agent with memory (MAMBA, a recurrent policy) identifies its task from what it lived
through: the meta-episode keeps the task fixed for ``episodes`` episodes of at most
``episode_steps`` steps each. When an inner episode ends (termination or its step limit) the
simulator restarts on the same task (from a start state drawn, like every inner episode's, when
the meta-episode began), but the meta-episode goes on: ``done`` is set only when the
last inner episode ends, so a collector that resets an agent's memory where ``done`` is set
carries that memory across the inner boundaries and resets it between meta-episodes.

The agent sees the boundary: each observation is the environment's followed by

* the reward of the step that led to it (0 on an episode's first step),
* the previous action (zeros on an episode's first step),
* a first-step flag (1 on the first step of every inner episode),
* the inner episode's index scaled to [0, 1] (index / (episodes - 1); 0 for one episode),

as MAMBA's observation carries the reward, the previous action and the episode boundary.
``metrics["meta_episode_index"]`` holds the index of the episode each step belongs to, so an
evaluation splits a meta-episode's return by episode (``returns_by_episode``): the in-context
adaptation curve.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import State

EXTRA = 3  # reward, first-step flag, episode index; the previous action adds action_size


class MetaEpisode:
    """``env`` run as meta-episodes of ``episodes`` inner episodes of ``episode_steps`` steps.

    Keeps the wrapped environment's interface (``reset(rng, task)``, ``step``, sizes, ``dt``,
    tasks); every other attribute is the wrapped environment's.
    """

    def __init__(self, env: Any, episodes: int, episode_steps: int) -> None:
        if episodes < 1 or episode_steps < 1:
            raise ValueError(f"a meta-episode needs episodes >= 1 and episode_steps >= 1, got "
                             f"{episodes} and {episode_steps}")  # fmt: skip
        self.env = env
        self.episodes = int(episodes)
        self.episode_steps = int(episode_steps)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    @property
    def observation_size(self) -> int:
        return self.env.observation_size + self.env.action_size + EXTRA

    @property
    def action_size(self) -> int:
        return self.env.action_size

    @property
    def obs_names(self) -> tuple[str, ...]:
        """Every input of the observation: the inner environment's, then the meta-episode's."""
        previous = tuple(f"previous_action_{i}" for i in range(self.env.action_size))
        return (*self.env.obs_names, *previous, "reward", "first_step", "episode_index")

    @property
    def max_steps(self) -> int:
        """The steps of a whole meta-episode (the collector's episode limit)."""
        return self.episodes * self.episode_steps

    def _observe(self, inner: State, reward: jax.Array, action: jax.Array, first: jax.Array,
                 index: jax.Array) -> jax.Array:  # fmt: skip
        scale = 1.0 / max(self.episodes - 1, 1)
        extra = jnp.stack([reward, first, index * scale]).astype(inner.obs.dtype)
        return jnp.concatenate([inner.obs, action.astype(inner.obs.dtype), extra])

    def _wrap(self, inner: State, reward: jax.Array, done: jax.Array, action: jax.Array,
              first: jax.Array, index: jax.Array, step: jax.Array, starts: State,
              belongs_to: jax.Array) -> State:  # fmt: skip
        # the simulator state is held once, in pipeline_state; "inner" keeps the rest
        info = {"inner": inner.replace(pipeline_state=None), "meta_index": index,
                "meta_step": step, "meta_starts": starts, "task": inner.info["task"]}  # fmt: skip
        metrics = {**inner.metrics, "meta_episode_index": belongs_to.astype(jnp.float32)}
        obs = self._observe(inner, reward, action, first, index)
        return State(inner.pipeline_state, obs, reward, done, metrics, info)

    def reset(self, rng: jax.Array, task: Any = None) -> State:
        """The first step of a meta-episode on ``task``. The start states of all its inner
        episodes are drawn here (one reset each, own keys): a restart inside the meta-episode
        then selects the next one, and never runs a reset under a per-environment condition
        (under ``vmap`` that would run a reset in every environment at every step)."""
        keys = jax.random.split(rng, self.episodes)
        starts = jax.vmap(lambda k: self.env.reset(k, task))(keys)
        inner = jax.tree.map(lambda x: x[0], starts)
        zero = jnp.zeros((), jnp.float32)
        index = jnp.zeros((), jnp.int32)
        return self._wrap(inner, zero, zero, jnp.zeros(self.action_size), jnp.ones(()), index,
                          index, starts, index)  # fmt: skip

    @staticmethod
    def _inner(state: State) -> State:
        """The wrapped environment's state inside the meta-episode ``state``."""
        return state.info["inner"].replace(pipeline_state=state.pipeline_state)

    def with_start(self, state: State, data: Any) -> State:
        """The meta-episode ``state`` (a reset's) with its first inner episode started from the
        simulator state ``data`` (the failure grid's initial states); the later episodes keep
        the start states drawn at the reset."""
        inner = self.env.with_start(self._inner(state), data)
        starts = jax.tree.map(lambda s, x: s.at[0].set(x), state.info["meta_starts"], inner)
        obs = jnp.concatenate([inner.obs, state.obs[inner.obs.shape[-1] :]])
        info = {**state.info, "inner": inner.replace(pipeline_state=None), "meta_starts": starts}
        return state.replace(pipeline_state=inner.pipeline_state, obs=obs, info=info)

    def step(self, state: State, action: jax.Array) -> State:
        """One step; an inner episode that ends restarts the simulator on the same task (from
        the start state drawn for the next episode when the meta-episode began)."""
        inner = self.env.step(self._inner(state), action)
        index, step = state.info["meta_index"], state.info["meta_step"] + 1
        inner_ended = (inner.done > 0) | (step >= self.episode_steps)
        last = index >= self.episodes - 1
        restart = inner_ended & ~last
        starts = state.info["meta_starts"]
        fresh = jax.tree.map(lambda x: x[jnp.minimum(index + 1, self.episodes - 1)], starts)
        # the step's reward and metrics stay the ended episode's; its state is the fresh one
        fresh = fresh.replace(reward=inner.reward, metrics=inner.metrics)
        inner_next = jax.tree.map(lambda f, s: jnp.where(restart, f, s), fresh, inner)
        done = (inner_ended & last).astype(jnp.float32)
        first = restart.astype(jnp.float32)
        new_index = index + restart.astype(jnp.int32)
        new_step = jnp.where(restart, 0, step)
        prev_action = jnp.where(restart, jnp.zeros_like(action), action)
        reward = jnp.where(restart, 0.0, inner.reward)  # a fresh episode's first step saw none
        wrapped = self._wrap(inner_next, reward, done, prev_action, first, new_index, new_step,
                             starts, index)  # fmt: skip
        # the reward of the step itself (what a learner sums) is the inner episode's
        return wrapped.replace(reward=inner.reward)


def returns_by_episode(rewards: jax.Array, episode_index: jax.Array, alive: jax.Array,
                       episodes: int) -> jax.Array:  # fmt: skip
    """Each inner episode's return, (episodes,), from a meta-episode's per-step rewards, the
    ``meta_episode_index`` metric and the ``alive`` mask of ``acting.unroll``."""
    onehot = jax.nn.one_hot(episode_index.astype(jnp.int32), episodes)
    return jnp.sum((rewards * alive)[..., None] * onehot, axis=-2)

"""One way to act in an environment: policies, the training collect step, and ``unroll``.

* ``Policy``: what acts. ``prepare`` maps an observation to the policy's input (observation
  normalization), ``act`` maps (input, key) to an action, ``control`` is the deterministic control
  law u(x) whose Jacobian the feedback probe takes. Build one with ``deterministic``,
  ``stochastic``, ``zero_policy`` or ``random_policy``.
* ``RecurrentPolicy``: a policy with memory (DreamerV3's world-model state): ``at(memory)`` is
  the step's ``Policy`` (its control law u(x) at that memory, whose Jacobian the probe takes) and
  ``remember(memory, x, action, key)`` the memory after the step, with the same key the step's
  ``act`` got (so a sampled latent is the one that chose the action).
* ``unroll``: a fixed number of steps from a given state as one ``lax.scan``, returning a
  ``Trajectory`` (with the exact ||du/dx||_F^2 per step when asked). Evaluation, meta-test data
  collection, the report's rollouts, the failure grid and ``minatt-jax rollout`` all use it.
  Episodes that end early keep stepping (fixed shapes) and ``alive`` masks what follows.
* ``episode_metrics``: the paper's per-episode metrics of a trajectory.
* ``step_envs``: one step of the training environments and which episodes it ends (the episode
  rule every collector shares); ``reset_ended`` resets the ended ones on newly drawn tasks.
* ``collect_step``: one step of the training environments with the episode bookkeeping (returns,
  lengths, the step limit, resets with a newly drawn task).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from brax.envs.base import State as EnvState
from flax import struct

from minatt_jax import min_attention as ma
from minatt_jax import normalizer as obs_norm
from minatt_jax.envs import sample_task
from minatt_jax.replay import Transitions, select_rows


class Policy(NamedTuple):
    """A policy as three functions of one observation (see the module docstring)."""

    act: Callable[[jax.Array, jax.Array | None], jax.Array]  # (policy input, key) -> action
    control: Callable[[jax.Array], jax.Array] | None = None  # deterministic u(policy input)
    prepare: Callable[[jax.Array], jax.Array] = lambda obs: obs  # observation -> policy input


class RecurrentPolicy(NamedTuple):
    """A policy with memory (see the module docstring); ``memory`` is the state before an
    episode's first step."""

    memory: Any
    at: Callable[[Any], Policy]
    remember: Callable[[Any, jax.Array, jax.Array, jax.Array | None], Any]


AnyPolicy = Policy | RecurrentPolicy


def _prepare(normalizer: obs_norm.Normalizer | None, normalize: bool) -> Callable:
    if normalizer is None or not normalize:
        return lambda obs: obs
    return lambda obs: obs_norm.normalize(normalizer, obs, True)


def deterministic(
    control: Callable[[Any, jax.Array], jax.Array],
    params: Any,
    normalizer: obs_norm.Normalizer | None = None,
    normalize: bool = False,
) -> Policy:
    """The deterministic control u = control(params, x) (evaluation).

    Args:
        control: ``control(params, x) -> u`` on the policy's input x.
        params: its parameters.
        normalizer: the observation normalizer, or None.
        normalize: whether x is the normalized observation (static).

    Returns:
        A ``Policy`` for ``unroll``.
    """
    u = lambda x: control(params, x)  # noqa: E731
    return Policy(act=lambda x, key: u(x), control=u, prepare=_prepare(normalizer, normalize))


def stochastic(
    sample: Callable[[Any, jax.Array, jax.Array], jax.Array],
    control: Callable[[Any, jax.Array], jax.Array],
    params: Any,
    normalizer: obs_norm.Normalizer | None = None,
    normalize: bool = False,
) -> Policy:
    """Actions sampled from the policy distribution (data collection).

    Args:
        sample: ``sample(params, x, key) -> u``, a draw from the distribution.
        control: the deterministic control beside it (the feedback probe reads it).
        params: the parameters.
        normalizer: the observation normalizer, or None.
        normalize: whether x is the normalized observation (static).

    Returns:
        A ``Policy`` for ``unroll`` and the collectors (pass ``unroll`` a key).
    """
    return Policy(
        act=lambda x, key: sample(params, x, key),
        control=lambda x: control(params, x),
        prepare=_prepare(normalizer, normalize),
    )


def zero_policy(act_dim: int) -> Policy:
    """Always commands zero torque."""
    return Policy(act=lambda x, key: jnp.zeros((act_dim,), jnp.float32))


def random_policy(act_dim: int) -> Policy:
    """Uniform random actions in [-1, 1]."""
    return Policy(act=lambda x, key: jax.random.uniform(key, (act_dim,), minval=-1.0, maxval=1.0))


@struct.dataclass
class Trajectory:
    """What ``unroll`` returns, one row per step (a leading batch axis when vmapped)."""

    obs: jax.Array  # (T, obs_dim) observation before the step
    policy_obs: jax.Array  # (T, obs_dim) what the policy saw (normalized where that is on)
    action: jax.Array  # (T, act_dim)
    reward: jax.Array  # (T,)
    next_obs: jax.Array  # (T, obs_dim)
    done: jax.Array  # (T,) 1.0 where the step terminated the episode
    alive: jax.Array  # (T,) 1.0 up to and including the episode's first done
    env_metrics: dict[str, jax.Array]  # the environment's per-step metrics (reward terms, ...)
    feedback: jax.Array | None = None  # (T,) ||du/dx||_F^2 at each step, when probed
    gain: jax.Array | None = None  # (T, act_dim, obs_dim) du/dx at each step, when probed
    qpos: jax.Array | None = None  # (T, nq) the simulator's positions before each step (render)

    def transitions(self) -> Transitions:
        """The steps as replay transitions (``terminal`` = ``done``)."""
        return Transitions(obs=self.obs, action=self.action, reward=self.reward,
                           next_obs=self.next_obs, terminal=self.done)  # fmt: skip


def unroll(
    env: Any,
    policy: AnyPolicy,
    state: EnvState,
    steps: int,
    key: jax.Array | None = None,
    probe_feedback: bool = False,
    probe_gain: bool = False,
    record_qpos: bool = False,
) -> Trajectory:
    """Rolls a policy out for a fixed number of steps (one ``lax.scan``).

    Args:
        env: the environment (``reset``/``step``; a ``MetaEpisode`` too).
        policy: a ``Policy`` or ``RecurrentPolicy`` (``deterministic``, ``stochastic``, a
            family's ``deterministic(params, normalizer)``).
        state: the environment state to start from (``env.reset(key, task)``).
        steps: steps to take (static); steps after the episode's first ``done`` are taken but
            masked by ``alive``.
        key: split per step for ``act``; None for deterministic policies.
        probe_feedback: record ||du/dx||_F^2 at each step (exact, ``jacfwd``).
        probe_gain: record the Jacobian du/dx itself (for a recurrent policy, with respect to
            this step's input at the memory it acts with).
        record_qpos: record the simulator's positions before each step (to render).

    Returns:
        A ``Trajectory``, one row per step.
    """
    recurrent = isinstance(policy, RecurrentPolicy)
    first = policy.at(policy.memory) if recurrent else policy
    if (probe_feedback or probe_gain) and first.control is None:
        raise ValueError("probe_feedback needs a policy with a deterministic control")

    def body(carry, k):
        state, alive, memory = carry
        step_policy = policy.at(memory) if recurrent else policy
        x = step_policy.prepare(state.obs)
        action = step_policy.act(x, k)
        if recurrent:
            memory = policy.remember(memory, x, action, k)
        nxt = env.step(state, action)
        out = {
            "obs": state.obs,
            "policy_obs": x,
            "action": action,
            "reward": nxt.reward,
            "next_obs": nxt.obs,
            "done": nxt.done,
            "alive": alive,
            "env_metrics": nxt.metrics,
        }
        if record_qpos:
            out["qpos"] = state.pipeline_state.qpos
        if probe_gain:
            out["gain"] = gain_at(step_policy.control, x)
        if probe_feedback:
            out["feedback"] = (jnp.sum(jnp.square(out["gain"])) if probe_gain
                               else feedback_at(step_policy.control, x))  # fmt: skip
        return (nxt, alive * (1.0 - nxt.done), memory), out

    keys = None if key is None else jax.random.split(key, steps)
    memory = policy.memory if recurrent else None
    start = (state, jnp.ones((), jnp.float32), memory)
    _, out = jax.lax.scan(body, start, keys, length=steps)
    return Trajectory(**out)


def gain_at(u: Callable[[jax.Array], jax.Array], x: jax.Array) -> jax.Array:
    """The control's Jacobian at one policy input, exactly (``min_attention.control_jacobian``).

    Args:
        u: ``u(x) -> action``.
        x: one input, (x_dim,).

    Returns:
        du/dx, (act_dim, x_dim).
    """
    return ma.control_jacobian(lambda _, y: u(y), None, x[None])[0]


def feedback_at(u: Callable[[jax.Array], jax.Array], x: jax.Array) -> jax.Array:
    """The feedback norm at one policy input, exactly (``min_attention.feedback_exact``).

    Args:
        u: ``u(x) -> action``.
        x: one input, (x_dim,).

    Returns:
        ||du/dx||_F^2, a scalar.
    """
    return ma.feedback_exact(lambda _, y: u(y), None, x[None], "jacfwd")[0]


def episode_metrics(traj: Trajectory, dt: float) -> dict[str, jax.Array]:
    """The paper's metrics of one episode (steps until the first done):

    return; feedback_norm = mean ||du/dx||_F^2 (needs the probe); feedforward_norm = mean over
    t >= 1 of ||(u_t - u_{t-1}) / dt||^2; energy = mean ||u_t||^2; jerk = mean over t >= 2 of
    ||(u_t - 2 u_{t-1} + u_{t-2}) / dt^2||^2. In a meta-episode (``meta_episode_index`` among
    the environment's metrics) the differences run within each inner episode: the jump from one
    episode's last action to the next one's first is no change of the control law.

    Args:
        traj: one rollout (``unroll``; ``probe_feedback`` for the feedback norm).
        dt: the environment's control time step (``env.dt``).

    Returns:
        ``return``, ``length``, ``feedforward_norm``, ``energy``, ``jerk`` and, with the probe,
        ``feedback_norm``.
    """
    alive, u = traj.alive, traj.action
    length = jnp.sum(alive)
    du = jnp.sum(jnp.square((u[1:] - u[:-1]) / dt), -1)
    ddu = jnp.sum(jnp.square((u[2:] - 2 * u[1:-1] + u[:-2]) / dt**2), -1)
    pairs, triples = alive[1:], alive[2:]  # steps t >= 1 (t >= 2) of one episode
    episode = (traj.env_metrics or {}).get("meta_episode_index")
    if episode is not None:
        same = (episode[1:] == episode[:-1]).astype(alive.dtype)
        pairs, triples = pairs * same, triples * same[1:] * same[:-1]
    metrics = {
        "return": jnp.sum(alive * traj.reward),
        "length": length,
        "feedforward_norm": jnp.sum(pairs * du) / jnp.maximum(jnp.sum(pairs), 1),
        "energy": jnp.sum(alive * jnp.sum(jnp.square(u), -1)) / length,
        "jerk": jnp.sum(triples * ddu) / jnp.maximum(jnp.sum(triples), 1),
    }
    if traj.feedback is not None:
        metrics["feedback_norm"] = jnp.sum(alive * traj.feedback) / length
    return metrics


class CollectStep(NamedTuple):
    """One step of the training environments with the episode bookkeeping done."""

    transitions: Transitions  # what to store: (obs, action, reward, next_obs, terminal)
    env_state: EnvState  # next states, with ended episodes replaced by fresh resets
    episode_return: jax.Array  # running returns, zeroed where an episode ended
    episode_length: jax.Array
    ended: jax.Array  # (num_envs,) bool: terminated, reached the step limit, or non-finite
    finished_return: jax.Array  # sum of the returns of the finite episodes that ended this step
    finite: jax.Array  # (num_envs,) bool: the step's observation and reward are finite


def reset_with_tasks(env: Any, task_set: Any, num_envs: int, key: jax.Array) -> EnvState:
    """Fresh states of several environments, each on a task drawn from a task set.

    Args:
        env: the environment.
        task_set: the stacked tasks to draw from.
        num_envs: how many environments.
        key: the random key of the draws and resets.

    Returns:
        The states, with a leading axis of ``num_envs``.
    """
    k_task, k_reset = jax.random.split(key)
    tasks = jax.vmap(lambda k: sample_task(k, task_set))(jax.random.split(k_task, num_envs))
    return jax.vmap(env.reset)(jax.random.split(k_reset, num_envs), tasks)


def reset_ended(
    ended: jax.Array,
    reset: Callable[[jax.Array], EnvState],
    env_state: EnvState,
    key: jax.Array,
    members_axis: str | None = None,
) -> EnvState:
    """``env_state`` with the environments whose episode ``ended`` replaced by fresh ones.

    ``reset(key)`` runs under a ``lax.cond`` only when some episode ended. In a population
    (``members_axis``, the name of its vmapped axis) that predicate is taken over all members
    (``lax.pmax``), so it stays unbatched and the reset a real branch; a batched predicate would
    make it a select that resets every member at every step (cheetah_run's reset settles 200
    physics steps).
    """
    any_ended = jnp.any(ended)
    if members_axis is not None:
        any_ended = jax.lax.pmax(any_ended.astype(jnp.int32), members_axis) > 0
    fresh = jax.lax.cond(any_ended, reset, lambda k: env_state, key)
    return select_rows(ended, fresh, env_state)


class EnvStep(NamedTuple):
    """Every training environment stepped once, with its episode's end decided."""

    next_state: EnvState  # the stepped states (ended episodes not yet reset)
    length: jax.Array  # (num_envs,) episode lengths after the step
    finite: jax.Array  # (num_envs,) bool: the step's observation and reward are finite
    ended: jax.Array  # (num_envs,) bool: terminated, reached the step limit, or non-finite


def step_envs(
    env: Any, env_state: EnvState, action: jax.Array, episode_length: jax.Array,
    max_episode_steps: int,
) -> EnvStep:  # fmt: skip
    """Steps every environment and decides which episodes end: termination, the step limit, or
    a simulator state gone non-finite (whose step is not to be learned from). The one episode
    rule of every collector (``collect_step``; DreamerV3's, which stores the reset as a step)."""
    next_state = jax.vmap(env.step)(env_state, action)
    length = episode_length + 1
    finite = jnp.all(jnp.isfinite(next_state.obs), -1) & jnp.isfinite(next_state.reward)
    ended = (next_state.done > 0) | (length >= max_episode_steps) | ~finite
    return EnvStep(next_state, length, finite, ended)


def collect_step(
    env: Any,
    env_state: EnvState,
    action: jax.Array,
    episode_return: jax.Array,
    episode_length: jax.Array,
    max_episode_steps: int,
    reset: Callable[[jax.Array], EnvState],
    key: jax.Array,
    members_axis: str | None = None,
) -> CollectStep:
    """Steps every environment, ends episodes (termination or the step limit) and resets them.

    Args:
        env: the environment.
        env_state: the states of ``num_envs`` environments (a leading axis).
        action: their actions, (num_envs, act_dim).
        episode_return: each environment's return so far.
        episode_length: each environment's steps so far.
        max_episode_steps: the step limit that ends (and bootstraps) an episode.
        reset: ``reset(key)`` -> fresh states for all environments.
        key: the random key of the resets.
        members_axis: the name of a population's vmapped axis (``reset_ended``).

    Returns:
        A ``CollectStep``: the transitions to store, the next states (ended ones reset), the
        episode bookkeeping and which steps were finite.

    ``reset(key)`` returns fresh states for all environments (new tasks included); it runs
    only when some episode ended (``reset_ended``), so resets cost nothing otherwise. Only
    termination sets ``terminal`` (time limits are bootstrapped). A simulator state that went
    non-finite (NaN or inf observation or reward) ends its episode and is reset; ``finite``
    marks it so the caller does not learn from it, and its return is not counted.
    """
    next_state, length, finite, ended = step_envs(env, env_state, action, episode_length,
                                                  max_episode_steps)  # fmt: skip
    terminal = next_state.done
    transitions = Transitions(obs=env_state.obs, action=action, reward=next_state.reward,
                              next_obs=next_state.obs, terminal=terminal)  # fmt: skip
    ep_return = episode_return + next_state.reward
    new_state = reset_ended(ended, reset, next_state, key, members_axis)
    return CollectStep(
        transitions=transitions,
        env_state=new_state,
        episode_return=jnp.where(ended, 0.0, ep_return),
        episode_length=jnp.where(ended, 0, length),
        ended=ended,
        finished_return=jnp.sum(jnp.where(ended & finite, ep_return, 0.0)),
        finite=finite,
    )

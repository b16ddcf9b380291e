"""Meta-episodes (envs/meta_episode.py): inner episodes restart the simulator on the same task
while the meta-episode, and a recurrent agent's memory, go on; memory resets only between
meta-episodes; each inner episode's return is recovered from the steps."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import minatt_jax.envs as envs
from minatt_jax import acting
from minatt_jax.envs.meta_episode import EXTRA, MetaEpisode, returns_by_episode

EPISODES, STEPS = 3, 4


@pytest.fixture(scope="module")
def wrapped(make_env):
    return MetaEpisode(make_env("hopper"), EPISODES, STEPS)


def test_sizes_and_bad_settings(wrapped):
    inner = wrapped.env
    assert wrapped.observation_size == inner.observation_size + inner.action_size + EXTRA
    assert wrapped.action_size == inner.action_size and wrapped.dt == inner.dt
    assert wrapped.max_steps == EPISODES * STEPS
    # every input named (an export or an analysis reads them): the meta-episode's last
    assert len(wrapped.obs_names) == wrapped.observation_size
    assert wrapped.obs_names[-EXTRA - inner.action_size] == "previous_action_0"
    assert wrapped.obs_names[-EXTRA:] == ("reward", "first_step", "episode_index")
    # the simulator state is held once (pipeline_state), not again inside the inner state
    state = wrapped.reset(jax.random.PRNGKey(0))
    assert state.info["inner"].pipeline_state is None
    with pytest.raises(ValueError, match="episodes >= 1"):
        MetaEpisode(inner, 0, 10)


@pytest.fixture(scope="module")
def trajectory(wrapped):
    """A whole meta-episode (and the first step of the next) under a recurrent toy policy
    whose action depends on its memory: the number of steps it has lived."""
    act_dim = wrapped.action_size

    def at(memory):
        return acting.Policy(
            act=lambda x, k: 0.1 * jnp.tanh(0.1 * memory) * jnp.ones(act_dim),
            control=lambda x: 0.1 * jnp.tanh(0.1 * memory) * jnp.ones(act_dim),
        )

    policy = acting.RecurrentPolicy(memory=jnp.zeros(()), at=at,
                                    remember=lambda m, x, a, k: m + 1.0)  # fmt: skip
    task = wrapped.env.make_task(mass_scale=1.25)
    state = jax.jit(wrapped.reset)(jax.random.PRNGKey(0), task)
    run = jax.jit(lambda s: acting.unroll(wrapped, policy, s, EPISODES * STEPS))
    return state, run(state), task


def test_inner_episodes_restart_the_simulator_on_the_same_task(wrapped, trajectory):
    state, traj, task = trajectory
    obs_dim = wrapped.env.observation_size
    index = np.asarray(traj.env_metrics["meta_episode_index"])
    assert index.tolist() == [i for i in range(EPISODES) for _ in range(STEPS)]
    done = np.asarray(traj.done)
    assert done[:-1].sum() == 0 and done[-1] == 1  # only the last inner episode ends it
    first = np.asarray(traj.obs[:, -2])  # the first-step flag of the observation acted on
    assert first.tolist() == [1.0 if t % STEPS == 0 else 0.0 for t in range(EPISODES * STEPS)]
    # a restarted episode starts near the reset state (hopper: height ~1.25, still), not where
    # the previous one ended; the previous action and reward seen at its start are zeros
    starts = np.asarray(traj.obs[::STEPS, :obs_dim])
    np.testing.assert_allclose(starts[1:, 0], starts[0, 0], atol=0.02)
    assert np.all(np.asarray(traj.obs[STEPS::STEPS, obs_dim:-2]) == 0.0)
    # within an episode the observation carries the step's reward and the previous action
    np.testing.assert_allclose(np.asarray(traj.obs[1:STEPS, obs_dim + wrapped.action_size]),
                               np.asarray(traj.reward[: STEPS - 1]), rtol=1e-6)  # fmt: skip
    np.testing.assert_allclose(np.asarray(traj.obs[1, obs_dim:obs_dim + wrapped.action_size]),
                               np.asarray(traj.action[0]), rtol=1e-6)  # fmt: skip
    # the episode index, scaled to [0, 1]
    np.testing.assert_allclose(np.asarray(traj.obs[::STEPS, -1]), [0.0, 0.5, 1.0])
    # the task is the same in every inner episode
    tasks = jax.tree.leaves(jax.tree.map(lambda a, b: jnp.allclose(a, b), task, state.info["task"]))
    assert all(bool(t) for t in tasks)


def test_memory_goes_on_across_inner_episodes(trajectory):
    """The toy policy's action grows with its memory; no inner boundary resets it."""
    _, traj, _ = trajectory
    memory = np.arange(EPISODES * STEPS)
    np.testing.assert_allclose(np.asarray(traj.action[:, 0]), 0.1 * np.tanh(0.1 * memory),
                               rtol=1e-5)  # fmt: skip


def test_returns_by_episode_split_the_meta_episode(trajectory):
    _, traj, _ = trajectory
    got = returns_by_episode(traj.reward, traj.env_metrics["meta_episode_index"], traj.alive,
                             EPISODES)  # fmt: skip
    want = np.asarray(traj.reward).reshape(EPISODES, STEPS).sum(1)
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-5)


def test_a_collector_resets_memory_between_meta_episodes_only(wrapped):
    """``acting.step_envs`` (every collector's episode rule) with the meta-episode's length as
    the episode limit ends episodes only at meta-episode ends; a memory reset where an episode
    ended (DreamerV3's ``is_first``) then spans each whole meta-episode."""
    states = jax.vmap(wrapped.reset)(jax.random.split(jax.random.PRNGKey(1), 1))
    zeros = jnp.zeros((1, wrapped.action_size))

    def body(carry, _):
        states, length, memory = carry
        step = acting.step_envs(wrapped, states, zeros, length, wrapped.max_steps)
        fresh = jax.vmap(wrapped.reset)(jax.random.split(jax.random.PRNGKey(2), 1))
        states = jax.tree.map(
            lambda f, s: jnp.where(step.ended.reshape((-1,) + (1,) * (s.ndim - 1)), f, s),
            fresh,
            step.next_state,
        )
        memory = jnp.where(step.ended, 0.0, memory + 1.0)
        return (states, jnp.where(step.ended, 0, step.length), memory), (step.ended, memory)

    start = (states, jnp.zeros((1,), jnp.int32), jnp.zeros((1,)))
    _, (ended, memory) = jax.jit(lambda c: jax.lax.scan(body, c, None, 2 * wrapped.max_steps)
                                 )(start)  # fmt: skip
    ended = np.asarray(ended[:, 0])
    steps = wrapped.max_steps
    assert np.flatnonzero(ended).tolist() == [steps - 1, 2 * steps - 1]
    memory = np.asarray(memory[:, 0])
    assert memory[STEPS] == STEPS + 1  # carried over the first inner boundary
    assert memory[steps - 1] == 0 and memory[steps] == 1  # reset at the meta-episode's end


def test_evaluation_reports_each_inner_episodes_return(make_env):
    """The evaluator of a meta-episode run adds return_episode_<i>: here a policy that walks to
    the goal the same way in every inner episode earns the same return in each, summing to the
    meta-episode's."""
    from minatt_jax.evaluation import make_evaluator, summarize

    env = MetaEpisode(make_env("point_robot"), 3, 12)
    up = acting.Policy(act=lambda x, k: jnp.array([0.0, 1.0]), control=lambda x: x[:2] * 0.0)
    evaluate = make_evaluator(env, lambda params, norm: up, env.max_steps, 2)
    tasks = envs.task_set(env.env, "nominal")
    got = summarize(evaluate(None, None, jax.random.PRNGKey(0), tasks), env.dt)
    per_episode = [got[f"return_episode_{i}"] for i in (1, 2, 3)]
    assert per_episode[0] > 1.0 and np.allclose(per_episode, per_episode[0], rtol=1e-6)
    assert got["return"] == pytest.approx(sum(per_episode), rel=1e-6)
    assert got["length"] == 36


def test_feedforward_and_jerk_leave_out_the_jump_between_inner_episodes(make_env):
    """u = (0, 0.2 + 0.4 s) with s the scaled episode index: constant within each inner episode,
    so the feedforward and jerk of a meta-episode are 0; without the episode index (a plain
    episode's reading) the jumps at the two boundaries count."""
    env = MetaEpisode(make_env("point_robot"), 3, 6)
    u = lambda x: jnp.stack([0.0 * x[0], 0.2 + 0.4 * x[-1]])  # noqa: E731
    policy = acting.Policy(act=lambda x, key: u(x), control=u)
    traj = acting.unroll(env, policy, env.reset(jax.random.PRNGKey(0)), env.max_steps)
    got = acting.episode_metrics(traj, env.dt)
    assert float(got["feedforward_norm"]) == 0.0 and float(got["jerk"]) == 0.0
    assert float(got["energy"]) == pytest.approx(np.mean([0.2**2, 0.4**2, 0.6**2]), rel=1e-5)
    plain = acting.episode_metrics(traj.replace(env_metrics={}), env.dt)
    jump = (0.2 / env.dt) ** 2  # two boundaries among 17 differences
    assert float(plain["feedforward_norm"]) == pytest.approx(2 * jump / 17, rel=1e-5)


def test_a_chosen_start_begins_the_first_inner_episode_only(make_env):
    """``with_start`` (the failure grid's initial states): the first inner episode starts from
    the given simulator state and its observation shows it; the next inner episode starts from
    its own start drawn at the reset (the origin)."""
    env = MetaEpisode(make_env("point_robot"), 2, 3)
    state = env.reset(jax.random.PRNGKey(0))
    data = state.pipeline_state.replace(qpos=jnp.array([0.3, -0.2]))
    state = env.with_start(state, data)
    assert state.obs.shape == (env.observation_size,)
    np.testing.assert_allclose(state.obs[:2], [0.3, -0.2])
    assert state.obs[-2] == 1.0  # still the first step of an episode
    step = jax.jit(env.step)
    positions = []
    for _ in range(5):  # zero actions: the point stays where its episode started
        state = step(state, jnp.zeros(2))
        positions.append(np.asarray(state.obs[:2]))
    np.testing.assert_allclose(positions[:2], [[0.3, -0.2]] * 2)
    np.testing.assert_allclose(positions[2:], 0.0)  # the second episode, from the origin


@pytest.mark.slow
def test_a_run_in_meta_episodes_trains_and_evaluates(tmp_path, capsys):
    from minatt_jax.cli import main

    run = str(tmp_path / "meta")
    argv = ["train", "--env", "point_robot", "--preset", "smoke", "--steps", "300",
            "--set", "meta_episodes=3", "--set", "max_episode_steps=20", "--out", run]  # fmt: skip
    assert main(argv) == 0
    capsys.readouterr()
    assert main(["evaluate", run, "--variant", "ood", "--episodes", "2", "--json"]) == 0
    record = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert record["length"] == 60 and "return_episode_3" in record


def test_a_step_never_resets_the_simulator(make_env):
    """Restarts select a start state drawn when the meta-episode began: a step (vmapped, as
    collectors run it) calls no reset, which under a per-environment condition would run in
    every environment at every step."""

    class Counting:
        def __init__(self, env):
            self.env, self.resets = env, 0

        def __getattr__(self, name):
            return getattr(self.env, name)

        def reset(self, rng, task=None):
            self.resets += 1
            return self.env.reset(rng, task)

    inner = Counting(make_env("point_robot"))
    wrapped = MetaEpisode(inner, EPISODES, STEPS)
    states = jax.vmap(wrapped.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    assert inner.resets == 1  # traced once: one vmapped reset per inner episode's start
    jax.make_jaxpr(jax.vmap(wrapped.step))(states, jnp.zeros((2, 2)))
    assert inner.resets == 1

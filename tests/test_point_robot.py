"""point_robot (envs/point_robot.py): the reference's sparse goal reward written again in numpy,
goals as task data, crippled axes, train and out-of-distribution goal sets."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import counted_jit

import minatt_jax.envs as envs
from minatt_jax.envs.point_robot import OOD_GOALS, TRAIN_GOALS


def reference_step(position: np.ndarray, action: np.ndarray, goal_angle: float):
    """MAMBA's SparsePointEnv step (goal radius 0.2) in numpy, float64."""
    position = position + 0.1 * np.clip(action, -1.0, 1.0)
    goal = np.array([np.cos(goal_angle), np.sin(goal_angle)])
    distance = np.linalg.norm(position - goal)
    return position, (1.0 - distance if distance <= 0.2 else 0.0)


def test_steps_and_rewards_match_the_reference(make_env):
    env = make_env("point_robot")
    angle = 0.7
    state = jax.jit(env.reset)(jax.random.PRNGKey(0), env.make_task(target=angle))
    step = jax.jit(env.step)
    goal = np.array([np.cos(angle), np.sin(angle)])
    # head for the goal at the largest step, then overshoot with out-of-range actions
    actions = [np.clip(goal * 1.3, -1, 1)] * 9 + [np.array([2.0, -3.0])] * 3
    position, rewards = np.zeros(2), []
    for a in actions:
        state = step(state, jnp.asarray(a, jnp.float32))
        position, reward = reference_step(position, a, angle)
        rewards.append(reward)
        np.testing.assert_allclose(np.asarray(state.obs), position, atol=1e-5)
        assert float(state.reward) == pytest.approx(reward, abs=1e-5)
        assert float(state.done) == 0.0
    assert max(rewards) > 0.8 and rewards[-1] == 0.0  # reached the goal, then left it


def test_goals_are_data_and_crippled_axes_do_not_move(make_env):
    env = make_env("point_robot")
    step, traces = counted_jit(env.step)
    reset = jax.jit(env.reset)
    for angle in (0.0, 1.0, 3.0):
        step(reset(jax.random.PRNGKey(0), env.make_task(target=angle)), jnp.ones(2))
    crippled_x = envs.task_list(env, "crippled")[0][0]
    moved = step(reset(jax.random.PRNGKey(0), crippled_x), jnp.ones(2))
    assert len(traces) == 1
    np.testing.assert_allclose(np.asarray(moved.obs), [0.0, 0.1], atol=1e-7)


def test_train_goals_on_the_upper_half_ood_goals_on_the_lower(make_env):
    env = make_env("point_robot")
    train = np.asarray(envs.task_set(env, "train").target)
    ood = np.asarray(envs.task_set(env, "ood").target)
    np.testing.assert_allclose(train, TRAIN_GOALS, rtol=1e-6)
    np.testing.assert_allclose(ood, OOD_GOALS, rtol=1e-6)
    assert np.all((train >= 0) & (train <= np.pi + 1e-6))
    assert np.all((ood > np.pi) & (ood < 2 * np.pi))


def test_the_dense_variant_rewards_minus_the_distance_at_every_step(make_env):
    """point_robot_dense: the reference's PointEnv reward, -|x - goal|, on the same steps."""
    env = make_env("point_robot_dense")
    angle = 2.0
    state = jax.jit(env.reset)(jax.random.PRNGKey(0), env.make_task(target=angle))
    step = jax.jit(env.step)
    goal = np.array([np.cos(angle), np.sin(angle)])
    position = np.zeros(2)
    for a in ([1.0, 0.5], [-2.0, 0.3], [0.0, -1.0]):
        state = step(state, jnp.asarray(a, jnp.float32))
        position, _ = reference_step(position, np.asarray(a), angle)
        assert float(state.reward) == pytest.approx(-np.linalg.norm(position - goal), abs=1e-5)
    assert envs.task_set_names(env) == envs.task_set_names(make_env("point_robot"))

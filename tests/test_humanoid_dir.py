"""humanoid_dir (envs/humanoid_dir.py): the reward of the meta-RL benchmark, computed by hand
from MuJoCo C-engine states; directions as task data; train and out-of-distribution sets."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import counted_jit

import minatt_jax.envs as envs
from minatt_jax.envs.humanoid_dir import OOD_DIRECTIONS, TRAIN_DIRECTIONS


def _com_xy(m: mujoco.MjModel, d: mujoco.MjData) -> np.ndarray:
    return np.sum(m.body_mass[:, None] * d.xipos[:, :2], 0) / np.sum(m.body_mass)


@pytest.mark.slow
def test_reward_matches_a_hand_computation_on_the_c_engine(make_env):
    """20 steps of random actions on a direction task (and a heavier body): the MJX reward
    equals the reference definition computed from the C engine's states (float64): 1.25 x the
    centre of mass's velocity along the direction, + 5, - 0.1 |0.4 a|^2, - the contact cost."""
    env = make_env("humanoid_dir")
    theta = 2.0
    task = env.make_task(target=theta, mass_scale=1.1)
    state = jax.jit(env.reset)(jax.random.PRNGKey(3), task)
    m = env.mj_model.__copy__()
    envs.apply_task_to_mj_model(m, task)
    d = mujoco.MjData(m)
    d.qpos[:] = np.asarray(state.pipeline_state.qpos)
    d.qvel[:] = np.asarray(state.pipeline_state.qvel)
    mujoco.mj_forward(m, d)
    actions = np.random.default_rng(1).uniform(-1, 1, (20, env.action_size)).astype(np.float32)
    direction = np.array([np.cos(theta), np.sin(theta)])
    step = jax.jit(env.step)
    for a in actions:
        state = step(state, a)
        before = _com_xy(m, d)
        d.ctrl[:] = 0.4 * a
        for _ in range(5):
            mujoco.mj_step(m, d)
        mujoco.mj_rnePostConstraint(m, d)
        velocity = (_com_xy(m, d) - before) / (5 * m.opt.timestep)
        ctrl_cost = 0.1 * float(np.sum((0.4 * a.astype(np.float64)) ** 2))
        contact = min(5e-7 * float(np.sum(d.cfrc_ext**2)), 10.0)
        expected = 1.25 * float(direction @ velocity) + 5.0 - ctrl_cost - contact
        assert float(state.metrics["reward_ctrl"]) == pytest.approx(-ctrl_cost, rel=1e-5)
        assert float(state.reward) == pytest.approx(expected, abs=3e-3)
        assert bool(state.done) == (not 1.0 < d.qpos[2] < 2.0)
        np.testing.assert_allclose(np.asarray(state.obs)[:45], np.r_[d.qpos[2:], d.qvel],
                                   atol=2e-3, rtol=1e-3)  # fmt: skip


def test_direction_is_data_and_turns_the_forward_term(make_env):
    """One compiled step serves every direction; opposite directions give opposite forward
    terms from the same state and action, and the others their projections."""
    env = make_env("humanoid_dir")
    step, traces = counted_jit(env.step)
    reset = jax.jit(env.reset)
    action = jnp.full((env.action_size,), 0.3)
    forward = {}
    for theta in (0.0, np.pi / 2, np.pi):
        state = step(reset(jax.random.PRNGKey(0), env.make_task(target=theta)), action)
        forward[theta] = float(state.metrics["reward_forward"])
    assert len(traces) == 1
    assert forward[np.pi] == pytest.approx(-forward[0.0], rel=1e-4, abs=1e-6)
    assert abs(forward[0.0]) > 1e-4


def test_task_sets_train_inside_and_test_outside_the_training_directions(make_env):
    env = make_env("humanoid_dir")
    train = np.asarray(envs.task_set(env, "train").target)
    ood = np.asarray(envs.task_set(env, "ood").target)
    np.testing.assert_allclose(train, TRAIN_DIRECTIONS, rtol=1e-6)
    assert np.all((train >= 0) & (train < np.pi)) and np.all((ood > np.pi) & (ood < 2 * np.pi))
    np.testing.assert_allclose(ood, OOD_DIRECTIONS, rtol=1e-6)
    # the perturbation sets keep the nominal direction; a custom task names its own
    assert np.all(np.asarray(envs.task_set(env, "mass").target) == 0.0)
    assert float(envs.parse_task(env, "target=1.5,mass=1.2")[0].target) == pytest.approx(1.5)
    assert envs.task_set_names(env)[-1] == "ood" and "ood" not in envs.task_set_names(
        make_env("hopper"))  # fmt: skip
    with pytest.raises(envs.TaskSpecError, match="no 'ood' task set"):
        envs.task_list(make_env("hopper"), "ood")
    with pytest.raises(envs.TaskSpecError, match="take no target"):
        envs.parse_task(make_env("hopper"), "target=1")


def test_perturbation_tasks_keep_their_pytree_without_a_target(make_env):
    """Tasks of the other environments have no target leaf: their checkpoints are unchanged."""
    task = make_env("hopper").nominal_task()
    assert task.target is None
    assert len(jax.tree.leaves(task)) == 8

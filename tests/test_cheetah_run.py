"""cheetah_run against DMC's task written again on the MuJoCo C engine, with DMC's own reward
function (dm_control's Python physics does not load MuJoCo 4 models, so its files and its
``rewards.tolerance`` are what this test takes from the package)."""

from __future__ import annotations

import jax
import mujoco
import numpy as np
import pytest

from minatt_jax.envs import parse_task

rewards = pytest.importorskip("dm_control.utils.rewards", reason="needs minatt-jax[dmc]")


@pytest.fixture(scope="module")
def env(make_env):
    return make_env("cheetah_run")


def _dmc_observation(d: mujoco.MjData) -> np.ndarray:
    return np.concatenate([d.qpos[1:], d.qvel])  # DMC: position (without x), velocity


def _dmc_reward(m: mujoco.MjModel, d: mujoco.MjData) -> tuple[float, float]:
    """DMC's reward and speed: the torso_subtreelinvel sensor after the step's mj_step1 (DMC's
    legacy step brings position and velocity fields up to date after integrating)."""
    mujoco.mj_step1(m, d)
    speed = float(d.sensordata[m.sensor_adr[m.sensor("torso_subtreelinvel").id]])
    reward = rewards.tolerance(speed, bounds=(10, float("inf")), margin=10, value_at_margin=0,
                               sigmoid="linear")  # fmt: skip
    return float(reward), speed


def test_reset_settles_the_legs_like_the_c_engine(env):
    """The reset draws each leg joint in its range (root at rest) and settles 200 physics steps
    with zero control, as DMC's ``initialize_episode``."""
    key = jax.random.PRNGKey(4)
    state = jax.jit(env.reset)(key)
    _, key_q, key_v = jax.random.split(key, 3)
    qpos, qvel = (np.asarray(x, np.float64) for x in env.reset_noise(key_q, key_v))
    m = env.mj_model
    limited = m.jnt_limited == 1
    assert np.all(qpos[limited] >= m.jnt_range[limited, 0])
    assert np.all(qpos[limited] <= m.jnt_range[limited, 1])
    assert np.all(qpos[~limited] == 0) and np.all(qvel == 0) and limited.sum() == 6
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = qpos, qvel
    for _ in range(200):
        mujoco.mj_step(m, d)
    np.testing.assert_allclose(state.obs, _dmc_observation(d), atol=2e-3)
    assert float(state.pipeline_state.time) == 0.0


def test_steps_match_dmc_on_the_c_engine(env):
    """100 steps of random actions from a settled state: observation, speed and reward agree
    with the C engine (float64) and DMC's tolerance (float32 in MJX: 1e-4)."""
    m = env.mj_model
    assert (env.observation_size, env.action_size, env.dt) == (17, 6, 0.01)
    state = jax.jit(env.reset)(jax.random.PRNGKey(1))
    d = mujoco.MjData(m)
    d.qpos[:] = np.asarray(state.pipeline_state.qpos)
    d.qvel[:] = np.asarray(state.pipeline_state.qvel)
    mujoco.mj_forward(m, d)
    step = jax.jit(env.step)
    # Pushing forward so that the reward leaves 0 (it is 0 at and below zero speed).
    rng = np.random.default_rng(0)
    actions = np.clip(rng.normal(0.3, 0.6, (100, env.action_size)), -1, 1).astype(np.float32)
    rewarded = 0
    for t in range(100):
        state = step(state, actions[t])
        d.ctrl[:] = actions[t]
        mujoco.mj_step(m, d)
        reward, speed = _dmc_reward(m, d)
        np.testing.assert_allclose(state.obs, _dmc_observation(d), atol=2e-4, rtol=1e-4)
        assert float(state.metrics["x_velocity"]) == pytest.approx(speed, abs=1e-4)
        assert float(state.reward) == pytest.approx(reward, abs=1e-5)
        assert float(state.done) == 0.0
        rewarded += reward > 0
    assert rewarded > 10


def test_tasks_apply_to_cheetah_run(env):
    """Mass, crippled legs and slope change the run (tasks are data here as elsewhere)."""
    step = jax.jit(env.step)
    action = np.full(env.action_size, 0.5, np.float32)

    def speed_after(task):
        state = jax.jit(env.reset)(jax.random.PRNGKey(0), task)
        for _ in range(30):
            state = step(state, action)
        return float(state.metrics["x_velocity"])

    nominal = speed_after(env.nominal_task())
    for spec in ("mass=1.5", "crippled=bthigh+bshin", "slope=0.3"):
        assert abs(speed_after(parse_task(env, spec)[0]) - nominal) > 1e-3, spec

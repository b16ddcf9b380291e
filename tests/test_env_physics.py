"""The MJX environments against an independent computation on the MuJoCo C engine."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import minatt_jax.envs as envs

EXPECTED_DIMS = {
    "hopper": (11, 3),
    "halfcheetah": (17, 6),
    "walker2d": (17, 6),
    "humanoid": (45, 17),
    "humanoid_376": (376, 17),
    "cheetah_run": (17, 6),
    "humanoid_dir": (376, 17),
    "point_robot": (2, 2),
    "point_robot_dense": (2, 2),
}
# cheetah_run: test_cheetah_run.py; the meta-RL tasks (their rewards read the task):
# test_humanoid_dir.py, test_point_robot.py
GYM_ENVS = [
    n
    for n in envs.ENV_NAMES
    if n not in ("cheetah_run", "humanoid_dir", "point_robot", "point_robot_dense")
]


@pytest.mark.parametrize("name", envs.ENV_NAMES)
def test_dimensions(make_env, name):
    env = make_env(name)
    assert (env.observation_size, env.action_size) == EXPECTED_DIMS[name]
    assert len(env.obs_names) == env.observation_size


def _reference_obs(name: str, d: mujoco.MjData) -> np.ndarray:
    """Gym v3 observations written again in numpy (humanoid: MBPO's truncated obs)."""
    if name in ("hopper", "walker2d"):
        return np.concatenate([d.qpos[1:], np.clip(d.qvel, -10, 10)])
    if name == "halfcheetah":
        return np.concatenate([d.qpos[1:], d.qvel])
    if name == "humanoid_376":  # Gym v2/v3's observation, cfrc_ext after mj_rnePostConstraint
        return np.concatenate([d.qpos[2:], d.qvel, d.cinert.ravel(), d.cvel.ravel(),
                               d.qfrc_actuator, d.cfrc_ext.ravel()])  # fmt: skip
    return np.concatenate([d.qpos[2:], d.qvel])


def _reference_healthy(name: str, d: mujoco.MjData) -> bool:
    if name == "hopper":
        state = np.concatenate([d.qpos, d.qvel])[2:]
        return bool(np.all(np.abs(state) < 100) and d.qpos[1] > 0.7 and abs(d.qpos[2]) < 0.2)
    if name == "walker2d":
        return bool(0.8 < d.qpos[1] < 2.0 and -1 < d.qpos[2] < 1)
    if name.startswith("humanoid"):
        return bool(1.0 < d.qpos[2] < 2.0)
    return True


def _reference_forward(name: str, m: mujoco.MjModel, d: mujoco.MjData) -> float:
    if name.startswith("humanoid"):
        return float(np.sum(m.body_mass * d.xipos[:, 0]) / np.sum(m.body_mass))
    return float(d.qpos[0])


# (forward weight, ctrl weight, healthy bonus) from Gym v3's defaults.
GYM_WEIGHTS = {
    "hopper": (1.0, 1e-3, 1.0),
    "walker2d": (1.0, 1e-3, 1.0),
    "halfcheetah": (1.0, 0.1, 0.0),
    "humanoid": (1.25, 0.1, 5.0),
    "humanoid_376": (1.25, 0.1, 5.0),
}
FRAME_SKIP = {"hopper": 4, "walker2d": 4, "halfcheetah": 5, "humanoid": 5, "humanoid_376": 5}


@pytest.mark.slow
@pytest.mark.parametrize("name", GYM_ENVS)
def test_matches_mujoco_c_engine(make_env, name):
    """20 steps of a fixed random action sequence: observations, reward terms and termination
    agree with the C engine stepping the same MjModel in float64 (tolerance 2e-3: MJX runs in
    float32, and the difference grows with time in these chaotic systems)."""
    env = make_env(name)
    steps = 20
    state = jax.jit(env.reset)(jax.random.PRNGKey(1))
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, env.action_size)).astype(np.float32)
    m = env.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = np.asarray(state.pipeline_state.qpos)
    d.qvel[:] = np.asarray(state.pipeline_state.qvel)
    mujoco.mj_forward(m, d)
    mujoco.mj_rnePostConstraint(m, d)
    np.testing.assert_allclose(state.obs, _reference_obs(name, d), atol=1e-5, rtol=1e-5)
    dt = m.opt.timestep * FRAME_SKIP[name]
    assert env.dt == pytest.approx(dt)
    w_fwd, w_ctrl, w_healthy = GYM_WEIGHTS[name]
    step = jax.jit(env.step)
    contact_costs = []
    for t in range(steps):
        state = step(state, actions[t])
        x_before = _reference_forward(name, m, d)
        d.ctrl[:] = actions[t]
        for _ in range(FRAME_SKIP[name]):
            mujoco.mj_step(m, d)
        x_velocity = (_reference_forward(name, m, d) - x_before) / dt
        ctrl_cost = w_ctrl * float(np.sum(actions[t].astype(np.float64) ** 2))
        mujoco.mj_rnePostConstraint(m, d)  # fills cfrc_ext (only humanoid's read it)
        obs, reference = np.asarray(state.obs), _reference_obs(name, d)
        np.testing.assert_allclose(obs[:45], reference[:45], atol=2e-3, rtol=1e-3)
        # Contact forces come from the constraint solver: as the contact cost, to 2e-2.
        np.testing.assert_allclose(obs[45:], reference[45:], atol=2e-2, rtol=2e-2)
        assert float(state.metrics["reward_forward"]) == pytest.approx(w_fwd * x_velocity, abs=2e-3)
        assert float(state.metrics["reward_ctrl"]) == pytest.approx(-ctrl_cost, rel=1e-5)
        expected = w_fwd * x_velocity - ctrl_cost + w_healthy
        if name.startswith("humanoid"):  # Gym's contact cost, as Gymnasium v5 computes it
            contact = min(5e-7 * float(np.sum(d.cfrc_ext**2)), 10.0)
            contact_costs.append(contact)
            assert -float(state.metrics["reward_contact"]) == pytest.approx(
                contact, rel=2e-2, abs=2e-4
            )
            expected -= contact
        assert float(state.reward) == pytest.approx(expected, abs=3e-3)
        assert bool(state.done) == (not _reference_healthy(name, d))
    if name.startswith("humanoid"):
        assert max(contact_costs) > 1e-3  # the feet press on the floor: the term is not zero


@pytest.mark.slow
def test_reset_without_forward_steps_as_with_it(make_env):
    """Environments that observe qpos and qvel alone skip the reset's ``mjx.forward`` (one MJX
    pipeline fewer to compile in every program that resets): their observation and the steps
    that follow are exactly those of the forwarded state."""
    env = make_env("hopper")
    assert not env.reset_runs_forward and make_env("humanoid").reset_runs_forward
    state = jax.jit(env.reset)(jax.random.PRNGKey(2))
    forwarded = state.replace(
        pipeline_state=jax.jit(mjx.forward)(env.mjx_model, state.pipeline_state)
    )
    np.testing.assert_array_equal(env.observation(forwarded.pipeline_state), state.obs)
    actions = np.random.default_rng(1).uniform(-1, 1, (10, env.action_size)).astype(np.float32)

    @jax.jit
    def rollout(s):
        return jax.lax.scan(lambda s, a: (env.step(s, a),) * 2, s, actions)[1]

    ours, reference = rollout(state), rollout(forwarded)
    for field in ("obs", "reward", "done"):
        np.testing.assert_array_equal(getattr(ours, field), getattr(reference, field))
    assert float(jnp.max(jnp.abs(ours.obs[-1] - state.obs))) > 0.01  # the hopper moved

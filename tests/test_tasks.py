"""Tasks as data: each perturbation does what it says, inside one compiled program."""

from __future__ import annotations

import copy
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import counted_jit

import minatt_jax.envs as envs
from minatt_jax import acting


class _Totals(NamedTuple):
    episode_return: jax.Array
    forward_reward: jax.Array


def _rollout(env, policy, steps):
    """(key, task) -> returns summed until the first done (``acting.unroll``)."""

    def run(key, task):
        key_reset, key_policy = jax.random.split(key)
        traj = acting.unroll(env, policy, env.reset(key_reset, task), steps, key=key_policy)
        forward = jnp.sum(traj.alive * traj.env_metrics["reward_forward"])
        return _Totals(jnp.sum(traj.alive * traj.reward), forward)

    return run


def test_mass_scale_scales_total_mass_and_inertia(make_env):
    env = make_env("hopper")
    task = env.make_task(mass_scale=1.5)
    model = envs.apply_task(env.mjx_model, env.nominal_fields, task)
    total = float(jnp.sum(model.body_mass))
    assert total == pytest.approx(1.5 * float(np.sum(env.mj_model.body_mass)), rel=1e-6)
    np.testing.assert_allclose(model.body_inertia, 1.5 * env.mj_model.body_inertia, rtol=1e-6)
    # The root subtree mass is the total mass: derived constants follow the scale.
    assert float(model.body_subtreemass[0]) == pytest.approx(total, rel=1e-6)


def test_every_task_field_matches_the_c_engine(make_env):
    """One task perturbing everything at once, stepped in MJX, against the C engine stepping a
    model perturbed by hand (masses, inertias, friction, tilted gravity, gears), mj_setConst."""
    env = make_env("hopper")
    act_scale = np.array([0.0, 1.0, 0.5])
    task = env.make_task(
        mass_scale=1.3, friction_scale=0.7, gravity_scale=1.1, slope=0.08, actuator_scale=act_scale
    )
    m = copy.copy(env.mj_model)
    m.body_mass[:] *= 1.3
    m.body_inertia[:] *= 1.3
    m.geom_friction[:] *= 0.7
    g = 9.81 * 1.1
    m.opt.gravity[:] = [-g * np.sin(0.08), 0.0, -g * np.cos(0.08)]
    m.actuator_gear[:, 0] *= act_scale
    d = mujoco.MjData(m)
    mujoco.mj_setConst(m, d)
    state = jax.jit(env.reset)(jax.random.PRNGKey(3), task)
    d.qpos[:], d.qvel[:] = (
        np.asarray(state.pipeline_state.qpos),
        np.asarray(state.pipeline_state.qvel),
    )
    step = jax.jit(env.step)
    actions = np.random.default_rng(1).uniform(-1, 1, (15, 3)).astype(np.float32)
    for a in actions:
        state = step(state, a)
        d.ctrl[:] = a
        for _ in range(env.frame_skip):
            mujoco.mj_step(m, d)
    np.testing.assert_allclose(state.pipeline_state.qpos, d.qpos, atol=2e-3)
    np.testing.assert_allclose(state.pipeline_state.qvel, d.qvel, atol=2e-2)


def test_crippled_actuator_produces_no_force(make_env):
    env = make_env("hopper")
    crippled = envs.select_task(envs.task_set(env, "crippled"), 0)
    assert float(crippled.actuator_scale[0]) == 0.0  # the thigh
    step, reset = jax.jit(env.step), jax.jit(env.reset)
    action = jnp.array([1.0, -1.0, 0.5])
    thigh_dof = env.mj_model.jnt_dofadr[env.mj_model.joint("thigh_joint").id]
    forces = {}
    for label, task in (("nominal", env.nominal_task()), ("crippled", crippled)):
        state = step(reset(jax.random.PRNGKey(0), task), action)
        forces[label] = np.asarray(state.pipeline_state.qfrc_actuator)
    assert forces["crippled"][thigh_dof] == 0.0
    assert abs(forces["nominal"][thigh_dof]) > 50.0
    other = [i for i in range(env.mj_model.nv) if i != thigh_dof and abs(forces["nominal"][i]) > 0]
    np.testing.assert_allclose(forces["crippled"][other], forces["nominal"][other], rtol=1e-5)


def test_slope_tilts_gravity_and_changes_progress(make_env):
    env = make_env("halfcheetah")
    slopes = envs.task_set(env, "slope")
    model = envs.apply_task(env.mjx_model, env.nominal_fields, envs.select_task(slopes, 1))
    g = np.asarray(model.opt.gravity)
    assert np.linalg.norm(g) == pytest.approx(9.81, rel=1e-5)
    assert np.arctan2(-g[0], -g[2]) == pytest.approx(0.10, abs=1e-6)  # uphill 0.10 rad
    # A fixed action sequence on uphill and downhill slopes and on flat ground, one vmapped call.
    tasks = envs.stack_tasks([env.nominal_task()] + [envs.select_task(slopes, i) for i in (1, 3)])
    policy = acting.Policy(act=lambda obs, key: 0.5 * jnp.sin(jnp.arange(6.0) + obs[0]))
    rollout = jax.jit(jax.vmap(_rollout(env, policy, 60), in_axes=(None, 0)))
    progress = np.asarray(rollout(jax.random.PRNGKey(0), tasks).forward_reward)
    flat, uphill, downhill = progress
    assert uphill < flat < downhill


def test_friction_changes_sliding(make_env):
    """On a 0.1 rad downhill with zero torque, the cheetah (friction 0.4 > tan 0.1) holds, but
    slides once friction x0.1 (0.04 < tan 0.1)."""
    env = make_env("halfcheetah")
    tasks = envs.stack_tasks(
        [env.make_task(slope=-0.1), env.make_task(slope=-0.1, friction_scale=0.1)]
    )
    rollout = jax.jit(jax.vmap(_rollout(env, acting.zero_policy(6), 40), in_axes=(None, 0)))
    held, slid = np.asarray(rollout(jax.random.PRNGKey(0), tasks).forward_reward) * env.dt
    assert slid > 0.5
    assert slid > 5 * abs(held)


def test_switching_tasks_does_not_recompile(make_env):
    env = make_env("hopper")
    step, traces = counted_jit(env.step)
    action = jnp.full((3,), 0.3)
    reset = jax.jit(env.reset)
    returns = []
    for set_name in envs.TASK_SET_NAMES:
        task_set = envs.task_set(env, set_name)
        for i in range(envs.num_tasks(task_set)):
            state = step(reset(jax.random.PRNGKey(0), envs.select_task(task_set, i)), action)
            returns.append(float(state.pipeline_state.qpos[0]))
    assert len(traces) == 1
    assert len(set(np.round(returns, 7))) > 5  # the tasks did change the physics


def test_batch_of_different_tasks_in_one_call(make_env):
    env = make_env("hopper")
    mass = envs.task_set(env, "mass")
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    rollout = jax.jit(jax.vmap(_rollout(env, acting.zero_policy(3), 30)))
    out = rollout(jnp.stack([keys[0]] * 5), mass)
    single = jax.jit(_rollout(env, acting.zero_policy(3), 30))(keys[0], envs.select_task(mass, 4))
    np.testing.assert_allclose(out.episode_return[4], single.episode_return, rtol=1e-5)
    assert len(set(np.round(np.asarray(out.episode_return), 5))) == 5


def test_sample_task_draws_from_the_set(make_env):
    env = make_env("hopper")
    train = envs.task_set(env, "train")
    draws = jax.vmap(lambda k: envs.sample_task(k, train).gravity_scale)(
        jax.random.split(jax.random.PRNGKey(0), 200)
    )
    assert {round(float(x), 2) for x in draws} == {0.9, 0.95, 1.0, 1.05, 1.1}


def test_fixed_key_gives_identical_rollouts(make_env):
    env = make_env("walker2d")
    rollout = jax.jit(_rollout(env, acting.random_policy(6), 50))
    task = env.nominal_task()
    a = rollout(jax.random.PRNGKey(7), task)
    b = rollout(jax.random.PRNGKey(7), task)
    c = rollout(jax.random.PRNGKey(8), task)
    assert float(a.episode_return) == float(b.episode_return)
    assert float(a.forward_reward) == float(b.forward_reward)
    assert float(a.episode_return) != float(c.episode_return)


def test_invalid_task_values_are_rejected(make_env):
    env = make_env("hopper")
    with pytest.raises(ValueError, match="mass_scale"):
        env.make_task(mass_scale=-1.0)
    with pytest.raises(ValueError, match="slope"):
        env.make_task(slope=2.0)

"""Imagined rollouts and termination functions: stop at termination, guard, masked insertion."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from minatt_jax import imagination, replay
from minatt_jax.agents.mbpo import MBConfig
from minatt_jax.dynamics_ensemble import Ensemble, EnsembleState, ModelConfig, Normalization
from minatt_jax.envs import Hopper


def _falling_model(nan_slot: int | None = None) -> tuple[Ensemble, EnsembleState]:
    """A stand-in ensemble: member k lowers obs[0] by 0.1 * (k + 1) per step, reward = k."""

    def step(params, norm, obs, action, key, deterministic=False):
        drop = 0.1 * (params["k"] + 1.0)
        nxt = obs.at[..., 0].add(-drop)
        if nan_slot is not None:
            nxt = jnp.where(params["k"] == nan_slot, jnp.nan, nxt)
        return nxt, jnp.broadcast_to(params["k"], obs.shape[:-1]).astype(jnp.float32)

    ens = Ensemble(config=ModelConfig(), init=None, fit=None, predict=None, step=step)
    norm = Normalization(jnp.zeros(14), jnp.ones(14), jnp.zeros(12), jnp.ones(12))
    state = EnsembleState(
        params={"k": jnp.arange(3.0)}, opt_state=None, norm=norm, holdout_mse=jnp.zeros(3),
        elites=jnp.array([0, 1], jnp.int32), fits=jnp.zeros((), jnp.int32),
        last_epochs=jnp.zeros((), jnp.int32),
    )  # fmt: skip
    return ens, state


def _policy(params, obs, key):
    return jnp.zeros(obs.shape[:-1] + (3,))


def _start(slots, n):
    obs = jnp.zeros((slots, n, 11)).at[..., 0].set(1.0)  # hopper: z = 1.0, upright
    return obs


def test_rollouts_stop_at_termination_and_length():
    ens, state = _falling_model()
    members = jnp.array([0, 1], jnp.int32)
    out, alive = imagination.imagine(
        ens, state, members, _policy, None, Hopper.terminated, _start(2, 4), jnp.asarray(5), 8,
        jax.random.PRNGKey(0),
    )  # fmt: skip
    alive = np.asarray(alive)
    # Member 0: z = 0.9, 0.8, 0.7 -> the third step terminates (z <= 0.7); member 1 (drop 0.2):
    # z = 0.8, 0.6 -> the second step terminates. Steps after termination are not alive.
    np.testing.assert_array_equal(alive[0, :, 0], [1, 1, 1, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(alive[1, :, 0], [1, 1, 0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(np.asarray(out.terminal)[0, :3, 0], [0, 0, 1])
    np.testing.assert_allclose(np.asarray(out.next_obs)[1, 1, 0, 0], 0.6, atol=1e-6)
    # Each trajectory stays on its slot's member: slot 1's rewards are member 1's.
    assert np.all(np.asarray(out.reward)[1, :2] == 1.0)
    # The length limit: with length 2, slot 0 stops after two steps without terminating.
    _, alive2 = imagination.imagine(
        ens, state, members, _policy, None, Hopper.terminated, _start(2, 4), jnp.asarray(2), 8,
        jax.random.PRNGKey(0),
    )  # fmt: skip
    np.testing.assert_array_equal(np.asarray(alive2)[0, :, 0], [1, 1, 0, 0, 0, 0, 0, 0])


def test_non_finite_predictions_are_not_stored():
    ens, state = _falling_model(nan_slot=1)
    out, alive = imagination.imagine(
        ens, state, jnp.array([0, 1], jnp.int32), _policy, None, Hopper.terminated,
        _start(2, 3), jnp.asarray(3), 3, jax.random.PRNGKey(0),
    )  # fmt: skip
    assert np.all(np.asarray(alive)[1] == 0)  # member 1 predicts NaN: nothing alive
    assert np.all(np.isfinite(np.asarray(out.next_obs)))
    buffers = replay.init_slot_buffers(2, 50, 11, 3)
    buffers = replay.insert_slots(buffers, out, alive)
    np.testing.assert_array_equal(np.asarray(buffers.size), [9, 0])


def test_masked_insert_keeps_order_and_old_data():
    buf = replay.init_buffer(6, 1, 1)

    def rows(values):
        v = jnp.asarray(values, jnp.float32)
        return replay.Transitions(obs=v[:, None], action=v[:, None], reward=v,
                                  next_obs=v[:, None], terminal=jnp.zeros_like(v))  # fmt: skip

    buf = replay.insert_masked(buf, rows([1, 2, 3, 4]), jnp.array([1, 0, 1, 1]))
    assert int(buf.size) == 3 and int(buf.position) == 3
    np.testing.assert_array_equal(np.asarray(buf.data.reward)[:3], [1, 3, 4])
    buf = replay.insert_masked(buf, rows([5, 6, 7, 8]), jnp.array([0, 1, 1, 0]))
    np.testing.assert_array_equal(np.asarray(buf.data.reward), [1, 3, 4, 6, 7, 0])
    # Wrapping around: the oldest rows are overwritten, the rest kept.
    buf = replay.insert_masked(buf, rows([9, 10, 11, 12]), jnp.array([1, 1, 1, 0]))
    np.testing.assert_array_equal(np.asarray(buf.data.reward), [10, 11, 4, 6, 7, 9])
    assert int(buf.size) == 6
    with pytest.raises(ValueError):
        replay.insert_masked(buf, rows(list(range(7))), jnp.ones(7))


def test_slot_sampling_uses_only_valid_rows():
    buffers = replay.init_slot_buffers(3, 10, 1, 1)
    data = buffers.data.replace(reward=jnp.arange(30.0).reshape(3, 10))
    buffers = buffers.replace(data=data, size=jnp.array([2, 0, 5]))
    got = np.asarray(replay.sample_all_slots(buffers, jax.random.PRNGKey(0), 4000).reward)
    assert set(np.unique(got)) == {0.0, 1.0, 20.0, 21.0, 22.0, 23.0, 24.0}
    assert abs(np.mean(got >= 20) - 5 / 7) < 0.03  # uniform over the 7 valid rows
    one = np.asarray(replay.sample_slot(buffers, 2, jax.random.PRNGKey(1), 100).reward)
    assert set(np.unique(one)) <= {20.0, 21.0, 22.0, 23.0, 24.0}


def test_hopper_termination_fixes_mbpo_parenthesis():
    ok = np.zeros(11, np.float32)
    ok[0] = 1.25
    assert float(Hopper.terminated(jnp.asarray(ok))) == 0.0
    bad = ok.copy()
    bad[5] = -150.0  # a large negative value: MBPO's np.abs(x < 100) never flags it
    assert float(Hopper.terminated(jnp.asarray(bad))) == 1.0
    assert bool(np.abs(bad[1:] < 100).all())  # the official function would have continued


@pytest.mark.parametrize(
    "name",
    [  # hopper and halfcheetah in CI: one with termination, one without
        "hopper",
        pytest.param("walker2d", marks=pytest.mark.extended),
        pytest.param("humanoid", marks=pytest.mark.extended),
        "halfcheetah",
    ],
)
def test_termination_functions_match_the_environments(name, make_env):
    env = make_env(name)
    fn = env.terminated

    def rollout(key):
        state = env.reset(key)

        def body(state, k):
            action = jax.random.uniform(k, (env.action_size,), minval=-1.0, maxval=1.0)
            nxt = env.step(state, action)
            return nxt, (nxt.obs, nxt.done)

        return jax.lax.scan(body, state, jax.random.split(key, 60))[1]

    obs, done = jax.jit(jax.vmap(rollout))(jax.random.split(jax.random.PRNGKey(0), 8))
    obs, done = np.asarray(obs), np.asarray(done)
    np.testing.assert_array_equal(np.asarray(fn(jnp.asarray(obs))), done)
    if name != "halfcheetah":
        assert 0.05 < done.mean() < 0.95  # both outcomes occur on these states


def test_rollout_length_schedule():
    mb = MBConfig(rollout_schedule=(20, 100, 1, 15))
    assert [mb.rollout_length(e) for e in (0, 20, 60, 100, 300)] == [1, 1, 8, 15, 15]
    traced = jax.jit(lambda e: jnp.asarray(mb.rollout_length(e), jnp.int32))
    assert [int(traced(jnp.asarray(e))) for e in (0, 60, 300)] == [1, 8, 15]

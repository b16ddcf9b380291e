"""Control analysis: K(t) x + v(t) = u exactly, binning by hand, the failure criterion."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from minatt_jax import acting
from minatt_jax.analysis import control_analysis as ca
from minatt_jax.config import TrainConfig
from minatt_jax.min_attention import MAConfig
from minatt_jax.sac import SACConfig, make_sac
from minatt_jax.training import hyper_of


def test_decomposition_reproduces_the_control_exactly():
    sac = make_sac(11, 3, SACConfig(hidden=(32, 32)), MAConfig())
    params = sac.init(jax.random.PRNGKey(0), hyper_of(TrainConfig())).actor_params
    obs = jax.random.normal(jax.random.PRNGKey(1), (50, 11))
    out = ca.decompose(sac.control, params, obs)
    rebuilt = jnp.einsum("tao,to->ta", out["K"], obs) + out["v"]
    np.testing.assert_allclose(np.asarray(rebuilt), np.asarray(out["u"]), atol=1e-6)
    np.testing.assert_allclose(np.asarray(out["u"]), np.asarray(sac.control(params, obs)),
                               atol=1e-6)  # fmt: skip
    # K(t) is the Jacobian: a finite difference along one input direction.
    eps = 1e-3
    e = jnp.zeros(11).at[4].set(1.0)
    fd = (sac.control(params, obs[7] + eps * e) - sac.control(params, obs[7] - eps * e)) / (2 * eps)
    np.testing.assert_allclose(np.asarray(out["K"][7, :, 4]), np.asarray(fd), atol=2e-3)
    np.testing.assert_allclose(
        np.asarray(out["feedback"]), np.asarray(out["K_norm"]) ** 2, rtol=1e-5
    )


def test_binned_means_match_a_hand_computed_grid():
    x = np.array([0.1, 0.2, 0.6, 0.9, 1.0, 0.4, -0.5])
    y = np.array([0.1, 0.3, 0.1, 0.9, 1.0, 0.8, 0.5])
    v = np.array([1.0, 3.0, 5.0, 7.0, 9.0, 11.0, 100.0])
    means, counts = ca.binned_means(x, y, v, np.array([0.0, 0.5, 1.0]), np.array([0.0, 0.5, 1.0]))
    # Cells: x in [0, .5) / [.5, 1], y likewise; (-0.5, 0.5) falls outside and is dropped.
    np.testing.assert_array_equal(counts, [[2, 1], [1, 2]])
    np.testing.assert_allclose(means, [[2.0, 11.0], [5.0, 8.0]])
    empty, _ = ca.binned_means(x, y, v, np.array([5.0, 6.0]), np.array([5.0, 6.0]))
    assert np.isnan(empty).all()


def test_failure_criterion_on_constructed_states(make_env):
    cheetah = np.zeros((5, 17), np.float32)
    cheetah[1, 0] = -0.43  # torso below -0.42
    cheetah[2, 1] = 1.2  # pitched over
    cheetah[3, 1] = -1.15
    cheetah[4, 0], cheetah[4, 1] = -0.41, 1.09  # close, but fine
    np.testing.assert_array_equal(
        np.asarray(make_env("halfcheetah").failed(jnp.asarray(cheetah))), [0, 1, 1, 1, 0]
    )
    hopper = np.zeros((3, 11), np.float32)
    hopper[:, 0] = 1.25
    hopper[1, 0] = 0.6  # fallen
    hopper[2, 1] = 0.3  # tilted
    np.testing.assert_array_equal(
        np.asarray(make_env("hopper").failed(jnp.asarray(hopper))), [0, 1, 1]
    )


def test_projections_name_real_observations(make_env):
    for name in ("hopper", "halfcheetah", "walker2d", "humanoid"):
        env = make_env(name)
        pairs = env.projection_indices()
        assert len(pairs) == len(env.projections) >= 2
        assert all(0 <= i < env.observation_size and 0 <= j < env.observation_size
                   for i, j in pairs)  # fmt: skip
        (vx_lo, vx_hi), (w_lo, w_hi) = env.failure_grid_ranges
        assert vx_lo < 0.0 < vx_hi and w_lo < 0.0 < w_hi  # standing still lies inside the grid


def test_failure_grid_zero_policy_on_hopper(make_env):
    env = make_env("hopper")
    grid = ca.make_failure_grid(env, lambda p: acting.zero_policy(3), steps=60, rollouts=3)
    rates = np.asarray(
        grid(None, jnp.array([0.0, 3.0]), jnp.array([0.0, 6.0]), jax.random.PRNGKey(0),
             env.nominal_task())
    )  # fmt: skip
    assert rates.shape == (2, 2) and np.all((rates >= 0) & (rates <= 1))
    # A passive hopper launched with a large pitch rate falls within 60 steps; standing still
    # it survives (0.5 s of a passive hop is not enough to fall).
    assert rates[0, 1] == 1.0 and rates[1, 1] == 1.0
    assert rates[0, 0] == 0.0

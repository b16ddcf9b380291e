"""The dynamics ensemble: fits a known nonlinear system, learns its noise level, picks elites."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from minatt_jax.dynamics_ensemble import ModelConfig, make_ensemble, member
from minatt_jax.replay import Transitions

SIGMA = 0.05  # known noise on the state change


def _system(obs, act):
    """A nonlinear 2-state system: delta obs and reward."""
    delta = np.stack([np.sin(2 * obs[:, 1]) + act[:, 0], np.cos(obs[:, 0]) * obs[:, 1]], -1)
    return delta, obs[:, 0] ** 2 - act[:, 0]


def _data(capacity, seed=0):
    rng = np.random.default_rng(seed)
    obs = rng.uniform(-2, 2, (capacity, 2)).astype(np.float32)
    act = rng.uniform(-1, 1, (capacity, 1)).astype(np.float32)
    delta, reward = _system(obs, act)
    noisy = obs + delta + SIGMA * rng.standard_normal(delta.shape)
    return Transitions(
        obs=jnp.asarray(obs), action=jnp.asarray(act), reward=jnp.asarray(reward, jnp.float32),
        next_obs=jnp.asarray(noisy, jnp.float32), terminal=jnp.zeros(capacity),
    )  # fmt: skip


CONFIG = ModelConfig(
    ensemble_size=4, num_elites=2, hidden=(64, 64), weight_decay=(1e-5, 1e-5, 1e-5),
    batch_size=128, max_epochs=80, max_holdout=1000,
)  # fmt: skip


def test_ensemble_fits_a_nonlinear_system_and_its_noise():
    ens = make_ensemble(2, 1, CONFIG)
    fit = jax.jit(ens.fit)
    data = _data(8000)
    state = ens.init(jax.random.PRNGKey(0))
    # The valid rows are the first 6000 of a larger buffer: the rest must be ignored.
    garbage = data.replace(next_obs=data.next_obs.at[6000:].set(1e6))
    state, metrics = fit(state, garbage, jnp.asarray(6000), jax.random.PRNGKey(1))
    state, metrics = fit(state, garbage, jnp.asarray(6000), jax.random.PRNGKey(2))
    assert float(metrics["model_holdout_mse"]) < 0.05  # normalized targets: 5% of the variance
    rng = np.random.default_rng(7)
    obs = rng.uniform(-1.5, 1.5, (3000, 2)).astype(np.float32)
    act = rng.uniform(-1, 1, (3000, 1)).astype(np.float32)
    delta, reward = _system(obs, act)
    truth = np.concatenate([delta, reward[:, None]], -1)
    best = int(state.elites[0])
    mean, var = ens.predict(member(state.params, best), state.norm, obs, act)
    mse = np.mean((np.asarray(mean) - truth) ** 2, axis=0)
    assert np.all(mse[:2] < 0.1 * np.var(delta, axis=0))
    # Predicted noise of the state change: the known sigma (model error adds a little).
    predicted_std = np.sqrt(np.mean(np.asarray(var)[:, :2], axis=0))
    assert np.all(predicted_std > 0.7 * SIGMA) and np.all(predicted_std < 1.6 * SIGMA)
    # The reward is noise-free: far smaller predicted std.
    assert np.sqrt(np.mean(np.asarray(var)[:, 2])) < 0.5 * SIGMA


def test_elites_are_the_lowest_holdout_members():
    config = ModelConfig(**{**CONFIG.__dict__, "lr": 1e-12, "max_epochs": 1})  # no learning
    ens = make_ensemble(2, 1, config)
    state = ens.init(jax.random.PRNGKey(0))
    fit = jax.jit(ens.fit)
    data = _data(4000)
    # Fit a little with a normal learning rate, then break members 0 and 2.
    trained, _ = jax.jit(make_ensemble(2, 1, CONFIG).fit)(
        state, data, jnp.asarray(4000), jax.random.PRNGKey(1)
    )
    last = trained.params["layers"][-1]
    broken_w = last["w"].at[jnp.array([0, 2])].add(3.0)
    params = {**trained.params, "layers": [*trained.params["layers"][:-1], {**last, "w": broken_w}]}
    state = trained.replace(params=params)
    state, _ = fit(state, data, jnp.asarray(4000), jax.random.PRNGKey(2))
    assert sorted(np.asarray(state.elites).tolist()) == [1, 3]
    mse = np.asarray(state.holdout_mse)
    assert np.all(np.argsort(mse)[:2] == np.asarray(state.elites))
    assert min(mse[0], mse[2]) > 10 * max(mse[1], mse[3])


def test_early_stopping_stops_and_growth_does_not_recompile():
    config = ModelConfig(**{**CONFIG.__dict__, "max_epochs": 500, "patience": 2})
    ens = make_ensemble(2, 1, config)
    fit = jax.jit(ens.fit)
    data = _data(3000)
    state = jax.device_put(ens.init(jax.random.PRNGKey(0)), jax.devices()[0])
    for size in (1000, 2000, 3000):
        state, metrics = fit(state, data, jnp.asarray(size), jax.random.PRNGKey(size))
        assert 1 <= int(metrics["model_epochs"]) < 500  # stopped by patience, not the cap
    assert fit._cache_size() == 1

"""SAC building blocks: tanh-Gaussian log-probabilities, replay buffer, observation normalizer."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from minatt_jax import normalizer, replay
from minatt_jax.networks import sample_tanh_gaussian


def test_tanh_gaussian_log_prob_matches_change_of_variables():
    mean, log_std = jnp.array([0.3, -0.5]), jnp.array([-0.2, 0.1])
    key = jax.random.PRNGKey(0)
    action, logp = sample_tanh_gaussian(key, mean, log_std)
    pre = jnp.arctanh(action)
    std = jnp.exp(log_std)
    gauss = -0.5 * ((pre - mean) / std) ** 2 - log_std - 0.5 * jnp.log(2 * jnp.pi)
    expected = jnp.sum(gauss - jnp.log(1 - action**2))
    assert float(logp) == pytest.approx(float(expected), rel=1e-4)


def test_replay_buffer_wraps_and_samples_only_valid_rows():
    buf = replay.init_buffer(5, obs_dim=2, act_dim=1)

    def batch(start, n):
        x = jnp.arange(start, start + n, dtype=jnp.float32)
        return replay.Transitions(
            obs=jnp.stack([x, x], 1), action=x[:, None], reward=x, next_obs=jnp.stack([x, x], 1),
            terminal=jnp.zeros(n),
        )  # fmt: skip

    buf = replay.insert(buf, batch(0, 3))
    assert int(buf.size) == 3
    sampled = replay.sample(buf, jax.random.PRNGKey(0), 200)
    assert set(np.asarray(sampled.reward).tolist()) == {0.0, 1.0, 2.0}
    buf = replay.insert(buf, batch(3, 4))  # 7 rows into capacity 5: 0 and 1 overwritten
    assert int(buf.size) == 5 and int(buf.position) == 2
    assert sorted(np.asarray(buf.data.reward).tolist()) == [2.0, 3.0, 4.0, 5.0, 6.0]


def test_select_rows_chooses_whole_rows_over_the_mask_axes():
    mask = jnp.array([[True, False, True], [False, False, True]])  # (members, envs)
    a = {"x": jnp.ones((2, 3, 4)), "s": jnp.ones((2, 3))}
    b = {"x": jnp.zeros((2, 3, 4)), "s": jnp.zeros((2, 3))}
    out = replay.select_rows(mask, a, b)
    np.testing.assert_array_equal(out["s"], mask.astype(jnp.float32))
    expected = np.repeat(np.asarray(mask, np.float32)[..., None], 4, axis=-1)
    np.testing.assert_array_equal(out["x"], expected)


def test_normalizer_matches_numpy_statistics():
    data = np.random.default_rng(0).normal(3.0, 2.0, (300, 4)).astype(np.float32)
    norm = normalizer.init_normalizer(4)
    for chunk in np.split(data, 6):
        norm = normalizer.update(norm, jnp.asarray(chunk))
    np.testing.assert_allclose(norm.mean, data.mean(0), rtol=1e-4)
    np.testing.assert_allclose(norm.var, data.var(0), rtol=1e-3)
    z = normalizer.normalize(norm, jnp.asarray(data), enabled=True)
    assert float(jnp.abs(jnp.mean(z))) < 1e-3
    assert normalizer.normalize(norm, jnp.asarray(data), enabled=False) is not None


def test_entropy_placement_charges_the_next_state_in_the_critic_target():
    """placement="entropy": the critic target loses gamma (1 - d) alpha penalty(s'), exactly the
    regularizer's per-state penalty at the next states; other placements leave the target alone."""
    from minatt_jax import min_attention as ma
    from minatt_jax.config import TrainConfig
    from minatt_jax.sac import SACConfig, make_sac
    from minatt_jax.training import hyper_of

    key = jax.random.PRNGKey(0)
    obs = jax.random.normal(key, (16, 4))
    batch = replay.Transitions(
        obs=obs, action=jnp.zeros((16, 2)), reward=jnp.ones((16,)),
        next_obs=obs + 0.1, terminal=jnp.zeros((16,)),
    )  # fmt: skip
    losses = {}
    for placement in ("actor_loss", "entropy"):
        cfg = ma.MAConfig(alpha=5.0, placement=placement, mode="jacobian", subsample=0)
        sac = make_sac(4, 2, SACConfig(hidden=(8, 8)), cfg)
        state = sac.init(jax.random.PRNGKey(1), hyper_of(TrainConfig(ma=cfg)))
        losses[placement] = float(sac.critic_step(state, batch, key)[1]["critic_loss"])
        pen = sac.regularizer.next_value_penalty(
            state.actor_params, batch.next_obs, key, alpha=state.hyper["alpha"]
        )
        if placement == "entropy":
            exact = 5.0 * ma.feedback_exact(sac.control, state.actor_params, batch.next_obs)
            np.testing.assert_allclose(pen, exact, rtol=1e-5)
            assert float(jnp.min(pen)) > 0
        else:
            assert float(jnp.max(jnp.abs(pen))) == 0.0
    assert losses["entropy"] != losses["actor_loss"]
    with pytest.raises(ValueError, match="parameter reading"):
        ma.MAConfig(alpha=1.0, placement="entropy", temporal="rollout")

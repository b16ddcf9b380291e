"""The MA penalty against analytic answers and finite differences."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from minatt_jax import min_attention as ma


def linear(params, x):
    return params["W"] @ x + params["b"]


def tanh_linear(params, x):
    return jnp.tanh(params["W"] @ x + params["b"])


@pytest.fixture
def problem():
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(0), 3)
    params = {"W": 0.5 * jax.random.normal(k1, (3, 5)), "b": 0.1 * jax.random.normal(k2, (3,))}
    obs = jax.random.normal(k3, (32, 5))
    return params, obs


def analytic_feedback(u, params, obs):
    if u is linear:
        return float(jnp.sum(params["W"] ** 2))
    pre = obs @ params["W"].T + params["b"]  # (n, 3)
    jac = (1 - jnp.tanh(pre) ** 2)[:, :, None] * params["W"][None]  # (n, 3, 5)
    return float(jnp.mean(jnp.sum(jac**2, axis=(1, 2))))


@pytest.mark.parametrize("u", [linear, tanh_linear])
@pytest.mark.parametrize("estimator", ["jacfwd", "jacrev"])
def test_exact_feedback_matches_analytic(problem, u, estimator):
    params, obs = problem
    cfg = ma.MAConfig(alpha=1.0, estimator=estimator, subsample=0)
    value = ma.feedback_term(cfg, u, params, obs, jax.random.PRNGKey(1))
    assert float(value) == pytest.approx(analytic_feedback(u, params, obs), rel=1e-5)


@pytest.mark.parametrize("u", [linear, tanh_linear])
def test_hutchinson_is_unbiased(problem, u):
    params, obs = problem
    cfg = ma.MAConfig(alpha=1.0, estimator="hutchinson", probes=1, subsample=0)
    estimates = jax.vmap(lambda k: ma.feedback_term(cfg, u, params, obs, k))(
        jax.random.split(jax.random.PRNGKey(2), 4000)
    )
    exact = analytic_feedback(u, params, obs)
    standard_error = float(jnp.std(estimates)) / np.sqrt(estimates.shape[0])
    assert abs(float(jnp.mean(estimates)) - exact) < 4 * standard_error + 1e-6
    assert float(jnp.std(estimates)) > 0  # it is a stochastic estimate


def test_subsample_uses_the_leading_states(problem):
    params, obs = problem
    cfg = ma.MAConfig(alpha=1.0, estimator="jacfwd", subsample=4)
    value = ma.feedback_term(cfg, tanh_linear, params, obs, jax.random.PRNGKey(0))
    assert float(value) == pytest.approx(analytic_feedback(tanh_linear, params, obs[:4]), rel=1e-5)
    assert float(value) != pytest.approx(analytic_feedback(tanh_linear, params, obs), rel=1e-3)
    # Both terms of the penalty see the same leading states.
    prev = jax.tree.map(lambda x: x - 0.05, params)
    full = ma.MAConfig(alpha=1.0, estimator="jacfwd", subsample=0)
    key = jax.random.PRNGKey(0)
    _, sub_parts = ma.penalty(cfg, tanh_linear, params, obs, key, prev_params=prev, alpha=cfg.alpha)
    _, head_parts = ma.penalty(
        full, tanh_linear, params, obs[:4], key, prev_params=prev, alpha=full.alpha
    )
    for name in ("feedback", "temporal"):
        assert float(sub_parts[name]) == pytest.approx(float(head_parts[name]), rel=1e-6)


def test_temporal_parameter_reading(problem):
    params, obs = problem
    assert float(ma.temporal_parameter(linear, params, params, obs)) == 0.0
    delta = 0.01 * jnp.ones((3, 5))
    moved = {**params, "W": params["W"] + delta}
    dt = 0.5
    expected = float(jnp.mean(jnp.sum((obs @ delta.T / dt) ** 2, axis=-1)))
    value = ma.temporal_parameter(linear, moved, params, obs, dt)
    assert float(value) == pytest.approx(expected, rel=1e-5)
    # The previous parameters are held fixed: no gradient reaches them.
    g_prev = jax.grad(lambda p: ma.temporal_parameter(linear, moved, p, obs, dt))(params)
    assert float(jnp.max(jnp.abs(g_prev["W"]))) == 0.0


def test_temporal_rollout_reading(problem):
    params, obs = problem
    next_obs = obs + 0.1
    expected = float(jnp.mean(jnp.sum((0.1 * params["W"].sum(1)) ** 2) / 0.05**2))
    value = ma.temporal_rollout(linear, params, obs, next_obs, dt=0.05)
    assert float(value) == pytest.approx(expected, rel=1e-4)


def test_penalty_gradient_matches_finite_differences(problem):
    params, obs = problem
    prev = jax.tree.map(lambda x: x - 0.05, params)
    cfg = ma.MAConfig(alpha=0.7, mode="full", estimator="jacfwd", subsample=0)

    def f(w):
        p = {**params, "W": w}
        return ma.penalty(
            cfg, tanh_linear, p, obs, jax.random.PRNGKey(0), prev_params=prev, alpha=cfg.alpha
        )[0]

    w = params["W"].astype(jnp.float64) if jax.config.jax_enable_x64 else params["W"]
    grad = jax.grad(f)(w)
    eps = 1e-2
    for i, j in [(0, 0), (1, 3), (2, 4)]:
        e = jnp.zeros_like(w).at[i, j].set(eps)
        fd = (f(w + e) - f(w - e)) / (2 * eps)
        assert float(grad[i, j]) == pytest.approx(float(fd), rel=2e-2, abs=1e-4)


def test_modes_select_terms(problem):
    params, obs = problem
    prev = jax.tree.map(lambda x: x - 0.05, params)
    key = jax.random.PRNGKey(0)
    parts = {}
    for mode in ma.MODES:
        cfg = ma.MAConfig(alpha=1.0, mode=mode, estimator="jacfwd", subsample=0)
        total, parts[mode] = ma.penalty(
            cfg, tanh_linear, params, obs, key, prev_params=prev, alpha=cfg.alpha
        )
    assert float(parts["none"]["penalty"]) == 0.0
    assert float(parts["jacobian"]["temporal"]) == 0.0
    assert float(parts["temporal"]["feedback"]) == 0.0
    full = parts["jacobian"]["penalty"] + parts["temporal"]["penalty"]
    assert float(parts["full"]["penalty"]) == pytest.approx(float(full), rel=1e-6)
    zero_alpha = ma.MAConfig(alpha=0.0, estimator="jacfwd")
    assert (
        float(
            ma.penalty(
                zero_alpha, tanh_linear, params, obs, key, prev_params=prev, alpha=zero_alpha.alpha
            )[0]
        )
        == 0
    )


def test_interval_keeps_a_gradient_with_scaled_weight(problem):
    params, obs = problem
    key = jax.random.PRNGKey(0)
    every = ma.MAConfig(alpha=0.5, mode="jacobian", estimator="jacfwd", subsample=0)
    sparse = ma.MAConfig(alpha=0.5, mode="jacobian", estimator="jacfwd", subsample=0, interval=10)

    def loss(cfg, p, step):
        return ma.penalty(cfg, tanh_linear, p, obs, key, update_step=step, alpha=cfg.alpha)[0]

    g_every = jax.grad(lambda p: loss(every, p, 0))(params)["W"]
    g_due = jax.jit(jax.grad(lambda p, s: loss(sparse, p, s)))(params, 20)["W"]
    g_off = jax.jit(jax.grad(lambda p, s: loss(sparse, p, s)))(params, 21)["W"]
    np.testing.assert_allclose(g_due, 10 * g_every, rtol=1e-5)
    assert float(jnp.max(jnp.abs(g_off))) == 0.0


def test_a_skipped_update_fills_no_per_state_residuals(problem):
    """Differentiated, each thinned term's ``cond`` returns what its backward pass needs; the
    skipping branch fills it with zeros. The term is rematerialized, so that is at most its
    inputs (parameters, previous parameters, states), not the Jacobian's states x outputs x
    inputs intermediates (1,546 numbers here without it, against a bound of 198)."""
    params, obs = problem
    prev = jax.tree.map(lambda x: x - 0.05, params)
    cfg = ma.MAConfig(alpha=0.5, mode="full", estimator="jacfwd", subsample=0, interval=10,
                      interval_terms="both")  # fmt: skip

    def loss(p, step):
        return ma.penalty(cfg, tanh_linear, p, obs, jax.random.PRNGKey(0), prev_params=prev,
                          update_step=step, alpha=cfg.alpha)[0]  # fmt: skip

    jaxpr = jax.make_jaxpr(jax.grad(loss))(params, 3).jaxpr
    conds = [e for e in jaxpr.eqns if e.primitive.name == "cond"]
    assert len(conds) == 4  # two terms: each a forward cond and its transpose
    n_params = sum(x.size for x in jax.tree.leaves(params))
    bound = 2 * n_params + obs.size + 2
    for eqn in conds:
        assert sum(int(np.prod(v.aval.shape)) for v in eqn.outvars) <= bound


def test_caps_penalty(problem):
    params, obs = problem
    cfg = ma.CAPSConfig(lambda_t=1.0, lambda_s=0.0, sigma=0.2)
    total, parts = ma.caps_penalty(cfg, linear, params, obs, obs, jax.random.PRNGKey(0))
    assert float(total) == pytest.approx(0.0, abs=1e-5)
    cfg = ma.CAPSConfig(lambda_t=0.0, lambda_s=1.0, sigma=0.0)
    total, _ = ma.caps_penalty(cfg, linear, params, obs, obs + 1.0, jax.random.PRNGKey(0))
    assert float(total) == pytest.approx(0.0, abs=1e-5)
    cfg = ma.CAPSConfig(lambda_t=2.0)
    total, parts = ma.caps_penalty(cfg, linear, params, obs, obs + 1.0, jax.random.PRNGKey(0))
    expected = 2.0 * float(jnp.linalg.norm(params["W"].sum(1)))
    assert float(total) == pytest.approx(expected, rel=1e-4)


def test_invalid_config_is_rejected():
    with pytest.raises(ValueError, match="estimator"):
        ma.MAConfig(estimator="magic")
    with pytest.raises(ValueError, match="alpha"):
        ma.MAConfig(alpha=-1.0)


def test_per_state_penalty_matches_the_batch_penalty(problem):
    """The reward-shaping placement's per-state values average to the actor-loss penalty."""
    params, obs = problem
    prev = jax.tree.map(lambda x: x - 0.05, params)
    cfg = ma.MAConfig(alpha=0.3, estimator="jacfwd", subsample=0)
    key = jax.random.PRNGKey(0)
    per_state = ma.per_state_penalty(
        cfg, tanh_linear, params, obs, key, prev_params=prev, alpha=cfg.alpha
    )
    total, _ = ma.penalty(cfg, tanh_linear, params, obs, key, prev_params=prev, alpha=cfg.alpha)
    assert per_state.shape == (obs.shape[0],)
    assert float(jnp.mean(per_state)) == pytest.approx(float(total), rel=1e-5)


def test_the_whole_attention_cost_can_be_thinned(problem):
    """interval_terms="both": the temporal term too runs on every 10th update only, weighted
    10x there, and is skipped (zero, no gradient) between; "feedback" leaves it every update."""
    params, obs = problem
    prev = jax.tree.map(lambda x: x + 0.05, params)
    key = jax.random.PRNGKey(0)
    every = ma.MAConfig(alpha=0.5, mode="temporal", estimator="jacfwd", subsample=0)
    both = ma.MAConfig(alpha=0.5, mode="full", estimator="jacfwd", subsample=0, interval=10,
                       interval_terms="both")  # fmt: skip
    jacobian_only = dataclasses.replace(both, interval_terms="feedback")

    def parts(cfg, step):
        return jax.jit(lambda s: ma.penalty(cfg, tanh_linear, params, obs, key, prev_params=prev,
                                            update_step=s, alpha=cfg.alpha)[1])(step)  # fmt: skip

    temporal = float(parts(every, 0)["temporal"])
    assert temporal > 0
    assert float(parts(both, 20)["temporal"]) == pytest.approx(temporal, rel=1e-6)
    assert float(parts(both, 21)["temporal"]) == 0.0 and float(parts(both, 21)["penalty"]) == 0.0
    assert float(parts(jacobian_only, 21)["temporal"]) == pytest.approx(temporal, rel=1e-6)

    def grad(cfg, step):
        def loss(p):
            return ma.penalty(cfg, tanh_linear, p, obs, key, prev_params=prev, update_step=step,
                              alpha=cfg.alpha)[0]  # fmt: skip

        return jax.grad(loss)(params)["W"]

    only_temporal = dataclasses.replace(both, mode="temporal")
    np.testing.assert_allclose(grad(only_temporal, 20), 10 * grad(every, 0), rtol=1e-5)
    assert float(jnp.max(jnp.abs(grad(only_temporal, 21)))) == 0.0

"""The MAML meta step: its gradient is the derivative of the post-inner-step objective."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from minatt_jax.maml import Trajectories, make_meta_step
from minatt_jax.min_attention import MAConfig
from minatt_jax.replay import Transitions
from minatt_jax.sac import SACConfig, make_sac

OBS, ACT, TASKS, BATCH = 3, 2, 2, 6


def _hyper(alpha, inner_lr):
    """The learner's hyper values: the inner step size beta lives there (no default)."""
    return {"alpha": alpha, "ma_terms": np.ones(2, np.float32), "actor_lr": 3e-4,
            "critic_lr": 3e-4, "entropy_lr": 3e-4, "inner_lr": inner_lr}  # fmt: skip


def _setup(inner_lr, first_order, inner="sac", x64=True):
    sac = make_sac(OBS, ACT, SACConfig(hidden=(8, 8)), MAConfig(alpha=1.0, subsample=0))
    agent = sac.init(jax.random.PRNGKey(0), _hyper(1.0, inner_lr))
    if x64:
        agent = jax.tree.map(
            lambda x: x.astype(jnp.float64) if x.dtype == jnp.float32 else x, agent
        )
    meta = make_meta_step(sac, first_order, inner=inner)
    rng = np.random.default_rng(0)

    def batch(shape):
        return Transitions(
            obs=jnp.asarray(rng.normal(size=(*shape, OBS))),
            action=jnp.asarray(rng.uniform(-1, 1, (*shape, ACT))),
            reward=jnp.asarray(rng.normal(size=shape)),
            next_obs=jnp.asarray(rng.normal(size=(*shape, OBS))),
            terminal=jnp.zeros(shape),
        )

    supports = batch((TASKS, BATCH))
    if inner == "vpg":  # trajectories (tasks, steps, n): 4 steps, the last one dead
        data = batch((TASKS, 4, BATCH))
        supports = Trajectories(data, jnp.ones((TASKS, 4, BATCH)).at[:, 3, ::2].set(0.0))
    return sac, agent, meta, supports, batch((TASKS, BATCH))


def _task(tree, i):
    return jax.tree.map(lambda x: x[i], tree)


def _flat(tree):
    return jnp.concatenate([x.ravel() for x in jax.tree.leaves(tree)])


@pytest.mark.parametrize("inner", ["sac", pytest.param("vpg", marks=pytest.mark.extended)])
def test_meta_gradient_matches_finite_difference_and_first_order_differs(inner):
    with jax.enable_x64(True):
        key = jax.random.PRNGKey(3)
        sac, agent, meta, supports, queries = _setup(0.3, False, inner)

        def objective(params):
            return meta.meta_loss(params, agent, supports, queries, key)[0]

        grad = jax.grad(objective)(agent.actor_params)
        direction = jax.tree.map(
            lambda x: jax.random.normal(jax.random.PRNGKey(x.size), x.shape, x.dtype),
            agent.actor_params,
        )
        eps = 1e-6
        plus = jax.tree.map(lambda p, d: p + eps * d, agent.actor_params, direction)
        minus = jax.tree.map(lambda p, d: p - eps * d, agent.actor_params, direction)
        fd = (objective(plus) - objective(minus)) / (2 * eps)
        analytic = jnp.dot(_flat(grad), _flat(direction))
        np.testing.assert_allclose(float(analytic), float(fd), rtol=1e-5)

        # First order: the mean of the tasks' gradients at their adapted parameters.
        _, _, fo_meta, _, _ = _setup(0.3, True, inner)
        fo_grad = jax.grad(lambda p: fo_meta.meta_loss(p, agent, supports, queries, key)[0])(
            agent.actor_params
        )
        keys = jax.random.split(key, TASKS)
        by_hand = []
        for i in range(TASKS):
            k_in, k_out = jax.random.split(keys[i])
            adapted, _ = meta.adapt(agent.actor_params, agent, _task(supports, i), k_in)
            query_grad = jax.grad(lambda p, q, k: sac.actor_loss(p, agent, q, k)[0])
            by_hand.append(_flat(query_grad(adapted, _task(queries, i), k_out)))
        np.testing.assert_allclose(_flat(fo_grad), np.mean(by_hand, axis=0), rtol=1e-6, atol=1e-9)
        # ...which differs from the exact (second-order) meta-gradient.
        gap = jnp.linalg.norm(_flat(fo_grad) - _flat(grad)) / jnp.linalg.norm(_flat(grad))
        assert float(gap) > 1e-3


def test_zero_inner_step_is_plain_sac_actor_gradient():
    with jax.enable_x64(True):
        key = jax.random.PRNGKey(4)
        sac, agent, meta, supports, queries = _setup(inner_lr=0.0, first_order=False)
        loss, aux = meta.meta_loss(agent.actor_params, agent, supports, queries, key)
        keys = jax.random.split(key, TASKS)
        plain = [
            sac.actor_loss(agent.actor_params, agent, _task(queries, i),
                           jax.random.split(keys[i])[1])[0]
            for i in range(TASKS)
        ]  # fmt: skip
        np.testing.assert_allclose(float(loss), float(np.mean(plain)), rtol=1e-10)
        assert float(aux["meta_outer_loss"]) == float(loss)


def test_vpg_inner_step_raises_the_imagined_return():
    """A one-step bandit, reward = first action: the adapted policy's mean action rises."""
    sac = make_sac(OBS, ACT, SACConfig(hidden=(16, 16)), MAConfig(alpha=0.0))
    agent = sac.init(jax.random.PRNGKey(0), _hyper(0.0, 0.05))
    meta = make_meta_step(sac, inner="vpg")
    obs = jax.random.normal(jax.random.PRNGKey(1), (1, 512, OBS))
    action = jax.vmap(sac.sample, in_axes=(None, 0, 0))(
        agent.actor_params, obs, jax.random.split(jax.random.PRNGKey(2), 1)
    )
    data = Transitions(obs=obs, action=action, reward=action[..., 0], next_obs=obs,
                       terminal=jnp.zeros((1, 512)))  # fmt: skip
    adapted, _ = meta.adapt(agent.actor_params, agent, Trajectories(data, jnp.ones((1, 512))),
                            jax.random.PRNGKey(3))  # fmt: skip
    before = jnp.mean(sac.control(agent.actor_params, obs[0])[:, 0])
    after = jnp.mean(sac.control(adapted, obs[0])[:, 0])
    other_before = jnp.mean(sac.control(agent.actor_params, obs[0])[:, 1])
    other_after = jnp.mean(sac.control(adapted, obs[0])[:, 1])
    assert float(after - before) > 0.02
    assert abs(float(other_after - other_before)) < 0.5 * float(after - before)


def test_trpo_outer_step_stays_in_the_trust_region():
    sac = make_sac(OBS, ACT, SACConfig(hidden=(8, 8)), MAConfig(alpha=1.0, subsample=0))
    agent = sac.init(jax.random.PRNGKey(0), _hyper(1.0, 0.1))
    _, _, _, supports, queries = _setup(0.1, False, x64=False)
    supports, queries = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), (supports, queries))
    meta = make_meta_step(sac, outer="trpo", max_kl=0.005)
    critic_batch = _task(queries, 0)
    key = jax.random.PRNGKey(5)
    before = meta.meta_loss(agent.actor_params, agent, supports, queries, jax.random.split(key)[1])
    new_agent, _, metrics = jax.jit(meta.update)(agent, critic_batch, supports, queries, key)
    assert float(metrics["trpo_accepted"]) == 1.0
    assert 0 < float(metrics["trpo_kl"]) <= 0.005 * 1.001
    # The actor moved without Adam (its optimizer state is untouched) and the objective fell
    # (same critic as the line search saw: the critic step comes first).
    assert _flat(new_agent.actor_params).shape == _flat(agent.actor_params).shape
    assert float(jnp.max(jnp.abs(_flat(new_agent.actor_params) - _flat(agent.actor_params)))) > 0
    moved = agent.replace(critic_params=new_agent.critic_params)
    k_actor = jax.random.split(key)[1]
    old_obj = meta.meta_loss(agent.actor_params, moved, supports, queries, k_actor)[0]
    new_obj = meta.meta_loss(new_agent.actor_params, moved, supports, queries, k_actor)[0]
    assert float(new_obj) < float(old_obj)
    del before


def test_the_inner_step_size_cannot_default():
    """beta lives in the learner's hyper values alone: a learner built without it cannot adapt
    (no silent beta = 0), and the training program refuses hyper values that lack it."""
    from minatt_jax.agents import registry
    from minatt_jax.agents.base import check_hyper

    sac = make_sac(OBS, ACT, SACConfig(hidden=(8, 8)), MAConfig(alpha=1.0, subsample=0))
    hyper = _hyper(1.0, 0.1)
    del hyper["inner_lr"]
    agent = sac.init(jax.random.PRNGKey(0), hyper)
    _, _, meta, supports, _ = _setup(0.1, False, x64=False)
    with pytest.raises(KeyError, match="inner_lr"):
        meta.adapt(agent.actor_params, agent, _task(supports, 0), jax.random.PRNGKey(1))
    with pytest.raises(ValueError, match="missing inner_lr"):
        check_hyper(registry.get("mbmpo"), hyper)
    check_hyper(registry.get("mbmpo"), _hyper(1.0, 0.1))  # complete: accepted

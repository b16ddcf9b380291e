"""The MAML meta step: its gradient is the derivative of the post-inner-step objective."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from minatt_jax.config import SACConfig
from minatt_jax.maml import make_meta_step
from minatt_jax.min_attention import MAConfig
from minatt_jax.replay import Transitions
from minatt_jax.sac import make_sac

OBS, ACT, TASKS, BATCH = 3, 2, 2, 6


def _setup(inner_lr, first_order):
    sac = make_sac(OBS, ACT, SACConfig(hidden=(8, 8)), MAConfig(alpha=1.0, subsample=0))
    agent = sac.init(jax.random.PRNGKey(0))
    agent = jax.tree.map(lambda x: x.astype(jnp.float64) if x.dtype == jnp.float32 else x, agent)
    meta = make_meta_step(sac, inner_lr, first_order)
    rng = np.random.default_rng(0)

    def batch(shape):
        return Transitions(
            obs=jnp.asarray(rng.normal(size=(*shape, OBS))),
            action=jnp.asarray(rng.uniform(-1, 1, (*shape, ACT))),
            reward=jnp.asarray(rng.normal(size=shape)),
            next_obs=jnp.asarray(rng.normal(size=(*shape, OBS))),
            terminal=jnp.zeros(shape),
        )

    return sac, agent, meta, batch((TASKS, BATCH)), batch((TASKS, BATCH))


def _task(tree, i):
    return jax.tree.map(lambda x: x[i], tree)


def _flat(tree):
    return jnp.concatenate([x.ravel() for x in jax.tree.leaves(tree)])


def test_meta_gradient_matches_finite_difference_and_first_order_differs():
    with jax.enable_x64(True):
        key = jax.random.PRNGKey(3)
        sac, agent, meta, supports, queries = _setup(inner_lr=0.3, first_order=False)

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
        _, _, fo_meta, _, _ = _setup(inner_lr=0.3, first_order=True)
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

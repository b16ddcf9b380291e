"""PPO with minimum attention (``agents/ppo.py``): the GAE against a hand-worked trajectory, the
clipped objective against numpy, MA's gradient reaching the policy, one program for seeds,
swept values and tasks, and a smoke population that resumes exactly."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from minatt_jax import runner
from minatt_jax.agents import ppo
from minatt_jax.config import PRESETS, resolve, with_overrides
from minatt_jax.training import hyper_of, make_train

SMOKE = resolve(with_overrides(PRESETS["smoke"], algo="ppo", env="point_robot_dense"))


def test_gae_equals_the_hand_worked_trajectory():
    """Three steps, gamma 0.9, lambda 0.8: an episode that terminates at the last step, and one
    cut by its time limit after the second (bootstrapped, no advantage passed back)."""
    rewards = jnp.asarray([1.0, 2.0, 3.0])
    values = jnp.asarray([0.5, 1.0, 1.5])
    next_values = jnp.asarray([1.0, 1.5, 2.0])
    terminal = jnp.asarray([0.0, 0.0, 1.0])
    adv, target = ppo.gae(rewards, values, next_values, terminal, terminal, 0.9, 0.8)
    # delta = (1 + .9 - .5, 2 + .9 * 1.5 - 1, 3 - 1.5) = (1.4, 2.35, 1.5); A = delta + .72 A'
    np.testing.assert_allclose(adv, [1.4 + 0.72 * (2.35 + 0.72 * 1.5), 2.35 + 0.72 * 1.5, 1.5],
                               rtol=1e-6)  # fmt: skip
    np.testing.assert_allclose(target, np.asarray(adv) + np.asarray(values), rtol=1e-6)
    cut = jnp.asarray([0.0, 1.0, 0.0])  # time limit after step 1: no terminal, A restarts
    adv, _ = ppo.gae(rewards, values, next_values, jnp.zeros(3), cut, 0.9, 0.8)
    np.testing.assert_allclose(adv, [1.4 + 0.72 * 2.35, 2.35, 3 + 0.9 * 2.0 - 1.5], rtol=1e-6)
    # Batched over environments (time-major): each column is its own trajectory.
    both, _ = ppo.gae(jnp.stack([rewards, rewards], 1), jnp.stack([values, values], 1),
                      jnp.stack([next_values, next_values], 1), jnp.stack([terminal] * 2, 1),
                      jnp.stack([terminal, cut], 1), 0.9, 0.8)  # fmt: skip
    np.testing.assert_allclose(both[:, 1], [1.4 + 0.72 * 2.35, 2.35, 1.5], rtol=1e-6)


def test_the_clipped_objective_equals_numpy():
    rng = np.random.default_rng(0)
    new, old = rng.normal(size=64), rng.normal(size=64)
    adv = rng.normal(size=64)
    loss, clipped = ppo.clipped_surrogate(jnp.asarray(new), jnp.asarray(old), jnp.asarray(adv), 0.2)
    ratio = np.exp(new - old)
    expected = -np.minimum(ratio * adv, np.clip(ratio, 0.8, 1.2) * adv)
    np.testing.assert_allclose(loss, expected, rtol=1e-5)
    np.testing.assert_array_equal(clipped, np.abs(ratio - 1) > 0.2)


def _batch(obs_dim: int, act_dim: int, n: int = 16) -> ppo.Batch:
    k = jax.random.split(jax.random.PRNGKey(3), 5)
    return ppo.Batch(jax.random.normal(k[0], (n, obs_dim)), jax.random.normal(k[1], (n, obs_dim)),
                     jax.random.normal(k[2], (n, act_dim)), jax.random.normal(k[3], (n,)) - 3,
                     jax.random.normal(k[4], (n,)), jnp.zeros((n,)), jnp.ones((n,)))  # fmt: skip


def test_the_ma_penalty_reaches_the_policy_gradient():
    """With alpha > 0 the minibatch step moves the policy differently from alpha 0 (the value
    network's step is the same) and reports the penalty; alpha is data in one compiled step."""
    config = resolve(with_overrides(SMOKE, ma_alpha=1.0))
    lrn = ppo.learning(config, 2, 2)
    batch, key = _batch(2, 2), jax.random.PRNGKey(1)
    step = jax.jit(lrn.step)
    moved = {}
    for alpha in (0.0, 5.0):
        learner = lrn.init(jax.random.PRNGKey(0), {**hyper_of(config), "alpha": alpha})
        after, metrics = step(learner, batch, key)
        moved[alpha] = after.params
        assert (float(metrics["ma_penalty"]) > 0) == (alpha > 0)
    assert step._cache_size() == 1
    policy = jax.tree.leaves(
        jax.tree.map(
            lambda a, b: float(jnp.max(jnp.abs(a - b))), moved[0.0]["policy"], moved[5.0]["policy"]
        )
    )
    value = jax.tree.leaves(
        jax.tree.map(
            lambda a, b: float(jnp.max(jnp.abs(a - b))), moved[0.0]["value"], moved[5.0]["value"]
        )
    )
    assert max(policy) > 0 and max(value) == 0
    # The penalty's own gradient: the feedback term of u = tanh(mean(x)) pulls on the policy.
    learner = lrn.init(jax.random.PRNGKey(0), hyper_of(config))

    def penalty(params):
        return lrn.regularizer.actor_penalty(params, batch.obs, batch.next_obs, (key, key),
                                             learner.prev_policy, 0, alpha=1.0)[0]  # fmt: skip

    grads = jax.grad(penalty)(learner.params["policy"])
    assert max(float(jnp.max(jnp.abs(g))) for g in jax.tree.leaves(grads)) > 0


@pytest.mark.slow
def test_seeds_swept_values_and_tasks_share_one_program_and_ppo_learns_the_point_robot():
    """One compiled chunk for another seed, another alpha and learning rate, and tasks drawn at
    resets from a task set; the return improves on the dense point robot."""
    config = resolve(with_overrides(SMOKE, task_set="train", total_steps=3200, eval_every=640,
                                    ma_alpha=0.1))  # fmt: skip
    trainer = make_train(config)
    state = trainer.init(jax.random.PRNGKey(0), hyper_of(config))
    first = trainer.evaluate(state, jax.random.PRNGKey(1), trainer.task_set)
    goals = set()
    for _ in range(5):
        state, metrics = trainer.train_chunk(state)
        goals |= {round(float(t), 3) for t in state.env_state.info["task"].target}
    assert len(goals) > 1  # goals from the train set were drawn at resets
    assert float(metrics["updates"]) == 10 * config.ppo.epochs * config.ppo.minibatches
    assert float(metrics["ma_penalty"]) > 0 and np.isfinite(float(metrics["value_loss"]))
    last = trainer.evaluate(state, jax.random.PRNGKey(1), trainer.task_set)
    assert float(np.mean(last.metrics["return"])) > float(np.mean(first.metrics["return"]))
    other = with_overrides(config, ma_alpha=0.0, ppo_lr=1e-3, ppo_entropy_cost=0.0, seed=3)
    trainer.train_chunk(trainer.init(jax.random.PRNGKey(3), hyper_of(other)))
    assert trainer.train_chunk._cache_size() == 1


@pytest.mark.slow
def test_a_ppo_population_resumes_exactly_and_exports_its_policy(tmp_path, capsys):
    from conftest import run_cli

    from minatt_jax.numpy_policy import load_policy

    argv = ["train", "--algo", "ppo", "--env", "point_robot_dense", "--preset", "smoke",
            "--seeds", "0", "--sweep", "ma.alpha=0,0.5"]  # fmt: skip
    whole, split = str(tmp_path / "whole"), str(tmp_path / "split")
    status, out = run_cli([*argv, "--out", whole], capsys)
    assert status == 0 and "2 members in 1 compiled program(s)" in out.out
    assert run_cli([*argv, "--steps", "320", "--out", split], capsys)[0] == 0
    assert run_cli(["train", "--out", split, "--resume", "--steps", "640"], capsys)[0] == 0
    for name in ("ppo_alpha0_seed0", "ppo_alpha0.5_seed0"):
        a = runner.without_timings(runner.read_metrics(f"{whole}/{name}"))
        b = runner.without_timings(runner.read_metrics(f"{split}/{name}"))
        assert len(a) == 2 and a == b, name
    assert a[-1]["ma_penalty"] > 0
    out = str(tmp_path / "ppo.npz")
    assert run_cli(["export", f"{whole}/ppo_alpha0.5_seed0", "--out", out], capsys)[0] == 0
    from minatt_jax import checkpoint

    policy = checkpoint.load_policy(f"{whole}/ppo_alpha0.5_seed0")
    exported = load_policy(out)
    obs = np.random.default_rng(0).normal(size=(8, exported.obs_dim)).astype(np.float32)
    assert exported.metadata["activation"] == "swish" and exported.metadata["normalize_obs"]
    np.testing.assert_allclose(exported(obs), np.stack([policy.control(o) for o in obs]),
                               atol=1e-5)  # fmt: skip

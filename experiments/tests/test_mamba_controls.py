"""The in-context adaptation controls of the MAMBA study: the episode-index views and the memory
reset at every inner episode, on the point robot's meta-episodes."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mamba_point_robot as study
import numpy as np
import pytest

from minatt_jax import acting


@pytest.fixture(scope="module")
def env():
    return study.run_config("mamba", 0.0, 0, None, []).make_env()  # 3 inner episodes


def _unroll(env, policy, seed: int = 0):
    task = env.nominal_task()
    key = jax.random.PRNGKey(seed)
    return jax.jit(lambda k: acting.unroll(env, policy, env.reset(k, task), env.max_steps,
                                           key=k))(key)  # fmt: skip


def test_the_index_views_change_only_the_index_input(env) -> None:
    policy = acting.random_policy(env.action_size)
    plain = _unroll(env, policy)
    index = np.asarray(plain.env_metrics["meta_episode_index"], int)
    assert sorted(set(index)) == [0, 1, 2]
    for mode in ("withheld", "shuffled"):
        traj = _unroll(study.EpisodeIndexView(env, mode), policy)
        shown = np.asarray(traj.obs[:, -1])
        np.testing.assert_array_equal(traj.reward, plain.reward)  # same episodes, same reward
        np.testing.assert_array_equal(traj.obs[:, :-1], plain.obs[:, :-1])
        if mode == "withheld":
            assert np.all(shown == 0.0)
        else:  # one shown index per inner episode, together a permutation of 0, 1/2, 1
            per_episode = [set(shown[index == i]) for i in range(3)]
            assert all(len(s) == 1 for s in per_episode)
            assert sorted(s.pop() for s in per_episode) == [0.0, 0.5, 1.0]
    orders = {tuple(np.asarray(_unroll(study.EpisodeIndexView(env, "shuffled"), policy, seed
                                       ).obs[[0, 60, 120], -1])) for seed in range(12)}  # fmt: skip
    assert len(orders) > 1  # drawn per meta-episode


def _counting_policy(act_dim: int) -> acting.RecurrentPolicy:
    """Memory counts the steps since it was last fresh; the action shows the count."""

    def at(memory):
        def u(x):
            return jnp.full(act_dim, jnp.tanh(memory / 100.0))

        return acting.Policy(act=lambda x, k: u(x), control=u)

    return acting.RecurrentPolicy(jnp.zeros(()), at, lambda m, x, a, k: m + 1.0)


def test_memory_reset_starts_each_inner_episode_afresh(env) -> None:
    policy = _counting_policy(env.action_size)
    first_step = env.observation_size - 2
    carried = _unroll(env, policy)
    reset = _unroll(env, study.reset_each_episode(policy, first_step))
    starts = np.flatnonzero(np.asarray(carried.obs[:, first_step]) > 0.5)
    assert list(starts) == [0, 50, 100]  # 3 episodes of 50 steps, the point robot never ends
    steps_since = np.arange(150) - starts[np.searchsorted(starts, np.arange(150), "right") - 1]
    np.testing.assert_allclose(np.asarray(reset.action[:, 0]), np.tanh(steps_since / 100.0),
                               rtol=1e-6)  # fmt: skip
    np.testing.assert_allclose(np.asarray(carried.action[:, 0]), np.tanh(np.arange(150) / 100.0),
                               rtol=1e-6)  # fmt: skip


def synthetic_summaries(adaptation: list[float], share: list[float], feedback: list[float]):
    """One task set, as trained and memory reset, from given per-seed values."""
    by_condition = {
        condition: {
            "episode_1": study.paired(np.zeros(6)),
            "adaptation": study.paired(np.asarray(adaptation)),
            "feedback_norm": study.paired(np.asarray(feedback)),
            "energy": study.paired(np.ones(6)),
        }
        for condition in ("as trained", "memory reset")
    }
    by_condition[study.SHARE] = study.paired(np.asarray(share))
    return {"train": by_condition}


def test_the_reading_claims_only_what_the_exact_tests_resolve() -> None:
    mixed = [1.0, -1.0, 2.0, -2.0, 0.5, -0.5]  # symmetric: sign-flip p = 1
    rising = [1.0, 2.0, 3.0, 1.5, 2.5, 0.5]  # all 6 above 0: p = 2 / 64
    summaries = {
        "mamba alpha=0": synthetic_summaries(mixed, mixed, [10.0] * 6),
        "mamba alpha=0.05": synthetic_summaries(rising, rising, [1.0, 2, 3, 4, 5, 6]),
    }
    effects = study.ma_effects(summaries)
    assert list(effects) == ["mamba alpha=0.05"]
    feedback = effects["mamba alpha=0.05"]["train"]["feedback_norm"]
    assert feedback["diff"] == pytest.approx(3.5 - 10.0)
    # every MA seed below every plain one: 2 of the C(12, 6) = 924 relabelings are as extreme
    assert feedback["permutation_p"] == pytest.approx(2 / 924)
    random = {"train": {"adaptation": {"mean": 0.0, "ci": [-1.0, 1.0]}}}
    result = {"goals": {"train": 16}, "summaries": summaries, "ma_effects": effects,
              "random_policy": random}  # fmt: skip
    lines = study.reading(result, 3)
    plain = next(line for line in lines if "mamba alpha=0:" in line)
    ma = next(line for line in lines if "mamba alpha=0.05:" in line)
    assert "no adaptation is resolved" in plain and "is not resolved" in plain
    assert "resolved above 0" in ma and "(p 0.0312" in ma and "in-context adaptation" in ma
    # the memory's share resolved without a gain: the memory is relied on, not adapted with
    summaries["mamba alpha=0.05"] = synthetic_summaries(mixed, rising, [1.0, 2, 3, 4, 5, 6])
    relied = next(line for line in study.reading(result, 3) if "mamba alpha=0.05:" in line)
    assert "no adaptation is resolved" in relied and "relies on its memory" in relied
    effect = next(line for line in lines if "minus alpha 0" in line)
    assert "feedback norm -6.5" in effect and "episode 1 +0" in effect
    assert "episode 1 +0 (Welch [nan, nan], p 1, not resolved)" in effect  # equal arms
    assert "feedback norm -6.5 (Welch [-8.46, -4.54], p 0.00216, resolved)" in effect
    adaptation = effects["mamba alpha=0.05"]["train"]["adaptation"]["permutation_p"]
    verdict = "resolved" if adaptation < 0.05 else "not resolved"
    assert f"p {adaptation:.3g}, {verdict})" in effect

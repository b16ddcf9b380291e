"""MAMBA (agents/mamba.py): whole meta-episodes replayed from their starts, the world-model
horizon's schedule and mask, MA's Jacobian by finite differences, the presets, and a run that
trains, resumes exactly, evaluates per inner episode, meta-tests in context and is analyzed."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_jacobian, sequence_batch

from minatt_jax import min_attention as ma
from minatt_jax.agents import mamba
from minatt_jax.dreamer.agent import Batch, Latent, make_agent
from minatt_jax.dreamer.config import DreamerConfig
from minatt_jax.dreamer.replay import SequenceReplay
from minatt_jax.training import hyper_of

TINY = DreamerConfig(deter=16, hidden=8, stoch=4, classes=3, blocks=2, units=16, layers=2,
                     bins=31, batch_size=3, batch_length=12, imag_length=3)  # fmt: skip
SUBSAMPLE = (5, 4)  # MAMBA's head states and imagination starts per sequence
HYPER = {"alpha": jnp.float32(0.05), "ma_terms": jnp.ones(2)}


def test_horizon_mask_grows_linearly_to_the_whole_meta_episode():
    mask = mamba.horizon_mask(300, 50, 1000)
    counts = [int(np.sum(mask(jnp.asarray(s)))) for s in (0, 1, 400, 1000, 5000)]
    # ceil(50 + steps x 250 / 1000), at most the meta-episode (MAMBA's schedule)
    assert counts == [50, 51, 150, 300, 300]
    assert mamba.horizon_mask(300, 0, 0)(jnp.asarray(0)) is None  # the whole sequence
    assert mamba.horizon_mask(300, 300, 0)(jnp.asarray(0)) is None


def test_replayed_sequences_start_where_meta_episodes_start():
    """Two rings of 20 slots, meta-episodes of 5 steps (env 0) and 4 steps (env 1), written
    past the capacity: every sequence of 6 begins at a stored start with 6 steps after it,
    and every such start is drawn."""
    replay = SequenceReplay.create(2, 20, 1, 1)
    for t in range(27):
        first = jnp.asarray([t % 5 == 0, t % 4 == 0], jnp.float32)
        obs = jnp.asarray([[t], [100 + t]], jnp.float32)
        replay = replay.add(Batch(obs, jnp.zeros((2, 1)), jnp.zeros(2), first, jnp.ones(2)))
    batch = jax.jit(lambda k: replay.sample_starts(k, 4000, 6))(jax.random.PRNGKey(0))
    obs = np.asarray(batch.obs[..., 0])
    assert np.all(np.asarray(batch.is_first[:, 0]) == 1)
    assert np.all(np.diff(obs, axis=1) == 1)  # consecutive steps, never across the ring's seam
    starts = {int(s) for s in obs[:, 0]}
    # held: steps 7..26; a start needs 6 steps after it (at most step 21)
    expected = {t for t in range(7, 22) if t % 5 == 0} | {100 + t for t in range(7, 22)
                                                           if t % 4 == 0}  # fmt: skip
    assert starts == expected
    counts = np.asarray([np.sum(obs[:, 0] == s) for s in sorted(expected)])
    assert counts.min() > 0.7 * counts.mean()  # uniform over the stored starts


@pytest.fixture(scope="module")
def agent():
    return make_agent(5, 2, TINY, ma.MAConfig(alpha=0.05), *SUBSAMPLE)


def test_steps_past_the_horizon_change_nothing_in_an_update(agent):
    """With the horizon at 7 of 12 steps, the world-model losses, the drawn head states and
    the imagination starts all lie inside it: what the batch holds after it changes no
    parameter; inside it, it does."""
    state = agent.init(jax.random.PRNGKey(0), HYPER)
    batch = sequence_batch(jax.random.PRNGKey(1), 3, 12)
    valid = jnp.broadcast_to(mamba.horizon_mask(12, 7, 10**9)(jnp.asarray(0)), (3, 12))
    key = jax.random.PRNGKey(2)

    @jax.jit
    def update(state, batch, key, valid):  # two: the learning rate warms up from 0
        state, _ = agent.update(state, batch, key, valid)
        return agent.update(state, batch, key, valid)

    base, metrics = update(state, batch, key, valid)
    later = batch._replace(obs=batch.obs.at[:, 7:].add(3.0), reward=batch.reward.at[:, 7:].set(9))
    same, _ = update(state, later, key, valid)
    for a, b in zip(jax.tree.leaves(base.params), jax.tree.leaves(same.params), strict=True):
        np.testing.assert_array_equal(a, b)
    earlier = batch._replace(obs=batch.obs.at[:, 3].add(3.0))
    moved, _ = update(state, earlier, key, valid)
    assert any(not np.array_equal(a, b) for a, b in zip(
        jax.tree.leaves(base.params["world_model"]),
        jax.tree.leaves(moved.params["world_model"]), strict=True))  # fmt: skip
    assert np.isfinite(float(metrics["wm_loss"])) and float(metrics["ma_penalty"]) > 0


def test_masked_world_model_loss_reads_only_the_horizon_and_all_ones_is_dreamers_loss():
    """Without subsampling: a mask of ones gives DreamerV3's loss; under a 7-step prefix the
    loss does not depend on the steps after it and differs from the whole batch's."""
    agent = make_agent(5, 2, TINY, ma.MAConfig(alpha=0.0))
    params = agent.init(jax.random.PRNGKey(0), HYPER).params["world_model"]
    batch = sequence_batch(jax.random.PRNGKey(1), 3, 12)
    key = jax.random.PRNGKey(4)
    whole, _ = agent.world_model_loss(params, batch, key)
    ones, _ = agent.world_model_loss(params, batch, key, jnp.ones((3, 12)))
    np.testing.assert_allclose(float(ones), float(whole), rtol=1e-6)
    valid = jnp.broadcast_to((jnp.arange(12) < 7).astype(jnp.float32), (3, 12))
    masked, _ = agent.world_model_loss(params, batch, key, valid)
    padded = batch._replace(obs=batch.obs.at[:, 7:].set(5.0), cont=batch.cont.at[:, 7:].set(0))
    again, _ = agent.world_model_loss(params, padded, key, valid)
    assert float(again) == float(masked) and float(masked) != pytest.approx(float(whole))


def test_ma_feedback_norms_match_finite_differences_on_meta_episode_observations(make_env):
    """MAMBA's actor carries DreamerV3's MA: the trained Jacobian (model state) and the
    reported one (the meta-episode's observation: position, previous action, reward, flag,
    index) match central differences."""
    from minatt_jax.envs.meta_episode import MetaEpisode

    env = MetaEpisode(make_env("point_robot"), 3, 10)
    agent = make_agent(
        env.observation_size, env.action_size, TINY, ma.MAConfig(alpha=0.05), *SUBSAMPLE
    )
    state = agent.init(jax.random.PRNGKey(0), HYPER)
    actor = jax.tree.map(lambda w: w + 0.3 * jax.random.normal(jax.random.PRNGKey(1), w.shape),
                         state.params["actor"])  # fmt: skip
    params = {**state.params, "actor": actor}
    latent = Latent(jax.random.normal(jax.random.PRNGKey(2), (TINY.deter,)),
                    jax.nn.one_hot(jnp.asarray([0, 2, 1, 1]), TINY.classes))  # fmt: skip
    feat = jnp.concatenate([latent.deter, latent.stoch.reshape(-1)])
    trained = float(ma.feedback_exact(agent.control, actor, feat[None], "jacrev")[0])
    fd = central_jacobian(lambda s: agent.control(actor, s), feat)
    assert trained == pytest.approx(float(np.sum(fd**2)), rel=2e-2)
    obs = jnp.asarray([0.3, -0.2, 0.5, -0.4, 0.8, 1.0, 0.5])  # x, y, a_prev, reward, flag, index
    assert obs.shape == (env.observation_size,)
    control = lambda o: agent.observation_control(params, latent, o)  # noqa: E731
    np.testing.assert_allclose(jax.jacfwd(control)(obs), central_jacobian(control, obs),
                               rtol=2e-2, atol=1e-4)  # fmt: skip


def test_presets_set_meta_episodes_and_official_settings_under_the_users_overrides():
    from minatt_jax.config import preset_config, resolve

    paper = resolve(preset_config("paper", fields={"algo": "mamba", "env": "humanoid_dir"}))
    assert (paper.meta_episodes, paper.max_episode_steps, paper.total_steps) == (2, 200, 30_000_000)
    assert paper.mamba.wm_horizon_start == 50 and paper.mamba.wm_horizon_full_at == 15_000_000
    assert paper.dreamer.train_ratio == 96.0 and paper.task_set == "train"
    halfcircle = preset_config("paper", fields={"algo": "mamba", "env": "point_robot"})
    assert (halfcircle.meta_episodes, halfcircle.max_episode_steps) == (3, 100)
    assert halfcircle.dreamer.imag_length == 2
    mine = preset_config("cpu", ["meta_episodes=4"], {"algo": "mamba", "env": "point_robot"})
    assert mine.meta_episodes == 4 and mine.max_episode_steps == mamba.CPU["max_episode_steps"]
    # other agents' presets are untouched
    dreamer = preset_config("cpu", fields={"algo": "dreamer", "env": "point_robot"})
    assert dreamer.meta_episodes == 1 and "mamba" not in dreamer.group_names


def test_mamba_refuses_plain_episodes_and_a_replay_without_two_meta_episodes(capsys):
    from conftest import run_cli

    argv = ["train", "--env", "point_robot", "--algo", "mamba", "--preset", "smoke"]
    for extra, words in ((["--set", "meta_episodes=1"], "meta_episodes to 2"),
                         (["--set", "buffer_size=50"], "buffer_size must hold")):  # fmt: skip
        status, out = run_cli([*argv, *extra, "--out", "/nonexistent/run"], capsys)
        assert status == 2 and words in out.err, out.err
        assert len(out.err.strip().splitlines()) == 1


@pytest.mark.slow
def test_a_mamba_run_resumes_exactly_evaluates_per_episode_and_meta_tests_in_context(
    tmp_path, capsys
):
    """``train --algo mamba`` on point_robot (smoke): a run split and resumed equals the
    straight one; ``evaluate`` gives each inner episode's return; ``meta-test`` on the
    out-of-distribution goals takes no gradient step (the curve is flat) and reports the
    in-context curve; ``analyze`` reports each inner episode."""
    from conftest import run_cli, straight_and_resumed

    from minatt_jax import runner

    argv = ["train", "--env", "point_robot", "--algo", "mamba", "--preset", "smoke",
            "--alpha", "0.05"]  # fmt: skip
    a, b = straight_and_resumed(argv, tmp_path, capsys)
    straight = str(tmp_path / "straight")
    assert [r["step"] for r in a] == [300, 600]
    assert runner.without_timings(a) == runner.without_timings(b)
    assert a[-1]["updates"] > 0 and a[-1]["ma_feedback"] > 0
    assert {"return_episode_1", "return_episode_2"} <= set(a[-1])
    status, out = run_cli(["evaluate", straight, "--variant", "ood", "--episodes", "6",
                           "--json"], capsys)  # fmt: skip
    assert status == 0, out.err
    metrics = json.loads(out.out)
    assert metrics["return"] == pytest.approx(
        metrics["return_episode_1"] + metrics["return_episode_2"], abs=1e-4
    )
    status, out = run_cli(["meta-test", straight, "--variant", "ood", "--adapt-steps", "1",
                           "--episodes", "1", "--json"], capsys)  # fmt: skip
    assert status == 0, out.err
    result = json.loads(out.out)
    assert len(result["tasks"]) == 6 and result["algo"] == "mamba"
    for row in result["tasks"]:
        assert row["return_curve"][0] == row["return_curve"][1]  # in context: no gradient step
        assert row["policy_distance_curve"] == [0.0]
        assert len(row["return_by_episode"]) == 2
    report = tmp_path / "report"
    status, out = run_cli(["analyze", straight, "--out", str(report), "--episodes", "2", "--bins",
                           "4", "--grid", "2", "--grid-rollouts", "1", "--grid-steps", "20"],
                          capsys)  # fmt: skip
    assert status == 0, out.err
    tables = json.loads((report / "tables.json").read_text())
    assert [r["episode"] for r in tables["in_context"]] == [1, 2]
    assert tables["in_context"][0]["group"] == "mamba alpha=0.05"
    assert all(r["feedback"] > 0 for r in tables["in_context"])


@pytest.mark.slow
@pytest.mark.extended  # one more compile; DreamerV3's population test covers the program in CI
def test_a_mamba_population_of_seeds_and_alphas_is_one_program():
    """Seeds and alpha are data: four members (2 seeds x alpha 0, 0.05) share one compiled
    chunk, and they train apart."""
    from minatt_jax import population
    from minatt_jax.config import preset_config, resolve

    members = [resolve(preset_config("smoke", fields={
        "algo": "mamba", "env": "point_robot", "seed": s, "ma.alpha": a, "total_steps": 300,
    })) for s in (0, 1) for a in (0.0, 0.05)]  # fmt: skip
    assert population.groups(members) == [[0, 1, 2, 3]]
    program = population.Program(members)
    states, metrics = program.chunk(program.init())
    assert program.chunk._cache_size() == 1
    losses = np.asarray(metrics["actor_loss"])
    assert np.all(np.isfinite(losses)) and len(set(losses.round(7).tolist())) == 4
    penalty = np.asarray(metrics["ma_penalty"])
    assert penalty[0] == 0 and penalty[2] == 0 and penalty[1] > 0 and penalty[3] > 0
    assert hyper_of(members[1])["alpha"] == np.float32(0.05)

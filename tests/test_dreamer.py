"""DreamerV3's parts: symlog and two-hot, KL balance, return normalization, lambda-returns,
straight-through samples, and the MA Jacobians (trained and reported) by finite differences."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_jacobian, sequence_batch

from minatt_jax import min_attention as ma
from minatt_jax.dreamer import distributions as dist
from minatt_jax.dreamer.agent import Latent, make_agent
from minatt_jax.dreamer.config import DreamerConfig
from minatt_jax.dreamer.networks import feature
from minatt_jax.min_attention import MAConfig
from minatt_jax.training import hyper_of

TINY = DreamerConfig(deter=16, hidden=8, stoch=4, classes=3, blocks=2, units=16, layers=2,
                     bins=31, batch_size=3, batch_length=5, imag_length=4)  # fmt: skip


def test_symlog_twohot_round_trip():
    y = jnp.asarray([-300.0, -2.5, -0.1, 0.0, 0.7, 12.0, 5000.0])
    np.testing.assert_allclose(dist.symexp(dist.symlog(y)), y, rtol=1e-5)
    np.testing.assert_allclose(dist.symlog(jnp.asarray([-1.0, 1.0])), [-np.log(2), np.log(2)])
    # Its derivative 1 / (1 + |x|), at 0 too (where sign(x) jumps).
    slopes = jax.vmap(jax.grad(dist.symlog))(jnp.asarray([-3.0, 0.0, 2.0]))
    np.testing.assert_allclose(slopes, [0.25, 1.0, 1 / 3], rtol=1e-6)
    bins = dist.twohot_bins(255)
    target = dist.twohot(y, bins)
    np.testing.assert_allclose(jnp.sum(target, -1), 1.0, rtol=1e-6)
    assert int(jnp.max(jnp.sum(target > 0, -1))) <= 2  # two neighbouring bins at most
    np.testing.assert_allclose(target @ bins, dist.symlog(y), atol=1e-5)  # mean in symlog space
    # A head whose softmax is the two-hot target predicts y back; its loss is the target's
    # entropy there and larger for any other prediction.
    logits = jnp.log(target + 1e-30)
    np.testing.assert_allclose(dist.twohot_mean(logits, bins), y, rtol=1e-4, atol=1e-5)
    best = dist.twohot_loss(logits, y, bins)
    worse = dist.twohot_loss(jnp.log(dist.twohot(y + 1.0, bins) + 1e-30), y, bins)
    assert np.all(np.asarray(worse) > np.asarray(best))


def test_straight_through_sample_has_the_probabilities_gradient():
    logits = jnp.asarray([[0.3, -1.0, 2.0], [0.0, 0.5, -0.5]])
    key = jax.random.PRNGKey(0)
    weights = jnp.asarray([[1.0, 2.0, 3.0], [-1.0, 0.5, 4.0]])
    f = lambda lg: jnp.sum(weights * dist.sample_onehot(key, dist.unimix_probs(lg, 0.01)))  # noqa: E731
    g = lambda lg: jnp.sum(weights * dist.unimix_probs(lg, 0.01))  # noqa: E731
    sample = dist.sample_onehot(key, dist.unimix_probs(logits, 0.01))
    np.testing.assert_allclose(sample, jax.nn.one_hot(jnp.argmax(sample, -1), 3), atol=1e-6)
    np.testing.assert_allclose(jax.grad(f)(logits), jax.grad(g)(logits), rtol=1e-6)
    assert float(jnp.min(dist.unimix_probs(jnp.asarray([50.0, -50.0, -50.0]), 0.01))) >= 0.01 / 3


def test_kl_balance_values_gradients_and_free_nats():
    post = dist.unimix_probs(jnp.asarray([[[2.0, 0.0, -1.0], [0.0, 0.0, 3.0]]]), 0.01)
    prior = dist.unimix_probs(jnp.asarray([[[0.0, 0.0, 0.0], [1.0, -1.0, 0.0]]]), 0.01)
    p, q = np.asarray(post, np.float64), np.asarray(prior, np.float64)
    kl = float(np.sum(p * (np.log(p) - np.log(q))))
    dyn, rep = dist.kl_balance(post, prior, free_nats=0.0)
    assert float(dyn[0]) == pytest.approx(kl, rel=1e-5) and float(rep[0]) == pytest.approx(
        kl, rel=1e-5
    )
    # dyn trains only the prior, rep only the posterior.
    d_post = jax.grad(lambda a: dist.kl_balance(a, prior, 0.0)[0].sum())(post)
    d_prior = jax.grad(lambda b: dist.kl_balance(post, b, 0.0)[1].sum())(prior)
    assert float(jnp.abs(d_post).max()) == 0.0 and float(jnp.abs(d_prior).max()) == 0.0
    assert (
        float(jnp.abs(jax.grad(lambda b: dist.kl_balance(post, b, 0.0)[0].sum())(prior)).max()) > 0
    )
    # Below the free nats both losses are constant: no gradient at all.
    dyn, rep = dist.kl_balance(post, prior, free_nats=kl + 1.0)
    assert float(dyn[0]) == float(rep[0]) == pytest.approx(kl + 1.0)
    flat = jax.grad(lambda a: dist.kl_balance(a, prior, kl + 1.0)[1].sum())(post)
    assert float(jnp.abs(flat).max()) == 0.0


def test_return_normalization_tracks_percentiles_and_never_amplifies():
    returns = jnp.linspace(0.0, 100.0, 1001)  # P5 = 5, P95 = 95
    scale = dist.ReturnScale.create()
    for _ in range(2000):
        scale = dist.update_return_scale(scale, returns, rate=0.01)
    assert float(scale.low) == pytest.approx(5.0, rel=1e-3)
    assert float(scale.high) == pytest.approx(95.0, rel=1e-3)
    assert float(dist.return_normalizer(scale)) == pytest.approx(90.0, rel=1e-3)
    small = dist.ReturnScale.create()
    for _ in range(2000):
        small = dist.update_return_scale(small, 0.01 * returns, rate=0.01)
    assert float(dist.return_normalizer(small)) == 1.0  # spread 0.9 < 1: divided by 1


@pytest.fixture(scope="module")
def agent():
    return make_agent(5, 2, TINY, MAConfig(alpha=0.5))


# The MA weight and the full mode's term weights, as the agent's init takes them.
HYPER = {"alpha": 0.5, "ma_terms": np.ones(2, np.float32)}


def test_lambda_returns_match_a_loop(agent):
    rng = np.random.default_rng(0)
    h = 6
    reward, value = rng.normal(size=(h + 1, 3)), rng.normal(size=(h + 1, 3))
    cont = (rng.uniform(size=(h + 1, 3)) > 0.2).astype(np.float64)
    got = np.asarray(
        agent.lambda_returns(jnp.asarray(reward), jnp.asarray(cont), jnp.asarray(value))
    )
    g, lam = TINY.gamma, TINY.lam
    expect = np.zeros((h, 3))
    nxt = value[h]
    for t in reversed(range(h)):
        nxt = reward[t + 1] + g * cont[t + 1] * ((1 - lam) * value[t + 1] + lam * nxt)
        expect[t] = nxt
    np.testing.assert_allclose(got, expect, rtol=1e-5, atol=1e-6)


def test_ma_jacobians_trained_and_reported_match_finite_differences(agent):
    state = agent.init(jax.random.PRNGKey(0), HYPER)
    # Actor weights away from their small initialization, so the Jacobians are not tiny.
    actor = jax.tree.map(lambda w: w + 0.3 * jax.random.normal(jax.random.PRNGKey(1), w.shape),
                         state.params["actor"])  # fmt: skip
    params = {**state.params, "actor": actor}
    key = jax.random.PRNGKey(2)
    latent = Latent(jax.random.normal(key, (TINY.deter,)),
                    jax.nn.one_hot(jnp.asarray([0, 2, 1, 1]), TINY.classes))  # fmt: skip
    feat = feature(latent.deter, latent.stoch)
    # Trained: ||d tanh(mean) / d s||_F^2 at the model state s the actor reads.
    from minatt_jax import min_attention as ma

    trained = float(ma.feedback_exact(agent.control, actor, feat[None], "jacrev")[0])
    fd = central_jacobian(lambda s: agent.control(actor, s), feat)
    assert trained == pytest.approx(float(np.sum(fd**2)), rel=2e-2)
    # Reported: with respect to the observation, through the encoder and the posterior.
    obs = jnp.asarray([0.3, -0.2, 1.5, 0.0, -0.7])
    jac = jax.jacfwd(lambda o: agent.observation_control(params, latent, o))(obs)
    fd_obs = central_jacobian(lambda o: agent.observation_control(params, latent, o), obs)
    np.testing.assert_allclose(jac, fd_obs, rtol=2e-2, atol=1e-4)
    assert float(jnp.sum(jac**2)) > 1e-6


def test_update_changes_every_module_and_ma_off_is_exactly_no_penalty(agent):
    state = agent.init(jax.random.PRNGKey(0), HYPER)
    batch = sequence_batch(jax.random.PRNGKey(3), TINY.batch_size, TINY.batch_length)
    update = jax.jit(agent.update)
    # The learning rate warms up from 0: the first update moves nothing, the second does.
    state, _ = update(state, batch, jax.random.PRNGKey(5))
    new, metrics = update(state, batch, jax.random.PRNGKey(4))
    for name in ("world_model", "actor", "critic"):
        before, after = jax.tree.leaves(state.params[name]), jax.tree.leaves(new.params[name])
        assert any(float(jnp.abs(a - b).max()) > 0 for a, b in zip(before, after, strict=True))
    assert all(np.isfinite(float(v)) for v in metrics.values())
    assert float(metrics["ma_feedback"]) > 0 and int(new.updates) == 2
    # alpha is data: the same program with alpha 0 leaves the actor's gradient without MA.
    off, metrics_off = update(
        state.replace(hyper={**state.hyper, "alpha": jnp.zeros(())}), batch, jax.random.PRNGKey(4)
    )
    assert float(metrics_off["ma_penalty"]) == 0.0
    assert update._cache_size() == 1
    pairs = zip(jax.tree.leaves(off.params["actor"]), jax.tree.leaves(new.params["actor"]),
                strict=True)  # fmt: skip
    moved = [float(jnp.abs(a - b).max()) for a, b in pairs]
    assert max(moved) > 0  # the penalty moved the actor
    # The world model and the critic do not see the MA weight.
    for name in ("world_model", "critic"):
        for a, b in zip(
            jax.tree.leaves(off.params[name]), jax.tree.leaves(new.params[name]), strict=True
        ):
            np.testing.assert_array_equal(a, b)


def test_ma_mode_is_data_and_each_weighting_equals_the_modes_own_agent(agent):
    """The (feedback, temporal) weights in the state pick the mode inside a program that
    computes both terms: each gives its own agent's update (a population of modes shares it)."""
    state = agent.init(jax.random.PRNGKey(0), HYPER)
    batch = sequence_batch(jax.random.PRNGKey(3), TINY.batch_size, TINY.batch_length)
    update = jax.jit(agent.update)
    for k in (5, 6):  # past the warm-up's zero rate, so the actor has moved (temporal term)
        state, _ = update(state, batch, jax.random.PRNGKey(k))
    np.testing.assert_array_equal(state.hyper["ma_terms"], [1.0, 1.0])
    penalties = []
    for mode in ("temporal", "none"):  # Jacobian-only: the population test below
        own = make_agent(5, 2, TINY, MAConfig(alpha=0.5, mode=mode))
        weighted = state.replace(
            hyper={**state.hyper, "ma_terms": jnp.asarray(ma.term_weights(mode))}
        )
        got, got_metrics = update(weighted, batch, jax.random.PRNGKey(4))
        want, want_metrics = jax.jit(own.update)(state, batch, jax.random.PRNGKey(4))
        # (an agent without MA reports no penalty)
        np.testing.assert_allclose(got_metrics["ma_penalty"], want_metrics.get("ma_penalty", 0),
                                   rtol=1e-5, atol=1e-8, err_msg=mode)  # fmt: skip
        for a, b in zip(jax.tree.leaves(got.params["actor"]),
                        jax.tree.leaves(want.params["actor"]), strict=True):  # fmt: skip
            np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6, err_msg=mode)
        penalties.append(float(got_metrics["ma_penalty"]))
    assert update._cache_size() == 1
    assert penalties[0] > 0 and penalties[1] == 0


@pytest.mark.slow
@pytest.mark.extended  # three DreamerV3 compiles (9 minutes in CI beside the other worker)
def test_cli_trains_cheetah_run_and_resumes_exactly(tmp_path, capsys):
    """``train --algo dreamer`` on cheetah_run (smoke): the whole program runs, writes the
    metrics every algorithm writes and resumes exactly."""
    from conftest import straight_and_resumed

    from minatt_jax import runner

    # The fast solver settings: the DMC ones (100 Newton iterations, self-collisions) compile
    # for a minute longer, and test_cheetah_run.py checks them.
    argv = ["train", "--env", "cheetah_run", "--algo", "dreamer", "--preset", "smoke",
            "--alpha", "0.05", "--set", "physics=fast"]  # fmt: skip
    a, b = straight_and_resumed(argv, tmp_path, capsys)
    assert [r["step"] for r in a] == [300, 600]
    assert runner.without_timings(a) == runner.without_timings(b)
    last = a[-1]
    for key in ("return", "feedback_norm", "feedforward_norm", "energy", "jerk", "smoothness",
                "wm_loss", "actor_loss", "critic_loss", "ma_feedback"):  # fmt: skip
        assert np.isfinite(last[key]), key
    assert last["updates"] > 0 and last["ma_feedback"] > 0


def test_recurrent_policy_unroll_matches_a_manual_filter(agent):
    """``acting.unroll`` of the agent's deterministic policy acts as a hand-written loop of
    the filter (posterior mode) and the actor, and its gain probe is du/dobs at each step's h."""
    from minatt_jax import acting

    class Env:  # a linear toy system: the policy, not the physics, is under test
        def step(self, state, action):
            obs = 0.9 * state.obs + 0.3 * jnp.concatenate([action, action[:1] * 2, action])
            return state.replace(obs=obs, reward=jnp.sum(obs), done=jnp.zeros(()))

    from brax.envs.base import State

    params = agent.init(jax.random.PRNGKey(0), HYPER).params
    state = State(pipeline_state=None, obs=jnp.linspace(-1.0, 1.0, 5), reward=jnp.zeros(()),
                  done=jnp.zeros(()), metrics={})  # fmt: skip
    traj = acting.unroll(Env(), agent.policy(params, False), state, 6, probe_gain=True,
                         probe_feedback=True)  # fmt: skip
    latent, prev, first, obs = agent.initial_latent(()), jnp.zeros(2), jnp.ones(()), state.obs
    for t in range(6):
        latent = agent.observe(params["world_model"], latent, obs, prev, first, None)
        u = agent.control(params["actor"], feature(latent.deter, latent.stoch))
        np.testing.assert_allclose(traj.action[t], u, atol=1e-6)
        gain = jax.jacfwd(lambda o, lt=latent: agent.observation_control(params, lt, o))(obs)
        np.testing.assert_allclose(traj.gain[t], gain, atol=1e-6)
        np.testing.assert_allclose(traj.feedback[t], jnp.sum(gain**2), rtol=1e-5)
        obs, prev, first = traj.next_obs[t], u, jnp.zeros(())
    assert float(jnp.std(traj.action[:, 0])) > 0  # the memory and the input change the action


def _initial_run(run_dir: str, evaluate: bool, **overrides) -> None:
    """A DreamerV3 run directory at its initial state, as the runner writes one (config, metrics
    record, policy snapshot, checkpoint) without compiling the training program: the tools that
    read trained runs read nothing else. ``evaluate``: the record holds a real evaluation (the
    profiles of ``analyze`` read it)."""
    import os

    from minatt_jax import runner
    from minatt_jax.config import PRESETS, resolve, with_overrides
    from minatt_jax.evaluation import summarize
    from minatt_jax.training import make_train

    config = resolve(with_overrides(PRESETS["smoke"], env="cheetah_run", algo="dreamer",
                                    **overrides))  # fmt: skip
    trainer = make_train(config)
    state = trainer.init(jax.random.PRNGKey(config.seed), hyper_of(config))
    record = {"step": 300}
    if evaluate:
        result = trainer.evaluate(state, jax.random.PRNGKey(1), trainer.task_set)
        record.update(summarize(jax.device_get(result), trainer.env.dt))
    os.makedirs(run_dir)
    runner.write_json_atomic(os.path.join(run_dir, "config.json"), config.to_dict())
    runner.write_step(run_dir, 300, state, record, None)


SMALL_RUN = {"physics": "fast", "max_episode_steps": 60, "ma_alpha": 0.05}


@pytest.mark.slow
def test_dreamer_run_evaluates_and_refuses_export(tmp_path, capsys):
    """A DreamerV3 run goes through the tools every algorithm's runs go through: ``evaluate``;
    ``export`` (feedforward actors for numpy) refuses it in one line. (Training: the extended
    CLI test; meta-test and analyze: below.)"""
    import json

    from conftest import run_cli

    run = str(tmp_path / "run")
    _initial_run(run, False, **SMALL_RUN)
    status, out = run_cli(["evaluate", run, "--episodes", "2", "--json"], capsys)
    assert status == 0, out.err
    metrics = json.loads(out.out)
    assert metrics["step"] == 300 and np.isfinite(metrics["return"])
    assert metrics["feedback_norm"] > 0 and metrics["energy"] > 0
    status, out = run_cli(["export", run, "--out", str(tmp_path / "p.npz")], capsys)
    assert status == 2 and "recurrent" in out.err and len(out.err.strip().splitlines()) == 1


@pytest.mark.slow
@pytest.mark.extended  # compiles DreamerV3's learner inside the adaptation program (a minute);
# CI meta-tests SAC and MB-MPO runs (tests/test_meta_test.py) and MAMBA's in-context ones
def test_dreamer_run_meta_tests(tmp_path, capsys):
    """``meta-test`` on a DreamerV3 run: its adaptation step changes the policy on each task."""
    import json

    from conftest import run_cli

    run = str(tmp_path / "run")
    _initial_run(run, False, **SMALL_RUN)
    meta = ["meta-test", run, "--variant", "mass", "--adapt-steps", "1", "--episodes", "1",
            "--updates-per-step", "2", "--json"]  # fmt: skip
    status, out = run_cli(meta, capsys)
    assert status == 0, out.err
    result = json.loads(out.out)
    assert len(result["tasks"]) > 1 and result["algo"] == "dreamer"
    for row in result["tasks"]:
        assert len(row["feedback_norm_curve"]) == 2
        assert row["feedback_norm_curve"][0] != row["feedback_norm_curve"][1]  # adapted


@pytest.mark.slow
@pytest.mark.extended  # three more compiles of the cheetah_run unroll
def test_dreamer_run_analyzes(tmp_path, capsys):
    """``analyze`` on a DreamerV3 run: heatmaps, K(t) x + v(t) at the recurrent policy's memory,
    the failure grid, tables."""
    import json

    from conftest import run_cli

    run, report = str(tmp_path / "run"), str(tmp_path / "report")
    _initial_run(run, True, **SMALL_RUN)
    analyze = ["analyze", run, "--out", report, "--episodes", "1", "--bins", "4", "--grid", "2",
               "--grid-rollouts", "1", "--grid-steps", "10"]  # fmt: skip
    status, out = run_cli(analyze, capsys)
    assert status == 0, out.err
    with open(f"{report}/failure_grid.json") as f:
        rates = np.asarray(next(iter(json.load(f)["failure_rate"].values())))
    assert rates.shape == (2, 2) and np.all((rates >= 0) & (rates <= 1))
    with open(f"{report}/tables.json") as f:
        assert "dreamer" in json.dumps(json.load(f))


def _dreamer_members() -> list:
    """Two DreamerV3 members: seed 0 with full MA, seed 1 Jacobian-only."""
    from minatt_jax.config import PRESETS, resolve, with_overrides

    base = with_overrides(PRESETS["smoke"], env="cheetah_run", algo="dreamer", total_steps=300,
                          **SMALL_RUN)  # fmt: skip
    return [resolve(with_overrides(base, seed=0)),
            resolve(with_overrides(base, seed=1, ma_mode="jacobian"))]  # fmt: skip


@pytest.mark.slow
def test_a_dreamer_population_is_one_program_whose_members_do_not_interact():
    """Seeds and MA modes are data for DreamerV3 too: two members train in one program, and
    each trains alike in either position (only the resets' predicate is shared, and a reset
    replaces only ended episodes). The comparison with each member's own run, which compiles a
    second program: the extended test below; the modes' own agents: the weighting test above."""
    from minatt_jax import population

    members = _dreamer_members()
    assert population.groups(members) == [[0, 1]]
    program = population.Program(members)
    init = program.init()
    swapped = jax.tree.map(lambda x: x[::-1], init)  # before the chunk takes (donates) init
    states, metrics = program.chunk(init)
    swapped_states, swapped_metrics = program.chunk(swapped)
    assert program.chunk._cache_size() == 1
    assert float(np.min(metrics["updates"])) > 0
    for key in ("wm_loss", "actor_loss", "critic_loss", "ma_penalty", "train_episode_return"):
        np.testing.assert_allclose(swapped_metrics[key][::-1], metrics[key], rtol=1e-5,
                                   atol=1e-7, err_msg=key)  # fmt: skip
    actor, swapped_actor = states.agent.params["actor"], swapped_states.agent.params["actor"]
    for a, b in zip(jax.tree.leaves(actor), jax.tree.leaves(swapped_actor), strict=True):
        np.testing.assert_allclose(b[::-1], a, rtol=1e-5, atol=1e-7)
    # The members are another seed in another mode: they trained otherwise.
    assert float(metrics["actor_loss"][0]) != float(metrics["actor_loss"][1])


@pytest.mark.slow
@pytest.mark.extended  # a second DreamerV3 compile (the member's own run): pytest -m extended
def test_a_dreamer_population_is_one_program_and_a_member_equals_its_own_run():
    """Seeds and MA modes are data for DreamerV3 too: two members (seed 0 with full MA, seed 1
    Jacobian-only) train in one program, and the second trains as its own run does (whose
    program computes the feedback term alone)."""
    from minatt_jax import population
    from minatt_jax.training import make_train

    members = _dreamer_members()
    assert population.groups(members) == [[0, 1]]
    program = population.Program(members)
    states, metrics = program.chunk(program.init())
    assert program.chunk._cache_size() == 1
    alone = make_train(members[1])
    single, single_metrics = alone.train_chunk(
        alone.init(jax.random.PRNGKey(1), hyper_of(alone.config))
    )
    assert int(single_metrics["updates"]) > 0
    for key in ("wm_loss", "actor_loss", "critic_loss", "ma_penalty", "train_episode_return"):
        np.testing.assert_allclose(metrics[key][1], single_metrics[key], rtol=1e-4, atol=1e-6,
                                   err_msg=key)  # fmt: skip
    for a, b in zip(jax.tree.leaves(states.agent.params["actor"]),
                    jax.tree.leaves(single.agent.params["actor"]), strict=True):  # fmt: skip
        np.testing.assert_allclose(a[1], b, rtol=1e-4, atol=1e-6)
    # The first member is another seed in another mode: it trained otherwise.
    assert float(metrics["actor_loss"][0]) != float(metrics["actor_loss"][1])

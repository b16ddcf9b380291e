"""One training program: every collection option in every algorithm, numbers kept, one Jacobian."""

from __future__ import annotations

import json
import os
import pathlib
import platform
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import minatt_jax
from minatt_jax import acting, runner
from minatt_jax import min_attention as ma
from minatt_jax.analysis import control_analysis as ca
from minatt_jax.config import PRESETS, TrainConfig, resolve, with_overrides
from minatt_jax.sac import SACConfig, make_sac
from minatt_jax.training import hyper_of, make_train

DATA = pathlib.Path(__file__).parent / "data"
sys.path.insert(0, str(DATA))

from record_golden import cpu_flags  # noqa: E402 - from tests/data


@pytest.mark.slow
@pytest.mark.parametrize(
    "algo",
    [  # mbmpo's chunk holds sac's collection and mbpo's model fits: CI runs it alone
        pytest.param("sac", marks=pytest.mark.extended),
        pytest.param("mbpo", marks=pytest.mark.extended),
        "mbmpo",
    ],
)
def test_collection_options_work_for_every_algorithm(algo):
    """OU noise, observation normalization and several environments, honoured by each algorithm."""
    config = resolve(with_overrides(
        PRESETS["smoke"], algo=algo, noise="ou", sac_normalize_obs=True, num_envs=2,
        warmup_steps=100, eval_every=200, total_steps=200,
    ))  # fmt: skip
    trainer = make_train(config)
    state, metrics = trainer.train_chunk(
        trainer.init(jax.random.PRNGKey(0), hyper_of(trainer.config))
    )
    assert int(state.env_steps) == 200 and int(state.data.real.size) == 200  # 100 x 2 envs
    assert float(state.data.normalizer.count) == 200  # the statistics saw every observation
    assert np.any(np.asarray(state.collector.ou_noise) != 0)  # OU exploration state moves
    assert float(metrics["updates"]) > 0 and np.isfinite(float(metrics["critic_loss"]))
    if algo != "sac":
        # Refits when the step counter crosses 100 and 200 (it moves 2 at a time).
        assert float(metrics["model_fits"]) == 2 and float(metrics["imagined_transitions"]) > 0
    # The policy acts on normalized observations: evaluation agrees with a manual rollout.
    result = trainer.evaluate(state, jax.random.PRNGKey(3), trainer.task_set)
    env, norm = trainer.env, state.data.normalizer
    first_task = jax.tree.map(lambda t: t[0], trainer.task_set)
    key = jax.random.split(jax.random.PRNGKey(3), config.eval_episodes)[0]
    x = jnp.clip((env.reset(key, first_task).obs - norm.mean) / jnp.sqrt(norm.var + 1e-8), -10, 10)
    u = trainer.agent.policy.agent.control(state.agent.actor_params, x)
    np.testing.assert_allclose(result.actions[0, 0], u, rtol=1e-5, atol=1e-6)


@pytest.mark.slow
def test_reward_normalization_tracks_the_discounted_return_and_scales_batches():
    """``sac.normalize_reward``: the running variance is that of every environment's discounted
    return G <- gamma G + r (zeroed at episode ends), computed here from the stored transitions;
    and an update sees rewards / std: rewards scaled by c with a std scaled by c update the
    agent identically."""
    config = resolve(with_overrides(
        PRESETS["smoke"], algo="sac", sac_normalize_reward=True, num_envs=2, warmup_steps=100,
        eval_every=200, total_steps=200,
    ))  # fmt: skip
    trainer = make_train(config)
    state, _ = trainer.train_chunk(trainer.init(jax.random.PRNGKey(0), hyper_of(trainer.config)))
    data = jax.device_get(state.data.real.data)
    returns = []
    for e in range(2):  # rows alternate between the two environments
        obs, nxt, r = data.obs[e:200:2], data.next_obs[e:200:2], data.reward[e:200:2]
        g = 0.0
        for t in range(100):
            g = config.sac.gamma * g + float(r[t])
            returns.append(g)
            if t + 1 < 100 and not np.array_equal(nxt[t], obs[t + 1]):  # a new episode
                g = 0.0
    stats = state.data.return_stats
    assert float(stats.count) == 200
    np.testing.assert_allclose(float(stats.var[0]), np.var(returns), rtol=1e-4)
    assert abs(float(stats.var[0]) - 1.0) > 0.1  # a scale that changes the rewards

    update = jax.jit(trainer.agent.parts["agent_update"])
    c = 3.0
    scaled = state.replace(data=state.data.replace(
        real=state.data.real.replace(data=state.data.real.data.replace(
            reward=state.data.real.data.reward * c)),
        return_stats=stats.replace(var=(stats.var + 1e-8) * c**2 - 1e-8),
    ))  # fmt: skip
    a, _ = update(state, jax.random.PRNGKey(5))
    b, _ = update(scaled, jax.random.PRNGKey(5))
    for x, y in zip(jax.tree.leaves(a.agent), jax.tree.leaves(b.agent), strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=2e-4, atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",  # the MA/normalization/OU run takes every step the plain one takes: CI runs it alone
    [pytest.param("sac", marks=pytest.mark.extended), "sac_ma_norm_ou"],
)
def test_smoke_numbers_are_kept(name, tmp_path, capsys):
    """SAC smoke runs give exactly the metrics recorded with this version, and those of before the
    one-program restructure to float rounding: the restructure itself kept them bit for bit
    (checked when it landed); making learning rates data in the optimizer state (populations
    sweep them) changed float rounding, by at most 5e-4 relative after 600 steps. Compared where
    the platform matches the recording: XLA's CPU code depends on the instruction set."""
    reference = json.loads((DATA / f"reference_smoke_{name}.json").read_text())
    here = (jax.__version__, platform.machine(), cpu_flags())
    there = (reference["jax"], reference["machine"], reference["cpu_flags"])
    if here != there:
        pytest.skip(f"reference recorded on {there}, this platform is {here}")
    from minatt_jax.cli import main

    out = str(tmp_path / "run")
    assert main([*reference["argv"], "--out", out]) == 0
    capsys.readouterr()
    records = runner.without_timings(runner.read_metrics(out))
    assert records == reference["current"]["records"]
    for now, before in zip(records, reference["records"], strict=True):
        assert set(now) >= set(before)
        for key, value in before.items():
            assert now[key] == pytest.approx(value, rel=5e-4, abs=1e-9), key


def test_one_function_computes_the_feedback_norm(make_env):
    """Evaluation's probe, the control decomposition and the penalty agree exactly, and no other
    module takes a Jacobian of the control."""
    env = make_env("hopper")
    sac = make_sac(11, 3, SACConfig(hidden=(16, 16)), ma.MAConfig())
    params = sac.init(jax.random.PRNGKey(0), hyper_of(TrainConfig())).actor_params
    policy = acting.deterministic(sac.control, params)
    traj = jax.jit(lambda k: acting.unroll(env, policy, env.reset(k), 20, probe_feedback=True))(
        jax.random.PRNGKey(1)
    )
    exact = ma.feedback_exact(sac.control, params, traj.obs, "jacfwd")
    np.testing.assert_allclose(traj.feedback, exact, rtol=1e-6)
    parts = ca.decompose(sac.control, params, traj.obs)
    np.testing.assert_allclose(parts["feedback"], exact, rtol=1e-6)
    # A central finite difference of u along one coordinate matches the Jacobian's column.
    x, e, h = traj.obs[3], jnp.zeros(11).at[4].set(1.0), 1e-3
    fd = (sac.control(params, x + h * e) - sac.control(params, x - h * e)) / (2 * h)
    np.testing.assert_allclose(parts["K"][3][:, 4], fd, rtol=2e-2, atol=1e-4)
    package = pathlib.Path(minatt_jax.__file__).parent
    users = sorted(p.name for p in package.glob("*.py")
                   if "jax.jacfwd" in p.read_text() or "jax.jacrev" in p.read_text())  # fmt: skip
    assert users == ["min_attention.py"]
    assert os.path.exists(package / "acting.py")


def test_no_import_cycles_in_the_package():
    """The module graph (every import, lazy ones included) has no cycle."""
    import ast

    root = pathlib.Path(minatt_jax.__file__).parent
    files = {}
    for p in root.rglob("*.py"):  # every module of every subpackage
        parts = p.relative_to(root).with_suffix("").parts
        if parts[0] != "envs":
            name = ".".join(("minatt_jax", *parts)).removesuffix(".__init__")
            files[name] = p
    envs_dir = root / "envs" if (root / "envs").is_dir() else root.parent / "envs"
    files.update({f"minatt_jax.envs.{p.stem}": p for p in envs_dir.glob("*.py")
                  if p.stem != "__init__"})  # fmt: skip
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:  # relative: resolve it
                raise AssertionError(f"{name} uses a relative import")
            if isinstance(node, ast.ImportFrom) and node.module:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            deps |= {t for t in targets if t in files and t != name}
        graph[name] = deps
    state: dict[str, int] = {}

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for dep in graph[node]:
            if state.get(dep) == 1:
                raise AssertionError("import cycle: " + " -> ".join([*stack, node, dep]))
            if dep not in state:
                visit(dep, [*stack, node])
        state[node] = 2

    for module in graph:
        if module not in state:
            visit(module, [])
    assert "minatt_jax.training" in graph and "minatt_jax.agents.sac" in graph
    # The generic program and the library around it name no algorithm: only agents/ does.
    for module, path in files.items():
        if module.startswith(("minatt_jax.agents", "minatt_jax.dreamer")):
            continue
        text = path.read_text()
        for name in ('"sac"', '"mbpo"', '"mbmpo"', '"dreamer"', "config.algo =="):
            assert f"algo == {name}" not in text and "algo in (" not in text, (module, name)

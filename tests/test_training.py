"""SAC + MA training: it learns, MA lowers the feedback norm, one compile, exact resume."""

from __future__ import annotations

import collections
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import jax
import numpy as np
import pytest
from conftest import run_cli

from minatt_jax import acting, checkpoint, runner
from minatt_jax.config import PRESETS, resolve, with_overrides
from minatt_jax.evaluation import make_evaluator, summarize
from minatt_jax.training import hyper_of, make_train, program_key

LEARN = with_overrides(
    PRESETS["smoke"], total_steps=6000, warmup_steps=1000, eval_every=2000,
    max_episode_steps=200, buffer_size=10_000, eval_episodes=3, sac_hidden=(64, 64),
    sac_batch_size=128,
)  # fmt: skip


def _train(config):
    trainer = make_train(resolve(config))
    state = trainer.init(jax.random.PRNGKey(config.seed), hyper_of(config))
    while int(state.env_steps) < config.total_steps:
        state, _ = trainer.train_chunk(state)
    result = trainer.evaluate(state, jax.random.PRNGKey(1), trainer.task_set)
    return trainer, state, summarize(jax.device_get(result), trainer.env.dt)


@pytest.mark.slow
@pytest.mark.extended  # 4 minutes; test_smoke_numbers_are_kept pins a training run's numbers in CI
def test_sac_learns_and_ma_lowers_feedback():
    trainer, state, plain = _train(LEARN)
    # One compiled program served every chunk, before and after warm-up.
    assert trainer.train_chunk._cache_size() == 1
    # Another seed runs in the same compiled program.
    trainer.train_chunk(trainer.init(jax.random.PRNGKey(5), hyper_of(trainer.config)))
    assert trainer.train_chunk._cache_size() == 1
    # A random policy on the same 200-step episodes.
    env, policy = trainer.env, acting.random_policy(3)

    def random_return(key):
        k_reset, k_act = jax.random.split(key)
        traj = acting.unroll(env, policy, env.reset(k_reset, env.nominal_task()), 200, key=k_act)
        return jax.numpy.sum(traj.alive * traj.reward)

    random_returns = jax.jit(jax.vmap(random_return))(jax.random.split(jax.random.PRNGKey(0), 50))
    best_random = float(np.max(random_returns))
    assert best_random < 80
    assert plain["return"] > 100 > best_random
    _, _, regularized = _train(with_overrides(LEARN, ma_alpha=1.0))
    assert regularized["feedback_norm"] < 0.5 * plain["feedback_norm"]


SMALL = with_overrides(PRESETS["smoke"], total_steps=900)


@pytest.mark.slow
def test_killed_run_resumes_exactly(tmp_path):
    env = dict(os.environ)  # conftest points JAX_COMPILATION_CACHE_DIR at a shared cache
    cmd = [sys.executable, "-m", "minatt_jax.cli", "train", "--preset", "smoke", "--steps", "900"]
    straight, killed = str(tmp_path / "straight"), str(tmp_path / "killed")
    # The uninterrupted run and the one to kill, side by side.
    proc_a = subprocess.Popen(cmd + ["--out", straight], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)  # fmt: skip
    proc_b = subprocess.Popen(cmd + ["--out", killed], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)  # fmt: skip
    deadline = time.time() + 400
    while time.time() < deadline and checkpoint.latest_step(killed) is None:
        time.sleep(0.2)
    proc_b.send_signal(signal.SIGKILL)
    proc_b.wait()
    assert proc_a.wait(timeout=400) == 0
    done_before_kill = len(runner.read_metrics(killed))
    assert 1 <= done_before_kill < 3
    resumed = subprocess.run(cmd + ["--out", killed, "--resume"], env=env, capture_output=True,
                             text=True, timeout=400)  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr
    assert "resumed" in resumed.stdout
    a, b = runner.read_metrics(straight), runner.read_metrics(killed)
    assert [r["step"] for r in a] == [300, 600, 900]
    assert runner.without_timings(a) == runner.without_timings(b)


@pytest.mark.slow
def test_a_run_stopped_before_its_first_checkpoint_resumes_with_its_own_values(tmp_path, capsys):
    """A stop during compilation leaves config.json alone; the resume it advises trains with the
    run's own alpha and learning rates (the state's hyper values come from the run's config on
    every path), and writes exactly the uninterrupted run's records."""
    from conftest import run_cli

    argv = ["train", "--preset", "smoke", "--steps", "300", "--alpha", "0.5",
            "--set", "sac.actor_lr=1e-3"]  # fmt: skip
    straight, stopped = str(tmp_path / "straight"), str(tmp_path / "stopped")
    assert run_cli([*argv, "--out", straight], capsys)[0] == 0
    config = runner.load_config(straight)
    os.makedirs(stopped)
    runner.write_json_atomic(os.path.join(stopped, "config.json"), config.to_dict())
    assert run_cli(["train", "--out", stopped, "--resume"], capsys)[0] == 0
    a, b = runner.read_metrics(straight), runner.read_metrics(stopped)
    assert len(a) == 1 and runner.without_timings(a) == runner.without_timings(b)
    # and the state trained with the run's values, not defaults
    trainer = make_train(config)
    other = hyper_of(with_overrides(config, ma_alpha=0.1, sac_actor_lr=0.1))
    state = checkpoint.restore(stopped, trainer.init(jax.random.PRNGKey(9), other))[1]
    assert float(state.agent.hyper["alpha"]) == 0.5
    assert float(state.agent.hyper["actor_lr"]) == np.float32(1e-3)


def test_runs_of_one_program_share_a_process_compiled_step(tmp_path, capsys):
    """A second run in the process that differs in seed, MA weight and length traces and
    compiles nothing, and writes the metrics of the same run built from scratch."""
    smoke = ["train", "--preset", "smoke"]
    runner._TRAINERS.clear()
    first, second, scratch = (str(tmp_path / name) for name in ("first", "second", "scratch"))
    assert run_cli([*smoke, "--steps", "300", "--alpha", "1", "--out", first], capsys)[0] == 0
    ((trainer, compiled),) = runner._TRAINERS.values()
    argv = [
        *smoke,
        "--steps",
        "600",
        "--alpha",
        "0.25",
        "--seed",
        "3",
        "--set",
        "sac.actor_lr=1e-3",
    ]
    status, io = run_cli([*argv, "--out", second], capsys)
    assert status == 0 and "reusing the training step compiled" in io.out
    assert (
        len(runner._TRAINERS) == 1 and runner._TRAINERS[program_key(trainer.config)][1] is compiled
    )
    runner._TRAINERS.clear()  # the same run again, with its own trainer
    status, io = run_cli([*argv, "--out", scratch], capsys)
    assert status == 0 and "compiled the training step in" in io.out
    with open(os.path.join(second, "config.json")) as f:
        assert json.load(f)["ma"]["alpha"] == 0.25
    a, b = runner.read_metrics(second), runner.read_metrics(scratch)
    assert [r["step"] for r in a] == [300, 600]
    assert runner.without_timings(a) == runner.without_timings(b)


def test_resume_errors_exit_2(tmp_path, capsys):
    status, out = run_cli(["train", "--resume", "--out", str(tmp_path / "none")], capsys)
    assert status == 2 and "does not exist" in out.err
    run = tmp_path / "run"
    run.mkdir()
    runner.write_json_atomic(str(run / "config.json"), SMALL.to_dict())
    status, out = run_cli(["train", "--resume", "--out", str(run), "--env", "walker2d"], capsys)
    assert status == 2 and "other settings" in out.err
    (run / "config.json").write_text("{not json")
    status, out = run_cli(["evaluate", str(run)], capsys)
    assert status == 2 and "corrupt" in out.err
    assert len(out.err.strip().splitlines()) == 1


def test_train_rejects_bad_values(capsys):
    for argv, message in [
        (["train", "--env", "ant"], "unknown environment"),
        (
            ["train", "--algo", "td3"],
            "unknown algorithm 'td3'; choose from sac, mbpo, mbmpo, dreamer",
        ),
        (["train", "--alpha=-1"], "expected a finite number >= 0"),
        (["train", "--variant", "moon"], "unknown variant"),
        (["train", "--estimator", "magic"], "invalid choice"),
    ]:
        status, out = run_cli(argv, capsys)
        assert status == 2, argv
        assert message in out.err
        assert len(out.err.strip().splitlines()) == 1


@pytest.mark.slow
def test_corrupt_checkpoint_is_reported(tmp_path, capsys, monkeypatch):
    run = str(tmp_path / "run")
    os.makedirs(run)
    config = with_overrides(PRESETS["smoke"], total_steps=300)
    runner.train(config, run, log=lambda m: None)
    # Evaluations of one program (other seeds, later the CLI's) build its evaluator once.
    built = []
    monkeypatch.setattr(runner, "_EVALUATORS", collections.OrderedDict())
    monkeypatch.setattr(runner, "make_evaluator",
                        lambda *a: built.append(a) or make_evaluator(*a))  # fmt: skip
    first, second = (runner.evaluate_run(run, None, None, seed=s) for s in (0, 1))
    assert len(built) == 1 and first["return"] != second["return"]
    step_dir = os.path.join(run, "checkpoints", "300")
    for root, _, files in os.walk(step_dir):
        for name in files:
            with open(os.path.join(root, name), "wb") as f:
                f.write(b"garbage")
    for argv in (["meta-test", run, "--variant", "mass"], ["inspect", run]):
        status, out = run_cli(argv, capsys)
        assert status == 2, argv
        assert "corrupt" in out.err and len(out.err.strip().splitlines()) == 1
    # evaluate reads the step's policy snapshot, which is intact.
    status, out = run_cli(["evaluate", run, "--json"], capsys)
    assert status == 0 and json.loads(out.out)["step"] == 300
    shutil.rmtree(os.path.join(run, "checkpoints"))
    shutil.rmtree(os.path.join(run, "policy_snapshots"))
    status, out = run_cli(["evaluate", run, "--json"], capsys)
    assert status == 2 and "no checkpoint" in out.err
    assert json.loads((tmp_path / "run" / "metrics.jsonl").read_text().splitlines()[0])["step"]

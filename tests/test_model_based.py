"""mbpo / mbmpo training: one compiled program across chunks, refits and tasks; exact resume."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import jax
import numpy as np
import pytest

from minatt_jax import checkpoint, runner
from minatt_jax.cli import main
from minatt_jax.config import PRESETS, resolve, with_overrides
from minatt_jax.training import hyper_of, make_train


@pytest.mark.parametrize(
    "algo", ["mbpo", "mbmpo", pytest.param("mbmpo-vpg-trpo", marks=pytest.mark.extended)]
)
def test_model_based_chunk_compiles_once(algo):
    inner, outer = ("vpg", "trpo") if algo.endswith("trpo") else ("sac", "sac")
    algo = algo.split("-")[0]
    config = with_overrides(PRESETS["smoke"], algo=algo, task_set="train", ma_alpha=1.0,
                            mb_meta_inner=inner, mb_meta_outer=outer)  # fmt: skip
    trainer = make_train(resolve(config))
    state = trainer.init(jax.random.PRNGKey(0), hyper_of(trainer.config))
    fits, holdouts, tasks = [], [], set()
    for _ in range(3):
        state, metrics = trainer.train_chunk(state)
        fits.append(float(metrics["model_fits"]))
        holdouts.append(float(metrics["model_holdout_mse"]))
        tasks.add(float(state.collector.env_state.info["task"].gravity_scale[0]))
    # Epochs (chunks), model refits inside them and task changes at resets: one program.
    assert trainer.train_chunk._cache_size() == 1
    assert fits == [2.0, 3.0, 3.0]  # warm-up ends at 200, refits every 100 steps
    assert holdouts[-1] < holdouts[0]  # the model improves as data arrives
    assert np.isfinite(float(metrics["critic_loss"])) and float(metrics["updates"]) == 300
    assert float(metrics["imagined_transitions"]) > 0
    if outer == "trpo":  # steps were taken, within the trust region
        assert float(metrics["trpo_accepted"]) > 0.5
        assert 0 < float(metrics["trpo_kl"]) <= config.mb.trpo_max_kl * 1.001
    if algo == "mbmpo":
        assert np.isfinite(float(metrics["meta_inner_loss"]))
        # The adapted policies differ from the meta policy.
        gap = jax.tree.map(
            lambda a, p: float(np.max(np.abs(np.asarray(a) - np.asarray(p)))),
            state.meta.adapted, state.agent.actor_params,
        )  # fmt: skip
        assert max(jax.tree.leaves(gap)) > 0
    # Another seed, same program.
    trainer.train_chunk(trainer.init(jax.random.PRNGKey(7), hyper_of(trainer.config)))
    assert trainer.train_chunk._cache_size() == 1


@pytest.mark.extended  # a subprocess compiling beside the other worker: CI kills SAC runs
def test_mbmpo_killed_run_resumes_exactly(tmp_path):
    """An mbmpo run SIGKILLed after its first checkpoint and resumed writes the metrics of an
    uninterrupted run (model buffers, ensemble and meta state all restored)."""
    base = ["train", "--env", "hopper", "--algo", "mbmpo", "--alpha", "1", "--preset", "smoke",
            "--steps", "600"]  # fmt: skip
    straight, killed = str(tmp_path / "straight"), str(tmp_path / "killed")
    assert main([*base, "--out", straight]) == 0  # compiles; the subprocess loads the cache
    proc = subprocess.Popen([sys.executable, "-m", "minatt_jax.cli", *base, "--out", killed],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    deadline = time.time() + 400
    while time.time() < deadline and checkpoint.latest_step(killed) is None:
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert len(runner.read_metrics(killed)) <= 1
    assert main([*base, "--out", killed, "--resume"]) == 0
    a, b = runner.read_metrics(straight), runner.read_metrics(killed)
    assert [r["step"] for r in a] == [300, 600]
    assert runner.without_timings(a) == runner.without_timings(b)
    assert "model_holdout_mse" in a[-1] and len(a[-1]["model_elites"]) == 2
    with open(tmp_path / "killed" / "config.json") as f:
        assert json.load(f)["task_set"] == "train"  # mbmpo's default task set


def _actor_at(run_dir: str, step: int) -> dict[str, np.ndarray]:
    with np.load(f"{run_dir}/policy_snapshots/step_{step:09d}.npz") as f:
        return dict(f)


@pytest.mark.slow
def test_resume_with_shorter_chunks_continues_the_same_trajectory(tmp_path, capsys):
    """eval_every may change on resume (finer checkpoints for a long run): the model schedule
    reads the env-step counter and the key is in the state, so 300 -> 600 in chunks of 100
    ends at the same actor, bit for bit, as one run in chunks of 300; a checkpoint off the new
    grid is refused with exit 2."""
    base = ["train", "--env", "hopper", "--algo", "mbmpo", "--alpha", "1", "--preset", "smoke"]
    straight, split = str(tmp_path / "straight"), str(tmp_path / "split")
    assert main([*base, "--steps", "600", "--out", straight]) == 0
    assert main([*base, "--steps", "300", "--out", split]) == 0
    capsys.readouterr()
    assert main(["train", "--out", split, "--resume", "--steps", "600", "--eval-every", "200"]) == 2
    err = capsys.readouterr().err
    assert "not a multiple of eval_every 200" in err and len(err.strip().splitlines()) == 1
    assert main(["train", "--out", split, "--resume", "--steps", "600", "--eval-every", "100"]) == 0
    assert [r["step"] for r in runner.read_metrics(split)] == [300, 400, 500, 600]
    assert runner.load_config(split).eval_every == 100
    a, b = _actor_at(straight, 600), _actor_at(split, 600)
    assert a and a.keys() == b.keys()
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    last_a, last_b = runner.read_metrics(straight)[-1], runner.read_metrics(split)[-1]
    assert last_a["return"] == last_b["return"]
    assert last_a["feedback_norm"] == last_b["feedback_norm"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--algo", "mbmpo", "--elites", "9"], "num_elites"),
        (["--algo", "mbmpo2"], "unknown algorithm"),
        (["--algo", "mbpo", "--rollout-batch", "1"], "rollout_batch"),
    ],
)
def test_model_based_bad_values_exit_2(argv, message, capsys, tmp_path):
    status = main(["train", "--preset", "smoke", "--out", str(tmp_path / "r"), *argv])
    err = capsys.readouterr().err
    assert status == 2 and message in err and len(err.strip().splitlines()) == 1

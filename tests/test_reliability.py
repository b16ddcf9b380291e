"""Faults a long run meets: non-finite states and training, signals, a second writer, unreadable
or half-written checkpoints, a cut metrics line. Each ends in one line and keeps what was saved."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import State
from conftest import run_cli

from minatt_jax import acting, checkpoint, run_guard, runner

SMOKE = ["train", "--preset", "smoke"]


def _records(run_dir):
    return runner.without_timings(runner.read_metrics(run_dir))


class _ExplodingEnv:
    """A toy environment whose state goes NaN on its third step after a reset."""

    def reset(self, key):
        del key
        return State(None, jnp.zeros(2), jnp.zeros(()), jnp.zeros(()), {}, {"t": jnp.zeros(())})

    def step(self, state, action):
        t = state.info["t"] + 1
        obs = jnp.where(t == 3, jnp.nan, t) * jnp.ones(2)
        return State(None, obs, jnp.ones(()), jnp.zeros(()), {}, {"t": t})


def test_a_non_finite_simulator_state_is_reset_and_not_learned_from():
    env = _ExplodingEnv()
    reset = jax.vmap(env.reset)
    state = reset(jnp.zeros((2, 2)))
    ret, length = jnp.zeros(2), jnp.zeros(2, jnp.int32)
    seen, fresh = [], lambda key: reset(jnp.zeros((2, 2)))
    for _ in range(4):
        s = acting.collect_step(env, state, jnp.zeros((2, 1)), ret, length, 100, fresh,
                                jax.random.PRNGKey(0))  # fmt: skip
        state, ret, length = s.env_state, s.episode_return, s.episode_length
        seen.append(s)
    third = seen[2]
    assert not bool(third.finite.any()) and bool(third.ended.all())
    assert float(third.finished_return) == 0.0  # the broken episode's return is not counted
    assert np.all(np.isfinite(np.asarray(state.obs)))  # reset: the next step starts afresh
    assert bool(seen[3].finite.all()) and float(seen[3].transitions.obs[0, 0]) == 0.0


def test_a_second_writer_is_refused_and_nothing_is_written(tmp_path, capsys):
    out = str(tmp_path / "run")
    with run_guard.lock_run(out):
        status, io = run_cli([*SMOKE, "--steps", "300", "--out", out], capsys)
    assert status == 2 and "being trained by another process" in io.err
    assert len(io.err.strip().splitlines()) == 1
    assert not os.path.exists(os.path.join(out, "config.json"))


@pytest.mark.slow
def test_diverged_training_stops_with_3_and_resumes_with_other_settings(tmp_path, capsys):
    """alpha 1e38 overflows the penalty: exit 3 naming it, checkpoint 300 kept, nothing of the
    bad chunk written; resuming with a sane alpha (a data field: same program) goes on."""
    out = str(tmp_path / "run")  # alpha > 0 throughout: one program (MA on), compiled once
    assert run_cli([*SMOKE, "--steps", "300", "--alpha", "1", "--out", out], capsys)[0] == 0
    before = _records(out)
    status, io = run_cli(["train", "--out", out, "--resume", "--steps", "600", "--alpha", "1e38"],
                      capsys)  # fmt: skip
    assert status == 3, io.err
    assert "diverged at step 600" in io.err and "ma_penalty is not finite" in io.err
    assert "checkpoint 300 is kept" in io.err and "--resume" in io.err
    assert checkpoint.all_steps(out) == [300] and _records(out) == before
    assert runner.load_config(out).ma.alpha == 1e38  # the resume itself was valid
    # Finite but blown up: a loss 1e18 and a collapsed entropy stop the run just the same.
    status, io = run_cli(["train", "--out", out, "--resume", "--alpha", "1e8", "--set",
                          "sac.actor_lr=1"], capsys)  # fmt: skip
    assert status == 3, io.err
    assert "diverged at step 600" in io.err and "running scale" in io.err
    assert len(io.err.strip().splitlines()) == 1 and "Traceback" not in io.err
    assert checkpoint.all_steps(out) == [300] and _records(out) == before
    status, io = run_cli(["train", "--out", out, "--resume", "--alpha", "0.5", "--set",
                          "sac.actor_lr=3e-4"], capsys)  # fmt: skip
    assert status == 0, io.err
    assert "resuming with ma.alpha=0.5" in io.out
    assert [r["step"] for r in _records(out)] == [300, 600]
    # A policy with non-finite weights is refused by evaluate, not plotted.
    policy = checkpoint.load_policy(out)
    broken = jax.tree.map(lambda x: x * np.nan, policy.actor_params)
    checkpoint.save_policy_snapshot(out, 600, broken, policy.normalizer)
    status, io = run_cli(["evaluate", out], capsys)
    assert status == 2 and "non-finite weights" in io.err


@pytest.mark.slow
def test_resume_falls_back_past_an_unreadable_checkpoint(tmp_path, capsys):
    """Checkpoint 600 corrupt, the snapshot of 300 lost, metrics.jsonl cut mid-line: resume goes
    on from 300, says so, rewrites the snapshot and the records exactly."""
    out = str(tmp_path / "run")
    assert run_cli([*SMOKE, "--steps", "600", "--out", out], capsys)[0] == 0
    before = _records(out)
    for root, _, files in os.walk(os.path.join(out, "checkpoints", "600")):
        for name in files:
            with open(os.path.join(root, name), "wb") as f:
                f.write(b"garbage")
    os.remove(os.path.join(out, "policy_snapshots", "step_000000300.npz"))
    with open(os.path.join(out, "metrics.jsonl"), "a") as f:
        f.write('{"step": 9')
    status, io = run_cli(["train", "--out", out, "--resume"], capsys)
    assert status == 0, io.err
    assert "checkpoint 600 is unreadable; resuming from checkpoint 300" in io.out
    assert _records(out) == before  # step 600 trained again, identically
    assert os.listdir(os.path.join(out, "checkpoints_unreadable"))
    assert 300 in checkpoint.snapshot_steps(out)
    lines = open(os.path.join(out, "metrics.jsonl")).read().splitlines()
    assert all(json.loads(line) for line in lines) and len(lines) == 2


def test_a_failed_reads_abandoned_futures_log_nothing(caplog):
    """Orbax abandons its other reads once one fails; asyncio logs each as "exception was never
    retrieved" whenever it is collected. Those of a tensorstore (OCDBT) read are dropped: the
    one-line CheckpointError already says it. Any other never-retrieved exception still logs."""
    import asyncio
    import gc

    def abandon(message: str) -> None:
        loop = asyncio.new_event_loop()
        future = loop.create_future()
        future.set_exception(ValueError(message))
        loop.close()
        del future
        gc.collect()

    with caplog.at_level(logging.ERROR, logger="asyncio"):
        abandon('OUT_OF_RANGE: Error reading "x" in OCDBT database at local file "y"')
        assert not caplog.records
        abandon("something else failed")
        assert [r.getMessage().splitlines()[0] for r in caplog.records] == [
            "Future exception was never retrieved"
        ]


_DIE_IN_SAVE = """
import os, sys
import orbax.checkpoint as ocp
from minatt_jax.cli import main
calls = {"n": 0}
original = ocp.CheckpointManager.save
def dying(self, *args, **kwargs):
    calls["n"] += 1
    saved = original(self, *args, **kwargs)
    if calls["n"] == 2:  # the second checkpoint: being written, never finalized
        os._exit(137)
    return saved
ocp.CheckpointManager.save = dying
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.slow
def test_killed_during_a_checkpoint_save_resumes_from_the_previous_one(tmp_path):
    out = str(tmp_path / "run")
    argv = [*SMOKE, "--steps", "600", "--out", out]
    died = subprocess.run([sys.executable, "-c", _DIE_IN_SAVE, *argv], capture_output=True,
                          text=True, timeout=600)  # fmt: skip
    assert died.returncode == 137, died.stderr
    assert checkpoint.all_steps(out) == [300]
    resumed = subprocess.run([sys.executable, "-m", "minatt_jax.cli", *argv, "--resume"],
                             capture_output=True, text=True, timeout=600)  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr
    assert "resumed" in resumed.stdout and "at env step 300" in resumed.stdout
    assert [r["step"] for r in runner.read_metrics(out)] == [300, 600]


@pytest.mark.slow
def test_a_signal_stops_after_the_chunk_with_a_checkpoint(tmp_path):
    """SIGINT stops after the chunk with its checkpoint (130); two SIGTERMs exit at once (143)
    and the checkpoint stays readable; the run then resumes to the end."""
    out = str(tmp_path / "run")
    signum, status = signal.SIGINT, 130
    cmd = [sys.executable, "-m", "minatt_jax.cli", *SMOKE, "--steps", "1500", "--out", out]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 500
    while time.time() < deadline and checkpoint.latest_step(out) is None:
        time.sleep(0.2)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == status, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("minatt-jax: stopped: stopped by SIG")
    assert f"resume with: minatt-jax train --out {out} --resume" in last
    assert "Traceback" not in err
    step = checkpoint.latest_step(out)
    assert 300 <= step < 1500 and runner.read_metrics(out)[-1]["step"] == step
    # A second signal while stopping exits at once; the checkpoint stays readable.
    signum, status = signal.SIGTERM, 143
    proc = subprocess.Popen([*cmd, "--resume"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    for line in proc.stdout:  # training's handlers are installed once it has resumed
        if line.startswith("resumed"):
            break
    proc.send_signal(signum)
    time.sleep(0.5)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == status, err
    assert checkpoint.latest_step(out) == step
    resumed = subprocess.run([*cmd, "--resume"], capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert [r["step"] for r in runner.read_metrics(out)] == [300, 600, 900, 1200, 1500]


def test_a_full_disk_during_a_checkpoint_is_one_line(tmp_path, monkeypatch, capsys):
    """ENOSPC inside orbax's save: CheckpointError naming the cause, nothing logged by absl."""
    import errno

    import orbax.checkpoint as ocp

    def full(self, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(ocp.CheckpointManager, "save", full)
    with pytest.raises(checkpoint.CheckpointError, match="No space left on device"):
        checkpoint.save(str(tmp_path), 300, {"x": jnp.zeros(3)})
    assert "absl" not in capsys.readouterr().err


def test_result_files_follow_the_umask_not_the_temporary_files_0600(tmp_path):
    from minatt_jax.analysis import plots

    previous = os.umask(0o022)
    try:
        runner.write_json_atomic(str(tmp_path / "a.json"), {"x": 1})
        runner.keep_metrics_until(str(tmp_path), 0, [])
        fig = plots._pyplot().figure()
        plots.save_figure(fig, str(tmp_path / "f.png"))
    finally:
        os.umask(previous)
    for name in ("a.json", "metrics.jsonl", "f.png"):
        assert os.stat(tmp_path / name).st_mode & 0o777 == 0o644, name


def test_a_start_that_fails_before_writing_leaves_no_folder(tmp_path):
    fresh, kept = str(tmp_path / "fresh"), str(tmp_path / "kept")
    with pytest.raises(RuntimeError), run_guard.lock_run(fresh):
        raise RuntimeError("failed before writing anything")
    assert not os.path.exists(fresh)
    with run_guard.lock_run(kept):
        open(os.path.join(kept, "config.json"), "w").write("{}")
    assert sorted(os.listdir(kept)) == [".lock", "config.json"]


_FILE_SIZE_LIMIT = """
import resource, sys
limit = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))  # Python ignores SIGXFSZ: EFBIG
from minatt_jax.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow
def test_a_write_failure_during_a_checkpoint_is_one_line_and_resumes_exactly(tmp_path, capsys):
    """A 32 KiB file-size limit: config.json, the record and the policy snapshot fit, the
    checkpoint's files do not. One line naming the cause, exit 2, the step's record and snapshot
    taken back, no temporary folder; the resume then trains the step as a straight run does."""
    out, straight = str(tmp_path / "run"), str(tmp_path / "straight")
    argv = [*SMOKE, "--steps", "300", "--alpha", "1"]
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    limited = subprocess.run([sys.executable, "-c", _FILE_SIZE_LIMIT, str(32 * 1024), *argv,
                              "--out", out], env=env, capture_output=True, text=True,
                             timeout=600)  # fmt: skip
    assert limited.returncode == 2, limited.stderr
    lines = limited.stderr.strip().splitlines()
    assert len(lines) == 1, limited.stderr
    assert "checkpoint 300 could not be written" in lines[0] and "File too large" in lines[0]
    assert "nothing of step 300 was kept" in lines[0] and "--resume" in lines[0]
    assert runner.read_metrics(out) == [] and checkpoint.snapshot_steps(out) == []
    assert checkpoint.all_steps(out) == [] and os.listdir(os.path.join(out, "checkpoints")) == []
    assert run_cli(["train", "--out", out, "--resume"], capsys)[0] == 0
    assert run_cli([*argv, "--out", straight], capsys)[0] == 0
    assert _records(out) == _records(straight) and checkpoint.all_steps(out) == [300]


@pytest.mark.slow
def test_a_signal_while_compiling_ends_the_command_at_once(tmp_path):
    """SIGTERM two seconds into the compilation (which takes tens of seconds): exit 143 within a
    few seconds, one line saying so and how to resume; the resume then trains the run."""
    out = str(tmp_path / "run")
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    cmd = [sys.executable, "-m", "minatt_jax.cli", *SMOKE, "--steps", "300", "--out", out]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    deadline = time.time() + 300
    while time.time() < deadline and not os.path.exists(os.path.join(out, "config.json")):
        time.sleep(0.05)
    time.sleep(2.0)  # the trainer is built and the compile has begun
    sent = time.time()
    proc.send_signal(signal.SIGTERM)
    out_text, err = proc.communicate(timeout=60)
    waited = time.time() - sent
    assert proc.returncode == 143, err
    assert "compiled" not in out_text and waited < 5, (waited, out_text)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "stopped by SIGTERM while" in lines[0], err
    assert f"resume with: minatt-jax train --out {out} --resume" in lines[0]
    assert checkpoint.all_steps(out) == [] and runner.read_metrics(out) == []

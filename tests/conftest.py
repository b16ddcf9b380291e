"""Shared fixtures and a persistent XLA compilation cache for the whole test run.

Several tests compile the same programs (in-process, in subprocesses and in pytest-xdist
workers); the cache, in one fresh temporary folder per test run that the workers and subprocesses
inherit through the environment, lets the later ones load them instead of compiling again.
"""

from __future__ import annotations

import json
import os
import tempfile

from minatt_jax import gl

# mujoco reads MUJOCO_GL once, at its first import: the test process imports it able to render
# offscreen (tests/test_render.py), while the commands tests start in subprocesses keep their
# own choice (the CLI turns OpenGL off for every command but render).
_GL_BEFORE = os.environ.get("MUJOCO_GL")
gl.choose_for_rendering()
import mujoco  # noqa: E402, F401 - imported here, with the backend chosen above

if _GL_BEFORE is None:
    os.environ.pop("MUJOCO_GL", None)

import jax  # noqa: E402
import pytest  # noqa: E402

import minatt_jax.envs as envs  # noqa: E402

# The controller makes the folder; xdist workers and subprocesses find it in their environment.
_CACHE = os.environ.get("JAX_COMPILATION_CACHE_DIR") or tempfile.mkdtemp(
    prefix="minatt-jax-xla-cache-"
)
os.environ["JAX_COMPILATION_CACHE_DIR"] = _CACHE
jax.config.update("jax_compilation_cache_dir", _CACHE)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


@pytest.fixture(scope="session")
def make_env():
    cache: dict[str, envs.LocomotionEnv] = {}

    def get(name: str) -> envs.LocomotionEnv:
        if name not in cache:
            cache[name] = envs.make(name)
        return cache[name]

    return get


def counted_jit(fn):
    """``jax.jit(fn)`` and the list its traces append to: a test asserts the list's length to
    show that new data (a task, a seed, a swept value) did not recompile."""
    traces: list[int] = []

    def counted(*args):
        traces.append(1)
        return fn(*args)

    return jax.jit(counted), traces


def central_jacobian(f, x, eps: float = 1e-3):
    """The Jacobian of ``f`` at ``x`` by central differences, in float64 (f runs in float32)."""
    import numpy as np

    x = np.asarray(x, np.float64)
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e.flat[i] = eps
        up = np.asarray(f(jax.numpy.asarray(x + e, jax.numpy.float32)), np.float64)
        down = np.asarray(f(jax.numpy.asarray(x - e, jax.numpy.float32)), np.float64)
        cols.append((up - down) / (2 * eps))
    return np.stack(cols, -1)


def sequence_batch(key, b: int, t: int, obs_size: int = 5, act_size: int = 2):
    """Random replayed sequences (B, T) for DreamerV3's learner: each starts an episode."""
    from minatt_jax.dreamer.agent import Batch

    jnp = jax.numpy
    k1, k2, k3 = jax.random.split(key, 3)
    return Batch(
        obs=jax.random.normal(k1, (b, t, obs_size)),
        prev_action=jax.random.uniform(k2, (b, t, act_size), minval=-1, maxval=1),
        reward=jax.random.uniform(k3, (b, t)),
        is_first=jnp.zeros((b, t)).at[:, 0].set(1.0),
        cont=jnp.ones((b, t)),
    )


def untrained_run(run: str, config, step: int) -> None:
    """A run directory made without training: ``config`` (resolved), a checkpoint and a policy
    snapshot of the initial state at ``step``, and one metrics record there."""
    from minatt_jax import checkpoint, run_files
    from minatt_jax.training import hyper_of, make_train

    run_files.write_json_atomic(os.path.join(run, "config.json"), config.to_dict())
    state = make_train(config).init(jax.random.PRNGKey(0), hyper_of(config))
    state = state.replace(env_steps=state.env_steps + step)
    checkpoint.save(run, step, state)
    checkpoint.save_policy_snapshot(run, step, state.agent.actor_params, state.data.normalizer)
    with open(os.path.join(run, "metrics.jsonl"), "w") as f:
        f.write(json.dumps({"step": step, "return": 1.0}) + "\n")


def digest(root: str) -> dict[str, str]:
    """sha256 of every file under ``root`` but the lock: what "nothing was changed" compares."""
    import hashlib

    out = {}
    for base, _, files in os.walk(root):
        for name in files:
            path = os.path.join(base, name)
            if os.path.islink(path):
                out[path] = "link to " + os.readlink(path)
            elif name != ".lock":
                out[path] = hashlib.sha256(open(path, "rb").read()).hexdigest()
    return out


def run_cli(argv: list[str], capsys: pytest.CaptureFixture) -> tuple[int, object]:
    """The CLI's exit status (returned, or raised by argparse) and what it printed."""
    from minatt_jax.cli import main

    try:
        status = main(argv)
    except SystemExit as e:
        status = e.code
    return status, capsys.readouterr()


# Seconds each test module took on two CI-like cores (pytest --durations, 2 workers, 2026-12),
# after the extended tests were set aside. Modules run longest first, so that the two
# pytest-xdist workers finish together instead of one idling while the other runs a late long
# module. Unlisted modules count as quick. A stale figure only costs balance, never correctness.
MODULE_SECONDS = {
    "test_population.py": 320,
    "test_dreamer.py": 280,
    "test_meta_test.py": 260,
    "test_notebooks.py": 240,
    "test_golden_runs.py": 180,
    "test_train_program.py": 180,
    "test_reliability.py": 160,
    "test_env_physics.py": 160,
    "test_mamba.py": 140,
    "test_training.py": 140,
    "test_model_based.py": 130,
    "test_report.py": 130,
    "test_plugin_example.py": 100,
    "test_meta_step.py": 100,
    "test_user_agent.py": 90,
    "test_meta_episode.py": 90,
    "test_tasks.py": 90,
    "test_humanoid_dir.py": 70,
    "test_config_fields.py": 70,
    "test_ppo.py": 60,
    "test_cheetah_run.py": 50,
    "test_checkpoint.py": 50,
    "test_imagination.py": 50,
    "test_signals.py": 40,
    "test_control_analysis.py": 30,
    "test_cli.py": 30,
    "test_dynamics_ensemble.py": 20,
    "test_sac_parts.py": 20,
    "test_min_attention.py": 20,
    "test_render.py": 20,
}


def straight_and_resumed(argv: list[str], tmp_path, capsys) -> tuple[list, list]:
    """The metrics of ``train`` run straight to 600 steps and of the same run stopped at 300
    and resumed to 600 (both must exit 0): what an exact-resume test compares."""
    from minatt_jax import runner

    straight, split = str(tmp_path / "straight"), str(tmp_path / "split")
    assert run_cli([*argv, "--out", straight], capsys)[0] == 0
    assert run_cli([*argv, "--steps", "300", "--out", split], capsys)[0] == 0
    assert run_cli(["train", "--out", split, "--resume", "--steps", "600"], capsys)[0] == 0
    return runner.read_metrics(straight), runner.read_metrics(split)


def pytest_configure(config: pytest.Config) -> None:
    if hasattr(config.option, "loadscopereorder"):  # pytest-xdist: keep the order set below
        config.option.loadscopereorder = False
    if os.environ.get("MINATT_COMPILE_LOG"):
        _log_compilations(os.environ["MINATT_COMPILE_LOG"])


_CURRENT_TEST = {"id": "(collection)"}
_COMPILE_EVENTS = (
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "/jax/core/compile/backend_compile_duration",
)


def _log_compilations(path: str) -> None:
    """Appends each trace, lowering and XLA compile (or cache load) to `path` as JSON lines.

    MINATT_COMPILE_LOG=/tmp/compiles.jsonl pytest ... shows where the suite's time goes: which
    test compiles which program for how long, and which programs several tests compile alike.
    """
    from jax import monitoring

    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")

    def listen(event: str, seconds: float, **kwargs: object) -> None:
        if event in _COMPILE_EVENTS and seconds >= 0.5:
            line = {"test": _CURRENT_TEST["id"], "worker": worker, "event": event.rsplit("/", 1)[1]}
            line |= {"seconds": round(seconds, 2), "fun": str(kwargs.get("fun_name", ""))}
            with open(path, "a") as f:
                f.write(json.dumps(line) + "\n")

    monitoring.register_event_duration_secs_listener(listen)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    _CURRENT_TEST["id"] = item.nodeid


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: -MODULE_SECONDS.get(item.path.name, 0))  # stable within a module
